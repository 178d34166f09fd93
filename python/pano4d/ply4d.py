"""3DGS ``.ply`` files and the ``.ply4d`` 4D scene format (spec: docs/ply4d.md).

The reading and writing happen in Rust (``pano4d._core``, through ``pano4d.extension``);
sets cross as its ``GaussianArrays``, converted to and from
:class:`~pano4d.gaussians.Gaussians` by ``pano4d.extension``. Format errors raise
``FormatError`` (a ``ValueError``) and operating-system errors ``OSError``, both with the
Rust message, which names the file; a timestamp out of range raises ``TimeIndexError``.
Every write is atomic (temporary file in the same folder, fsync, rename).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from pano4d import __version__
from pano4d.errors import InputError
from pano4d.extension import core, gaussian_arrays, gaussians_from
from pano4d.gaussians import Gaussians

__all__ = [
    "FormatError",
    "Ply4dFile",
    "Ply4dWriter",
    "Scene4D",
    "TimeIndexError",
    "export",
    "open",
    "read",
    "read_ply",
    "write",
    "write_ply",
]

PathLike = str | os.PathLike[str]


class FormatError(InputError, ValueError):
    """A .ply or .ply4d file that does not hold what its format says."""


class TimeIndexError(InputError, IndexError):
    """A timestamp index the scene does not have."""


@contextlib.contextmanager
def _format_errors() -> Iterator[None]:
    """The Rust reader's ValueError (its message names the file) as a FormatError."""
    try:
        yield
    except FormatError:
        raise
    except ValueError as error:
        raise FormatError(str(error)) from error


def read_ply(path: PathLike) -> Gaussians:
    """Read a standard 3DGS ``.ply`` or a SuperSplat ``.compressed.ply`` (CPU tensors)."""
    with _format_errors():
        return gaussians_from(core.read_ply(os.fspath(path)))


def write_ply(path: PathLike, g: Gaussians) -> None:
    """Write ``g`` as a standard binary 3DGS ``.ply`` (float32, bit-exact on read-back)."""
    core.write_ply(os.fspath(path), gaussian_arrays(g))


def _default_camera() -> dict[str, Any]:
    return {"position": [0.0, 0.0, 0.0], "params": {}}


def _default_provenance() -> dict[str, Any]:
    return {"tool_version": __version__, "config_hash": ""}


@dataclass
class Scene4D:
    """A 4D scene: ``static`` is shown at every timestamp, ``dynamic[t]`` only at ``t``.

    ``camera`` is the source panorama's camera: ``{"position": [x, y, z], "params": {...}}``
    with free-form params; ``provenance`` holds ``tool_version`` and ``config_hash``;
    ``extra`` is free-form. All three must be JSON-serialisable. ``antialiased`` is the
    rasteriser mode the scene was trained in, which every render of it must use
    (docs/rasterizer.md); files written before the key existed read as classic (False).
    """

    static: Gaussians
    dynamic: list[Gaussians]
    timestamps: list[float]
    fps: float
    camera: dict[str, Any] = field(default_factory=_default_camera)
    provenance: dict[str, Any] = field(default_factory=_default_provenance)
    extra: dict[str, Any] = field(default_factory=dict)
    antialiased: bool = False

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
        raise TimeIndexError(f"timestamp index {t} out of range: the scene has {num_times}")


def _meta_json(
    timestamps: list[float],
    fps: float,
    camera: dict[str, Any],
    provenance: dict[str, Any],
    extra: dict[str, Any],
    antialiased: bool,
) -> str:
    unknown = set(camera) - {"position", "params"}
    if unknown:
        raise ValueError(
            f"camera keys must be 'position' and 'params', got extra keys {sorted(unknown)}"
        )
    camera = {**_default_camera(), **camera}
    meta = {
        "timestamps": [float(t) for t in timestamps],
        "fps": float(fps),
        "camera": {"position": [float(v) for v in camera["position"]], "params": camera["params"]},
        "provenance": {**_default_provenance(), **provenance},
        "antialiased": bool(antialiased),
        "extra": extra,
    }
    if not all(math.isfinite(v) for v in [*meta["timestamps"], meta["fps"]]):
        raise ValueError("fps and timestamps must be finite")
    try:
        return json.dumps(meta, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise ValueError(f"scene metadata is not JSON-serialisable: {e}") from e


class Ply4dWriter:
    """Writes a ``.ply4d`` one set at a time, so only one set is held in memory::

        with ply4d.Ply4dWriter(path, static) as w:
            for g in dynamic_sets:
                w.push(g)
            w.finish(timestamps, fps)

    Every set is stored at the static set's SH degree (lower degrees are zero-padded).
    A writer closed without ``finish`` (or left by an exception) writes nothing.
    """

    def __init__(self, path: PathLike, static: Gaussians) -> None:
        self.sh_degree = static.sh_degree
        self.num_times = 0
        self._writer = core.Ply4dWriter(os.fspath(path), gaussian_arrays(static))

    def push(self, g: Gaussians) -> None:
        """Append the dynamic set of the next timestamp."""
        if g.sh_degree > self.sh_degree:
            raise ValueError(
                f"dynamic set {self.num_times} has SH degree {g.sh_degree}, above the static "
                f"set's {self.sh_degree}"
            )
        self._writer.push(gaussian_arrays(g.with_sh_degree(self.sh_degree)))
        self.num_times += 1

    def finish(
        self,
        timestamps: list[float],
        fps: float,
        camera: dict[str, Any] | None = None,
        provenance: dict[str, Any] | None = None,
        extra: dict[str, Any] | None = None,
        antialiased: bool = False,
    ) -> None:
        """Write the file (atomically); ``timestamps`` has one entry per pushed set."""
        self._finish(
            _meta_json(timestamps, fps, camera or {}, provenance or {}, extra or {}, antialiased)
        )

    def _finish(self, meta_json: str) -> None:
        self._writer.finish(meta_json)

    def close(self) -> None:
        """Abandon the file unless ``finish`` was called."""
        self._writer.close()

    def __enter__(self) -> Ply4dWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def write(path: PathLike, scene: Scene4D) -> None:
    """Write ``scene`` as a ``.ply4d`` file.

    Sets of a lower SH degree are zero-padded to the scene's highest degree, since all
    sections of a file share one degree.
    """
    degree = max([scene.static.sh_degree] + [g.sh_degree for g in scene.dynamic])
    # Metadata is checked before any set is encoded.
    meta = _meta_json(
        scene.timestamps, scene.fps, scene.camera, scene.provenance, scene.extra, scene.antialiased
    )
    with Ply4dWriter(path, scene.static.with_sh_degree(degree)) as writer:
        for g in scene.dynamic:
            writer.push(g)
        writer._finish(meta)


class Ply4dFile:
    """A ``.ply4d`` file opened lazily (memory-mapped): only the sets asked for are read,
    and each one's checksum is verified when it is read."""

    def __init__(self, path: PathLike) -> None:
        self.path = os.fspath(path)
        with _format_errors():
            self._reader = core.Ply4dReader(self.path)
            self.header: dict[str, Any] = json.loads(self._reader.header_json())

    @property
    def num_times(self) -> int:
        return self._reader.num_times

    @property
    def timestamps(self) -> list[float]:
        return list(self.header["timestamps"])

    @property
    def antialiased(self) -> bool:
        """The mode every render of this scene must use (absent in older files: classic)."""
        return bool(self.header["antialiased"])

    def static(self) -> Gaussians:
        with _format_errors():
            return gaussians_from(self._reader.read_static())

    def dynamic(self, t: int) -> Gaussians:
        _check_time(t, self.num_times)
        with _format_errors():
            return gaussians_from(self._reader.read_dynamic(t))

    def at(self, t: int) -> Gaussians:
        """Static followed by dynamic set ``t``."""
        _check_time(t, self.num_times)
        with _format_errors():
            return gaussians_from(self._reader.read_at(t))

    def verify(self) -> None:
        """Check every section's checksum; raises FormatError on the first mismatch."""
        with _format_errors():
            self._reader.verify()

    def export(self, t: int, path_out: PathLike) -> None:
        """Write timestamp ``t`` (static + dynamic) as a plain 3DGS ``.ply``: a classic
        scene's stored values copied byte for byte, an antialiased one's decoded and baked
        for the classic viewers that read the file (``share_formats.for_classic_viewers``)."""
        _check_time(t, self.num_times)
        if self.antialiased:
            # Imported here: share_formats builds on this module.
            from pano4d.share_formats import for_classic_viewers

            write_ply(path_out, for_classic_viewers(self.at(t), self))
            return
        with _format_errors():
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
            antialiased=self.antialiased,
        )


def open(path: PathLike) -> Ply4dFile:
    """Open a ``.ply4d`` file for lazy, per-timestamp reading."""
    return Ply4dFile(path)


def read(path: PathLike) -> Scene4D:
    """Read a whole ``.ply4d`` file."""
    return Ply4dFile(path).read()


def export(path_in: PathLike, t: int, path_out: PathLike) -> None:
    """Write timestamp ``t`` of a ``.ply4d`` (static + dynamic) as a plain 3DGS ``.ply``
    (``Ply4dFile.export``: an antialiased scene's baked for classic viewers)."""
    Ply4dFile(path_in).export(t, path_out)
