"""3DGS ``.ply`` files and the ``.ply4d`` 4D scene format (spec: docs/ply4d.md).

The reading and writing happen in Rust (``pano4d._core``); this module converts between
its float32 numpy arrays and :class:`~pano4d.gaussians.Gaussians`. Format errors raise
``ValueError`` and operating-system errors ``OSError``, both with the Rust message.
Every write is atomic (temporary file in the same folder, fsync, rename).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from typing import Any

from pano4d import __version__, _core
from pano4d.gaussians import Gaussians

__all__ = ["Ply4dFile", "Scene4D", "export", "open", "read", "read_ply", "write", "write_ply"]

PathLike = str | os.PathLike[str]


def read_ply(path: PathLike) -> Gaussians:
    """Read a standard 3DGS ``.ply`` or a SuperSplat ``.compressed.ply`` (CPU tensors)."""
    return Gaussians.from_numpy(_core.read_ply(os.fspath(path)))


def write_ply(path: PathLike, g: Gaussians) -> None:
    """Write ``g`` as a standard binary 3DGS ``.ply`` (float32, bit-exact on read-back)."""
    _core.write_ply(os.fspath(path), g.to_numpy())


def _default_camera() -> dict[str, Any]:
    return {"position": [0.0, 0.0, 0.0], "params": {}}


def _default_provenance() -> dict[str, Any]:
    return {"tool_version": __version__, "config_hash": ""}


@dataclass
class Scene4D:
    """A 4D scene: ``static`` is shown at every timestamp, ``dynamic[t]`` only at ``t``.

    ``camera`` is the source panorama's camera: ``{"position": [x, y, z], "params": {...}}``
    with free-form params; ``provenance`` holds ``tool_version`` and ``config_hash``;
    ``extra`` is free-form. All three must be JSON-serialisable.
    """

    static: Gaussians
    dynamic: list[Gaussians]
    timestamps: list[float]
    fps: float
    camera: dict[str, Any] = field(default_factory=_default_camera)
    provenance: dict[str, Any] = field(default_factory=_default_provenance)
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if len(self.timestamps) != len(self.dynamic):
            raise ValueError(
                f"Scene4D has {len(self.timestamps)} timestamps "
                f"but {len(self.dynamic)} dynamic sets"
            )

    @property
    def num_times(self) -> int:
        return len(self.dynamic)

    def at(self, t: int) -> Gaussians:
        """All Gaussians visible at timestamp index ``t``: static followed by dynamic."""
        _check_time(t, self.num_times)
        return Gaussians.cat([self.static, self.dynamic[t]])


def _check_time(t: int, num_times: int) -> None:
    if not 0 <= t < num_times:
        raise IndexError(f"timestamp index {t} out of range: the scene has {num_times}")


def write(path: PathLike, scene: Scene4D) -> None:
    """Write ``scene`` as a ``.ply4d`` file.

    Sets of a lower SH degree are zero-padded to the scene's highest degree, since all
    sections of a file share one degree.
    """
    degree = max([scene.static.sh_degree] + [g.sh_degree for g in scene.dynamic])
    unknown = set(scene.camera) - {"position", "params"}
    if unknown:
        raise ValueError(
            f"Scene4D.camera keys must be 'position' and 'params', got extra keys {sorted(unknown)}"
        )
    camera = {**_default_camera(), **scene.camera}
    meta = {
        "timestamps": [float(t) for t in scene.timestamps],
        "fps": float(scene.fps),
        "camera": {"position": [float(v) for v in camera["position"]], "params": camera["params"]},
        "provenance": {**_default_provenance(), **scene.provenance},
        "extra": scene.extra,
    }
    if not all(math.isfinite(v) for v in [*meta["timestamps"], meta["fps"]]):
        raise ValueError("Scene4D.fps and timestamps must be finite")
    try:
        meta_json = json.dumps(meta, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise ValueError(f"Scene4D metadata is not JSON-serialisable: {e}") from e
    _core.write_ply4d(
        os.fspath(path),
        scene.static.with_sh_degree(degree).to_numpy(),
        [g.with_sh_degree(degree).to_numpy() for g in scene.dynamic],
        meta_json,
    )


class Ply4dFile:
    """A ``.ply4d`` file opened lazily (memory-mapped): only the sets asked for are read,
    and each one's checksum is verified when it is read."""

    def __init__(self, path: PathLike) -> None:
        self.path = os.fspath(path)
        self._reader = _core.Ply4dReader(self.path)
        self.header: dict[str, Any] = json.loads(self._reader.header_json())

    @property
    def num_times(self) -> int:
        return self._reader.num_times

    @property
    def timestamps(self) -> list[float]:
        return list(self.header["timestamps"])

    def static(self) -> Gaussians:
        return Gaussians.from_numpy(self._reader.read_static())

    def dynamic(self, t: int) -> Gaussians:
        _check_time(t, self.num_times)
        return Gaussians.from_numpy(self._reader.read_dynamic(t))

    def at(self, t: int) -> Gaussians:
        """Static followed by dynamic set ``t``."""
        _check_time(t, self.num_times)
        return Gaussians.from_numpy(self._reader.read_at(t))

    def verify(self) -> None:
        """Check every section's checksum; raises ValueError on the first mismatch."""
        self._reader.verify()

    def export(self, t: int, path_out: PathLike) -> None:
        """Write timestamp ``t`` (static + dynamic) as a plain 3DGS ``.ply``."""
        _check_time(t, self.num_times)
        self._reader.export_ply(t, os.fspath(path_out))

    def read(self) -> Scene4D:
        """Decode the whole scene."""
        h = self.header
        return Scene4D(
            static=self.static(),
            dynamic=[self.dynamic(t) for t in range(self.num_times)],
            timestamps=list(h["timestamps"]),
            fps=h["fps"],
            camera=h["camera"],
            provenance=h["provenance"],
            extra=h["extra"],
        )


def open(path: PathLike) -> Ply4dFile:
    """Open a ``.ply4d`` file for lazy, per-timestamp reading."""
    return Ply4dFile(path)


def read(path: PathLike) -> Scene4D:
    """Read a whole ``.ply4d`` file."""
    return Ply4dFile(path).read()


def export(path_in: PathLike, t: int, path_out: PathLike) -> None:
    """Write timestamp ``t`` of a ``.ply4d`` (static + dynamic) as a plain 3DGS ``.ply``."""
    Ply4dFile(path_in).export(t, path_out)
