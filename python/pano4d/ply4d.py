"""3DGS ``.ply`` files and the ``.ply4d`` 4D scene format (spec: docs/ply4d.md).

A ``.ply4d`` holds a static set shown at every time and the dynamic Gaussians: one set per
timestamp (format version 1) or one :class:`~pano4d.spacetime.SpacetimeGaussians` for every
time of a looping animation (version 2). Both read the same way:

- ``read(path).at(t)``: the scene's Gaussians at time ``t``, in frames (timestamp indices,
  any real t ≥ 0, taken modulo the loop of ``num_times`` frames: ``loop_time``). A version-2
  scene's dynamic set is evaluated at that real time (``SpacetimeGaussians.at``); a
  version-1 scene holds each timestamp until the next (it shows ⌊t⌋). ``read`` gives a
  :class:`Scene4D` whose ``dynamic`` is a ``list[Gaussians]`` (version 1) or a
  ``SpacetimeGaussians`` (version 2).
- ``open(path)``: a lazy :class:`Ply4dFile` (``version``, ``num_times``, ``timestamps``,
  ``fps``, ``static()``, ``dynamic(t)``, ``at(t)``, ``shown_time(t)``, ``spacetime()`` for
  version 2, ``verify()``, ``export(t, out)``), which decodes only what is asked for.
- ``write(path, scene)`` writes version 2 when ``scene.dynamic`` is a
  ``SpacetimeGaussians``, else version 1; :class:`Ply4dWriter` streams a version-1 file
  one timestamp at a time. ``export(path, t, out)`` writes the scene at time ``t`` as a
  plain 3DGS ``.ply``; ``read_ply``/``write_ply`` read and write those.
- ``playback_time`` and ``loop_samples``: the scene times a playback at some rate shows
  (a video's frames, a browser page's samples), the scene playing at its own fps.

The reading and writing happen in Rust (``pano4d._core``, through ``pano4d.extension``);
sets cross as its ``GaussianArrays`` and ``SpacetimeArrays``, converted by
``pano4d.extension``. Format errors raise ``FormatError`` (a ``ValueError``) and
operating-system errors ``OSError``, both with the Rust message, which names the file; a
time that is NaN, infinite or negative raises ``TimeError``, as does any time of a scene
with no timestamps. Every write is atomic (temporary file in the same folder, fsync,
rename).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from pano4d import __version__
from pano4d.errors import InputError
from pano4d.extension import (
    core,
    gaussian_arrays,
    gaussians_from,
    spacetime_arrays,
    spacetime_from,
)
from pano4d.gaussians import Gaussians
from pano4d.spacetime import SpacetimeGaussians

__all__ = [
    "FormatError",
    "Ply4dFile",
    "Ply4dWriter",
    "Scene4D",
    "TimeError",
    "export",
    "loop_samples",
    "loop_time",
    "open",
    "playback_time",
    "read",
    "read_ply",
    "write",
    "write_ply",
]

PathLike = str | os.PathLike[str]


class FormatError(InputError, ValueError):
    """A .ply or .ply4d file that does not hold what its format says."""


class TimeError(InputError, ValueError):
    """A scene time that is not one: NaN, infinite or negative (or any time of a scene with
    no timestamps)."""


def loop_time(t: float, num_times: int) -> float:
    """Scene time ``t`` (frames, any real ≥ 0) within the loop of ``num_times`` frames:
    ``t mod num_times``, in [0, num_times). The one place a time given to a scene is checked
    and wrapped; a TimeError names a time that is not one."""
    if not (math.isfinite(t) and t >= 0):
        raise TimeError(f"time {t:g}: a scene time is a finite number of frames ≥ 0")
    if num_times == 0:
        raise TimeError(f"time {t:g}: the scene has no timestamps")
    return float(t % num_times)


def _shown_time(t: float, num_times: int, evaluated: bool) -> float:
    """The time whose Gaussians a scene of ``num_times`` timestamps shows at time ``t``
    (``loop_time``): that time itself where the dynamic set is ``evaluated`` at any time (a
    spacetime set, version 2), the timestamp it holds (⌊…⌋) where a set is stored per
    timestamp (version 1)."""
    time = loop_time(t, num_times)
    return time if evaluated else float(math.floor(time))


# A playback time this close to a whole frame is that frame: the rates' rounding must not
# show a version-1 scene's timestamp before it (0.3 fps / 0.1 fps is 2.9999999999999996).
WHOLE_FRAME_SLACK = 1e-9


def playback_time(sample: int, rate: float, fps: float) -> float:
    """The scene time (frames) that sample ``sample`` of a playback at ``rate`` samples a
    second shows (a video's frame, a browser page's step): the scene plays at its own
    ``fps`` whatever the rate, so a 30 fps video of an 8 fps scene advances 8/30 of a
    frame a video frame. Not wrapped: ``loop_time`` does that where the scene is read."""
    t = sample * fps / rate
    whole = round(t)
    return float(whole) if abs(t - whole) <= WHOLE_FRAME_SLACK else t


def loop_samples(num_times: int, fps: float, rate: float) -> int:
    """How many samples at ``rate`` a second one loop of ``num_times`` frames at ``fps``
    takes: ⌈num_times · rate / fps⌉ (0 for a scene with no timestamps)."""
    return math.ceil(num_times * rate / fps - WHOLE_FRAME_SLACK)


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
    """A 4D scene: ``static`` is shown at every time, the dynamic Gaussians at time ``t``
    (frames) only then: ``dynamic[t]`` of one set per timestamp (format version 1, each
    held until the next), or ``dynamic.at(t)`` of one ``SpacetimeGaussians`` (version 2,
    ``timestamps`` one per frame of its loop): ``dynamic_at(t)`` either way, at any real
    t ≥ 0 taken modulo the loop, and ``at(t)`` static and dynamic together.

    ``camera`` is the source panorama's camera: ``{"position": [x, y, z], "params": {...}}``
    with free-form params; ``provenance`` holds ``tool_version`` and ``config_hash``;
    ``extra`` is free-form. All three must be JSON-serialisable. ``antialiased`` is the
    rasteriser mode the scene was trained in, which every render of it must use
    (docs/rasterizer.md); files written before the key existed read as classic (False).
    """

    static: Gaussians
    dynamic: list[Gaussians] | SpacetimeGaussians
    timestamps: list[float]
    fps: float
    camera: dict[str, Any] = field(default_factory=_default_camera)
    provenance: dict[str, Any] = field(default_factory=_default_provenance)
    extra: dict[str, Any] = field(default_factory=dict)
    antialiased: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.dynamic, SpacetimeGaussians):
            period = self.dynamic.model.period
            if len(self.timestamps) != period:
                raise ValueError(
                    f"Scene4D has {len(self.timestamps)} timestamps but its spacetime set "
                    f"loops over {period} frames (one timestamp per frame)"
                )
        elif len(self.timestamps) != len(self.dynamic):
            raise ValueError(
                f"Scene4D has {len(self.timestamps)} timestamps "
                f"but {len(self.dynamic)} dynamic sets"
            )

    @property
    def num_times(self) -> int:
        return len(self.timestamps)

    def dynamic_at(self, t: float) -> Gaussians:
        """The dynamic Gaussians at time ``t`` (frames, any real ≥ 0, ``_shown_time``): the
        spacetime set evaluated there, or the set of the timestamp it holds (⌊t⌋)."""
        evaluated = isinstance(self.dynamic, SpacetimeGaussians)
        time = _shown_time(t, self.num_times, evaluated)
        if isinstance(self.dynamic, SpacetimeGaussians):
            return self.dynamic.at(time)
        return self.dynamic[int(time)]

    def at(self, t: float) -> Gaussians:
        """All Gaussians visible at time ``t`` (``dynamic_at``): static followed by dynamic."""
        return Gaussians.cat([self.static, self.dynamic_at(t)])


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

    or, for version 2, ``w.push_spacetime(s)`` once instead of the pushes (``timestamps``
    then has one time per frame of ``s``'s loop). Every set is stored at the static set's SH
    degree (lower degrees are zero-padded). A writer closed without ``finish`` (or left by
    an exception) writes nothing.
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

    def push_spacetime(self, s: SpacetimeGaussians) -> None:
        """Append the one spacetime set of a version-2 file: the dynamic Gaussians at every
        time."""
        if s.canonical.sh_degree > self.sh_degree:
            raise ValueError(
                f"the spacetime set has SH degree {s.canonical.sh_degree}, above the static "
                f"set's {self.sh_degree}"
            )
        padded = dataclasses.replace(s, canonical=s.canonical.with_sh_degree(self.sh_degree))
        self._writer.push_spacetime(spacetime_arrays(padded))
        self.num_times = s.model.period

    def finish(
        self,
        timestamps: list[float],
        fps: float,
        camera: dict[str, Any] | None = None,
        provenance: dict[str, Any] | None = None,
        extra: dict[str, Any] | None = None,
        antialiased: bool = False,
    ) -> None:
        """Write the file (atomically); ``timestamps`` has one entry per pushed set (per
        frame of the spacetime set's loop)."""
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
    """Write ``scene`` as a ``.ply4d`` file: version 2 when its dynamic part is a
    ``SpacetimeGaussians``, else version 1.

    Sets of a lower SH degree are zero-padded to the scene's highest degree, since all
    sections of a file share one degree.
    """
    dynamic = scene.dynamic
    degrees = (
        [dynamic.canonical.sh_degree]
        if isinstance(dynamic, SpacetimeGaussians)
        else [g.sh_degree for g in dynamic]
    )
    degree = max([scene.static.sh_degree, *degrees])
    # Metadata is checked before any set is encoded.
    meta = _meta_json(
        scene.timestamps, scene.fps, scene.camera, scene.provenance, scene.extra, scene.antialiased
    )
    with Ply4dWriter(path, scene.static.with_sh_degree(degree)) as writer:
        if isinstance(dynamic, SpacetimeGaussians):
            writer.push_spacetime(dynamic)
        else:
            for g in dynamic:
                writer.push(g)
        writer._finish(meta)


class Ply4dFile:
    """A ``.ply4d`` file opened lazily (memory-mapped): only the sets asked for are read,
    and each one's checksum is verified when it is read. A version-2 file's spacetime set
    is decoded once, on first use, and evaluated at each time asked for: keep one
    ``Ply4dFile`` open for a whole playback."""

    def __init__(self, path: PathLike) -> None:
        self.path = os.fspath(path)
        with _format_errors():
            self._reader = core.Ply4dReader(self.path)
            self.header: dict[str, Any] = json.loads(self._reader.header_json())
        self._spacetime: SpacetimeGaussians | None = None

    @property
    def version(self) -> int:
        """The format version: 1, a dynamic set per timestamp; 2, one spacetime set."""
        return int(self.header["format_version"])

    @property
    def num_times(self) -> int:
        """Timestamps: dynamic sets (version 1), frames of the loop (version 2)."""
        return self._reader.num_times

    @property
    def timestamps(self) -> list[float]:
        return list(self.header["timestamps"])

    @property
    def fps(self) -> float:
        """Timestamps a second: the rate the scene plays at."""
        return float(self.header["fps"])

    @property
    def antialiased(self) -> bool:
        """The mode every render of this scene must use (absent in older files: classic)."""
        return bool(self.header["antialiased"])

    def static(self) -> Gaussians:
        with _format_errors():
            return gaussians_from(self._reader.read_static())

    def spacetime(self) -> SpacetimeGaussians:
        """The spacetime set of a version-2 file, as stored (decoded once; FormatError for a
        version-1 file)."""
        if self._spacetime is None:
            with _format_errors():
                self._spacetime = spacetime_from(self._reader.read_spacetime())
        return self._spacetime

    def shown_time(self, t: float) -> float:
        """The time whose Gaussians the scene shows at time ``t`` (frames, any real ≥ 0):
        ``t`` within the loop (``loop_time``) for version 2, the timestamp it holds (⌊…⌋)
        for version 1. Two times show the same Gaussians when their shown times are equal,
        so a playback reads a version-1 set once for every time that shows it."""
        return _shown_time(t, self.num_times, evaluated=self.version == 2)

    def dynamic(self, t: float) -> Gaussians:
        """The dynamic Gaussians at time ``t`` (``shown_time``): version 2, the spacetime set
        evaluated there; version 1, the stored set of the timestamp it holds."""
        time = self.shown_time(t)
        if self.version == 2:
            return self.spacetime().at(time)
        with _format_errors():
            return gaussians_from(self._reader.read_dynamic(int(time)))

    def at(self, t: float) -> Gaussians:
        """Static followed by the dynamic Gaussians at time ``t`` (``dynamic``)."""
        time = self.shown_time(t)
        if self.version == 2:
            return Gaussians.cat([self.static(), self.dynamic(time)])
        with _format_errors():
            return gaussians_from(self._reader.read_at(int(time)))

    def verify(self) -> None:
        """Check every section's checksum; raises FormatError on the first mismatch."""
        with _format_errors():
            self._reader.verify()

    def export(self, t: float, path_out: PathLike) -> None:
        """Write the scene at time ``t`` (static + dynamic, ``at``) as a plain 3DGS ``.ply``:
        a classic version-1 scene's stored values copied byte for byte, a version-2 one's
        evaluated at ``t``, an antialiased one's baked for the classic viewers that read the
        file (``share_formats.for_classic_viewers``)."""
        time = self.shown_time(t)
        if self.antialiased:
            # Imported here: share_formats builds on this module.
            from pano4d.share_formats import for_classic_viewers

            write_ply(path_out, for_classic_viewers(self.at(time), self))
        elif self.version == 2:
            write_ply(path_out, self.at(time))
        else:
            with _format_errors():
                self._reader.export_ply(int(time), os.fspath(path_out))

    def read(self) -> Scene4D:
        """Decode the whole scene."""
        h = self.header
        dynamic = (
            self.spacetime()
            if self.version == 2
            else [self.dynamic(t) for t in range(self.num_times)]
        )
        return Scene4D(
            static=self.static(),
            dynamic=dynamic,
            timestamps=list(h["timestamps"]),
            fps=h["fps"],
            camera=h["camera"],
            provenance=h["provenance"],
            extra=h["extra"],
            antialiased=self.antialiased,
        )


def open(path: PathLike) -> Ply4dFile:
    """Open a ``.ply4d`` file for lazy reading, time by time."""
    return Ply4dFile(path)


def read(path: PathLike) -> Scene4D:
    """Read a whole ``.ply4d`` file."""
    return Ply4dFile(path).read()


def export(path_in: PathLike, t: float, path_out: PathLike) -> None:
    """Write a ``.ply4d`` at time ``t`` (frames; static + dynamic) as a plain 3DGS ``.ply``
    (``Ply4dFile.export``: an antialiased scene's baked for classic viewers)."""
    Ply4dFile(path_in).export(t, path_out)
