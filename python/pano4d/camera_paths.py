"""Headless test views of a scene: camera specs, still renders and camera paths (turntable,
fly-through), drawn by the same rasteriser as training."""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from pano4d import images, ply4d
from pano4d.camera import Camera
from pano4d.errors import InputError
from pano4d.gaussians import Gaussians
from pano4d.renderer import render

DEFAULT_FOV_DEG = 90.0


class RenderArgumentError(InputError, ValueError):
    """A --camera, --path or --time value that ``pano4d render`` cannot use."""


def parse_camera(spec: str | None, width: int, height: int) -> Camera:
    """A camera from JSON text or a JSON file; None is the panorama's viewpoint (origin, +x).

    Accepted shapes: {"position", "forward", "fov_deg"[, "up"]} or a views.json entry
    {"K", "world_to_cam"[, "width", "height"]}.
    """
    if spec is None:
        return Camera.from_fov(DEFAULT_FOV_DEG, width, height)
    text = Path(spec).read_text() if Path(spec).is_file() else spec
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise RenderArgumentError(f"--camera is neither a JSON file nor JSON text: {e}") from e
    if not isinstance(data, dict):
        raise RenderArgumentError(f"--camera must be a JSON object, got {type(data).__name__}")
    missing = {"position", "forward"} - set(data)
    if missing and "K" not in data:
        raise RenderArgumentError(
            f"--camera needs {sorted(missing)} (or K and world_to_cam); got keys {sorted(data)}"
        )
    for key in ("position", "forward", "up"):
        value = data.get(key, (0.0, 0.0, 0.0))
        if not (isinstance(value, list | tuple) and len(value) == 3):
            raise RenderArgumentError(f"--camera {key} must be a 3-vector [x, y, z], got {value}")
    try:
        if "K" in data:
            return Camera.from_dict({"width": width, "height": height, **data})
        return Camera.from_fov(
            float(data.get("fov_deg", DEFAULT_FOV_DEG)),
            width,
            height,
            data["position"],
            data["forward"],
            data.get("up", (0.0, 0.0, 1.0)),
        )
    except (ValueError, TypeError) as e:  # a value of the wrong shape or type
        raise RenderArgumentError(f"--camera {text.strip()}: {e}") from e


def scene_clock(scene: Path) -> tuple[int, float]:
    """The number of timestamps of ``scene`` and the rate they were made at (the .ply4d's
    ``fps``); a plain .ply is one timestamp."""
    if scene.suffix == ".ply4d":
        f = ply4d.open(scene)
        return f.num_times, f.fps
    return 1, 1.0


def scene_antialiased(scene: Path) -> bool:
    """The rasteriser mode every render of ``scene`` uses: the .ply4d's (the mode it was
    trained in); a plain .ply is classic, as every other tool draws it (``pano4d export``
    bakes an antialiased scene's filter into the file it writes)."""
    return scene.suffix == ".ply4d" and ply4d.open(scene).antialiased


def gaussians_per_frame(scene: Path, frames: int, fps: float) -> Iterator[Gaussians]:
    """The Gaussians each of ``frames`` video frames at ``fps`` shows: the scene plays at
    its own rate, looping, whatever the video's (``ply4d.playback_time``). A version-2 scene
    is evaluated at each frame's own time, so a 30 fps video of an 8 fps scene moves
    smoothly between its timestamps; a version-1 scene holds each timestamp for the run of
    frames that show it (3.75 frames there), read once for them. The file is opened once
    for the whole video (a version-2 spacetime set is decoded once)."""
    if scene.suffix != ".ply4d":
        yield from itertools.repeat(load_gaussians(scene, 0.0), frames)
        return
    f = ply4d.open(scene)
    shown, g = None, Gaussians.empty()
    for i in range(frames):
        t = f.shown_time(ply4d.playback_time(i, fps, f.fps))
        if t != shown:
            g, shown = f.at(t), t
        yield g


def load_gaussians(scene: Path, time: float) -> Gaussians:
    """Gaussians of ``scene`` at ``time`` (frames, ``ply4d.Ply4dFile.at``); a plain .ply has
    only time 0."""
    if scene.suffix == ".ply4d":
        return ply4d.open(scene).at(time)
    if time != 0:
        raise RenderArgumentError(f"{scene} is a single .ply; --time must be 0, got {time:g}")
    return ply4d.read_ply(scene)


def to_image(rgb: torch.Tensor) -> np.ndarray:
    return rgb.detach().clamp(0, 1).cpu().numpy()


def render_still(
    scene: Path, camera: Camera, time: float, out: Path, backend: str = "wgpu"
) -> None:
    """A still of ``scene`` at ``time`` (frames: a version-2 scene evaluated there, a
    version-1 one at the timestamp it holds)."""
    g = load_gaussians(scene, time)
    rgb = render(g, camera, backend=backend, antialiased=scene_antialiased(scene)).rgb
    images.write_image(out, to_image(rgb))


def turntable(
    width: int, height: int, frames: int, orbit: float = 0.0, fov_deg: float = DEFAULT_FOV_DEG
) -> list[Camera]:
    """``frames`` level cameras making one turn to the right: the view's centre sweeps the
    panorama from left to right (increasing u), since the image's right is the viewer's
    right (docs/design.md, "Conventions"). With ``orbit`` > 0 each camera stands that far to
    the left of the origin, seen along its view, so the path circles the origin and shows
    parallax."""
    cams = []
    for i in range(frames):
        a = 2 * math.pi * i / frames
        forward = (math.cos(a), -math.sin(a), 0.0)
        left = (math.sin(a), math.cos(a), 0.0)  # up × forward
        position = tuple(orbit * c for c in left)
        cams.append(Camera.from_fov(fov_deg, width, height, position, forward))
    return cams


def fly_through(width: int, height: int, frames: int, radius: float) -> list[Camera]:
    """A loop of the given radius through the origin at eye height, looking along the
    direction of travel."""
    cams = []
    for i in range(frames):
        a = 2 * math.pi * i / frames
        pos = (radius * math.sin(a), radius * (1 - math.cos(a)), 0.0)
        cams.append(
            Camera.from_fov(DEFAULT_FOV_DEG, width, height, pos, (math.cos(a), math.sin(a), 0))
        )
    return cams


def path_cameras(kind: str, width: int, height: int, frames: int, radius: float) -> list[Camera]:
    """The cameras of ``pano4d render --path``: ``turntable`` (a full turn in place at the
    origin) or ``fly-through`` (a loop of ``radius``)."""
    if kind == "turntable":
        return turntable(width, height, frames)
    if kind == "fly-through":
        return fly_through(width, height, frames, radius)
    raise RenderArgumentError(f"--path must be 'turntable' or 'fly-through', got {kind!r}")


def render_path(
    scene: Path,
    kind: str,
    out: Path,
    width: int,
    height: int,
    frames: int,
    fps: float,
    backend: str = "wgpu",
) -> None:
    """A video along a camera path; time follows the scene's own rate
    (``gaussians_per_frame``)."""
    cams = path_cameras(kind, width, height, frames, path_radius(scene))
    shown = zip(gaussians_per_frame(scene, frames, fps), cams, strict=True)
    antialiased = scene_antialiased(scene)
    images.write_video(
        out,
        (to_image(render(g, cam, backend=backend, antialiased=antialiased).rgb)
         for g, cam in shown),
        fps,
    )  # fmt: skip


def path_radius(scene: Path) -> float:
    """The fly-through's radius: 5 % of the median distance of timestamp 0's Gaussians."""
    first = load_gaussians(scene, 0.0)
    return 0.05 * float(torch.linalg.norm(first.means, dim=-1).median()) if len(first) else 1.0
