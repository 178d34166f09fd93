"""Headless test views of a scene: camera specs, still renders and camera paths (turntable,
fly-through), drawn by the same rasteriser as training."""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np
import torch

from pano4d import images, nerfstudio_path, ply4d
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
    # JSON text is told apart by its brace, not by asking the file system: a long pose is
    # no file name (stat raises "File name too long" on it).
    text = spec
    if not spec.lstrip().startswith("{"):
        try:
            text = Path(spec).read_text()
        except OSError as e:
            raise RenderArgumentError(
                f"--camera {spec}: neither JSON text nor a readable file ({e.strerror or e})"
            ) from e
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


def video_times(scene: Path, frames: int, fps: float, start: float = 0.0) -> list[float]:
    """The scene time (frames) each of ``frames`` video frames at ``fps`` shows, from time
    ``start``: the scene plays at its own rate, looping, whatever the video's
    (``ply4d.playback_time``)."""
    _, scene_fps = scene_clock(scene)
    return [start + ply4d.playback_time(i, fps, scene_fps) for i in range(frames)]


def gaussians_at(scene: Path, times: Iterable[float]) -> Iterator[Gaussians]:
    """The Gaussians ``scene`` shows at each of ``times`` (frames, ``Ply4dFile.at``). A
    version-2 scene is evaluated at each time, so a 30 fps video of an 8 fps scene moves
    smoothly between its timestamps; a version-1 scene holds each timestamp for the run of
    times that show it, read once for them. The file is opened once for all of them (a
    version-2 spacetime set is decoded once)."""
    if scene.suffix != ".ply4d":  # one moment, shown at every time
        g = ply4d.read_ply(scene)
        yield from (g for _ in times)
        return
    f = ply4d.open(scene)
    shown, g = None, Gaussians.empty()
    for t in times:
        time = f.shown_time(t)
        if time != shown:
            g, shown = f.at(time), time
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
    start: float = 0.0,
    backend: str = "wgpu",
) -> None:
    """A video along a built-in camera path (``path_cameras``); time follows the scene's
    own rate from ``start`` (``video_times``)."""
    cams = path_cameras(kind, width, height, frames, path_radius(scene))
    times = video_times(scene, frames, fps, start)
    images.write_video(out, path_frames(scene, cams, times, backend), fps)


def render_camera_path(
    scene: Path, path: nerfstudio_path.CameraPath, out: Path, backend: str = "wgpu"
) -> None:
    """A video along a perspective ``camera_path.json``: its cameras at its fps, each frame at
    its scene time (``CameraPath.scene_times``)."""
    num_times, scene_fps = scene_clock(scene)
    times = path.scene_times(num_times, scene_fps)
    images.write_video(out, path_frames(scene, path.cameras(), times, backend), path.fps)


def path_frames(
    scene: Path, cameras: list[Camera], times: list[float], backend: str
) -> Iterator[np.ndarray]:
    """The image of each camera at its time, drawn as ``render_still`` draws one."""
    antialiased = scene_antialiased(scene)
    for g, cam in zip(gaussians_at(scene, times), cameras, strict=True):
        yield to_image(render(g, cam, backend=backend, antialiased=antialiased).rgb)


def path_radius(scene: Path) -> float:
    """The fly-through's radius: 5 % of the median distance of timestamp 0's Gaussians."""
    first = load_gaussians(scene, 0.0)
    return 0.05 * float(torch.linalg.norm(first.means, dim=-1).median()) if len(first) else 1.0
