"""nerfstudio's ``camera_path.json``, the camera-path file people make in other tools
(nerfstudio's viewer, Blender through nerfstudio's add-on) and render with
``pano4d render scene.ply4d --path camera_path.json``.

The file, as ``ns-render camera-path`` reads it: a dense ``camera_path`` list, one entry a
video frame, each ``camera_to_world`` (4×4, row-major, flat or nested; OpenGL camera axes:
x right, y up, looking along −z), ``fov`` (vertical, degrees), ``aspect`` (ignored, as
ns-render ignores it: the file's size sets the shape) and an optional ``render_time`` in
[0, 1]; at the top ``render_width``, ``render_height``, ``fps``, ``seconds`` and
``camera_type``: ``perspective`` or ``equirectangular`` (a 360° video; the frame is
world-aligned, z up, as headsets expect: only each entry's position is used).

Time: when every entry has ``render_time`` (nerfstudio's rule), 0 → 1 spans the scene's loop
once (``render_time`` · timestamps frames; 1 is 0 again); otherwise the scene plays at its own
rate at the file's ``fps``, as every other video pano4d renders.

Poses are in the scene's own coordinates. A path made in nerfstudio on ``pano4d views``'
dataset is in nerfstudio's normalised coordinates instead; its ``dataparser_transforms.json``
(written beside the trained model) maps it back (``--path-transform``, ``to_scene``).
Every malformed or unsupported value is one ``CameraPathError`` naming the entry and field.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import torch

from pano4d import ply4d
from pano4d.camera import Camera, focal_length
from pano4d.errors import InputError

CameraType = Literal["perspective", "equirectangular"]
CAMERA_TYPES: tuple[CameraType, ...] = ("perspective", "equirectangular")


class CameraPathError(InputError, ValueError):
    """A camera-path file pano4d cannot render: the message names the file, entry and field."""


@dataclass(frozen=True)
class PathFrame:
    """One video frame of a camera path."""

    camera_to_world: torch.Tensor  # (4, 4) float64, OpenGL camera axes
    fov_deg: float  # vertical field of view (unused by an equirectangular path)
    render_time: float | None  # in [0, 1] over the loop, or None


@dataclass(frozen=True)
class CameraPath:
    """A whole ``camera_path.json``: its frames and the video they make."""

    frames: list[PathFrame]
    width: int
    height: int
    fps: float
    camera_type: CameraType
    source: str  # the file, for messages

    def cameras(self) -> list[Camera]:
        """The perspective camera of every frame, as ns-render builds it: focal length from
        the vertical field of view and the image height, principal point at the centre."""
        cameras = []
        for frame in self.frames:
            f = focal_length(frame.fov_deg, self.height)
            K = torch.tensor(
                [[f, 0.0, self.width / 2.0], [0.0, f, self.height / 2.0], [0.0, 0.0, 1.0]],
                dtype=torch.float64,
            )
            cameras.append(
                Camera.from_camera_to_world_gl(frame.camera_to_world, K, self.width, self.height)
            )
        return cameras

    def positions(self) -> list[torch.Tensor]:
        """Every frame's eye position (3,), float64: what a 360° frame uses."""
        return [frame.camera_to_world[:3, 3].clone() for frame in self.frames]

    def scene_times(self, num_times: int, scene_fps: float) -> list[float]:
        """Each frame's scene time in frames (readers take it modulo the loop): from
        ``render_time`` when every entry has one, else the scene's own clock at ``fps``."""
        if all(frame.render_time is not None for frame in self.frames):
            return [float(frame.render_time) * num_times for frame in self.frames]  # type: ignore[arg-type]
        return [ply4d.playback_time(i, self.fps, scene_fps) for i in range(len(self.frames))]

    def to_scene(self, transform: DataparserTransform) -> CameraPath:
        """The path in the scene's own coordinates, made in nerfstudio's normalised ones."""
        frames = [
            PathFrame(transform.to_scene(f.camera_to_world), f.fov_deg, f.render_time)
            for f in self.frames
        ]
        return CameraPath(frames, self.width, self.height, self.fps, self.camera_type, self.source)


@dataclass(frozen=True)
class DataparserTransform:
    """nerfstudio's ``dataparser_transforms.json``: it trains on poses ``scale · (T · pose)``
    (T: 3×4 rigid, the orientation and centring it chose; scale: uniform)."""

    transform: torch.Tensor  # (4, 4) float64
    scale: float

    def to_scene(self, camera_to_world: torch.Tensor) -> torch.Tensor:
        """A camera-to-world in nerfstudio's coordinates back in the dataset's."""
        c2w = camera_to_world.clone()
        c2w[:3, 3] = c2w[:3, 3] / self.scale
        return torch.linalg.inv(self.transform) @ c2w


def read(path: Path) -> CameraPath:
    """Read and check a ``camera_path.json``."""
    data = _load_json(path)
    where = str(path)
    if not isinstance(data, dict):
        raise CameraPathError(f"{where}: expected a JSON object, got {type(data).__name__}")
    camera_type = data.get("camera_type", "perspective")
    if camera_type not in CAMERA_TYPES:
        raise CameraPathError(
            f"{where}: camera_type {camera_type!r} is not supported; expected one of "
            f"{', '.join(CAMERA_TYPES)}"
        )
    width = _positive_int(data, "render_width", where)
    height = _positive_int(data, "render_height", where)
    fps = _number(data, "fps", where, lambda v: v > 0, "a frame rate > 0")
    entries = data.get("camera_path")
    if not isinstance(entries, list) or not entries:
        raise CameraPathError(f"{where}: camera_path must be a non-empty list of cameras")
    frames = [
        _frame(entry, f"{where}: camera_path[{i}]", camera_type) for i, entry in enumerate(entries)
    ]
    return CameraPath(frames, width, height, fps, camera_type, where)


def read_dataparser_transform(path: Path) -> DataparserTransform:
    """Read nerfstudio's ``dataparser_transforms.json`` (``transform`` 3×4, ``scale``)."""
    data = _load_json(path)
    where = str(path)
    if not isinstance(data, dict):
        raise CameraPathError(f"{where}: expected a JSON object, got {type(data).__name__}")
    scale = _number(data, "scale", where, lambda v: v > 0, "a scale > 0")
    rows = _matrix(data.get("transform"), 3, f"{where}: transform")
    transform = torch.eye(4, dtype=torch.float64)
    transform[:3] = rows
    return DataparserTransform(transform, scale)


def _load_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except OSError as e:
        raise CameraPathError(f"{path}: cannot be read ({e.strerror or e})") from e
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise CameraPathError(f"{path}: not JSON ({e})") from e


def _frame(entry: Any, where: str, camera_type: str) -> PathFrame:
    if not isinstance(entry, dict):
        raise CameraPathError(f"{where}: expected an object, got {type(entry).__name__}")
    c2w = _matrix(entry.get("camera_to_world"), 4, f"{where}.camera_to_world")
    if not torch.equal(c2w[3], torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)):
        raise CameraPathError(
            f"{where}.camera_to_world: the last row must be [0, 0, 0, 1], got {c2w[3].tolist()}"
        )
    rotation = c2w[:3, :3]
    # A camera that stretches or mirrors the world is no pose: say so rather than render it.
    error = float((rotation.T @ rotation - torch.eye(3, dtype=torch.float64)).abs().max())
    if error > 1e-4 or float(torch.linalg.det(rotation)) < 0:
        raise CameraPathError(
            f"{where}.camera_to_world: the 3×3 part must be a rotation (orthonormal, "
            f"determinant +1); it is off by {error:.3g}"
        )
    fov = float("nan")
    if camera_type == "perspective":
        fov = _number(entry, "fov", where, lambda v: 0 < v < 180, "degrees in (0, 180)")
    render_time = None
    if "render_time" in entry:
        render_time = _number(entry, "render_time", where, lambda v: 0 <= v <= 1, "in [0, 1]")
    return PathFrame(c2w, fov, render_time)


def _matrix(value: Any, rows: int, where: str) -> torch.Tensor:
    """A rows×4 matrix given nested or flat (row-major), finite numbers."""
    try:
        m = torch.tensor(value, dtype=torch.float64).reshape(rows, 4)
    except (TypeError, ValueError, RuntimeError) as e:
        raise CameraPathError(
            f"{where}: expected {rows * 4} numbers ({rows}×4, row-major), got {value!r:.80}"
        ) from e
    if not torch.isfinite(m).all():
        raise CameraPathError(f"{where}: every value must be finite, got {m.tolist()}")
    return m


def _number(data: dict[str, Any], key: str, where: str, valid: Any, expected: str) -> float:
    value = data.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise CameraPathError(f"{where}: {key} must be a number ({expected}), got {value!r}")
    if not (math.isfinite(value) and valid(value)):
        raise CameraPathError(f"{where}: {key} must be {expected}, got {value!r}")
    return float(value)


def _positive_int(data: dict[str, Any], key: str, where: str) -> int:
    value = data.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise CameraPathError(f"{where}: {key} must be a whole number of pixels ≥ 1, got {value!r}")
    return value
