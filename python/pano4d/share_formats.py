"""``pano4d export``: a timestamp of a .ply4d, or every timestamp as a numbered sequence, in
the formats people share splats in: plain 3DGS .ply, SuperSplat's .compressed.ply, Niantic's
SPZ (version 4), PlayCanvas's SOG (the bundled .sog zip) and .splat.

The plain .ply is our own writer (``ply4d``: bit-exact float32); the others are encoded by
gaussforge from our arrays. gaussforge writes every format at SH degree 0, but refuses to
read (and so to convert) an SH-0 .ply, which every draft scene is: so nothing goes through
a .ply on the way. A 4D scene is shared as a folder of ``frame_0000.<ext>``…, the numbered
sequence SuperSplat's timeline plays.
"""

from __future__ import annotations

import errno
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pano4d import ply4d
from pano4d.errors import InputError
from pano4d.fsutil import atomic_path
from pano4d.gaussians import Gaussians


@dataclass(frozen=True)
class ShareFormat:
    suffix: str  # the file name's ending, with its dot
    gaussforge: str | None  # gaussforge's name for it; None: our own writer


FORMATS = {
    "ply": ShareFormat(".ply", None),
    "compressed-ply": ShareFormat(".compressed.ply", "compressed.ply"),
    "spz": ShareFormat(".spz", "spz"),
    "sog": ShareFormat(".sog", "sog"),
    "splat": ShareFormat(".splat", "splat"),
}
# SPZ version 4 (zstd) is what Niantic's library, PlayCanvas and SuperSplat write and read
# today; PlayCanvas reads no other.
SPZ_VERSION = 4
# A .compressed.ply quantises each run of this many Gaussians, in file order, within the
# run's own bounding box (position to 11/10/11 bits).
COMPRESSED_PLY_CHUNK = 256
MORTON_BITS = 21  # per axis: three of them fill a 64-bit code
TRANSPARENT_LOGIT = -30.0  # sigmoid ≈ 1e-13: opacity 0 in the format's 8 bits


class ExportArgumentError(InputError, ValueError):
    """A --format, --time or --sequence that ``pano4d export`` cannot use."""


def check_format(name: str) -> ShareFormat:
    """The format named ``--format``, or an ExportArgumentError listing them."""
    if name not in FORMATS:
        raise ExportArgumentError(
            f"--format {name!r} is not one pano4d writes; use one of {', '.join(FORMATS)}"
        )
    return FORMATS[name]


def format_of(out: Path) -> str:
    """The format an output file's name asks for (its ending), .ply when none does."""
    name = out.name.lower()
    known = [key for key, f in FORMATS.items() if name.endswith(f.suffix)]
    # .compressed.ply also ends in .ply: the longest ending wins.
    return max(known, key=lambda key: len(FORMATS[key].suffix), default="ply")


def morton_codes(points: np.ndarray) -> np.ndarray:
    """(N,) uint64: each point's place along a Z-order curve through the points' bounds."""
    lo, hi = points.min(0), points.max(0)
    cells = (points - lo) / np.maximum(hi - lo, 1e-12) * (2**MORTON_BITS - 1)
    q = cells.astype(np.uint64)
    code = np.zeros(len(points), np.uint64)
    for bit in range(MORTON_BITS):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return code


def compressed_ply_chunks(g: Gaussians) -> Gaussians:
    """``g`` reordered (and padded) so that each run of COMPRESSED_PLY_CHUNK Gaussians is small
    for its distance from the viewpoint (the origin).

    A panorama's scene spans a few units around the viewpoint to the sky's thousand. In the
    order training leaves them, or along one Z-order curve (which leaps across the scene
    between neighbouring cells), a run holds a near Gaussian and a far one, and its box's
    quantisation step (extent / 2048) moves the near one by a tenth of its distance. So the
    Gaussians go by octave of distance, along a Z-order curve within each octave; a run that
    straddles two neighbouring octaves keeps a step within a few thousandths of its distance.
    Where octaves are empty between two groups (a room and the sky through its window), no run
    may straddle the gap: the nearer group is padded to whole runs with fully transparent
    copies of its last Gaussian (at most COMPRESSED_PLY_CHUNK − 1 per gap; none on a scene
    whose depth is continuous, as a real panorama's is)."""
    if len(g) == 0:
        return g
    means = g.means.detach().cpu().numpy()
    octave = np.floor(np.log2(np.maximum(np.linalg.norm(means, axis=1), 1e-6))).astype(np.int64)
    order = np.lexsort((morton_codes(means), octave))
    ordered = g[torch.from_numpy(order)]
    octaves = octave[order]
    # Group ends: where the next Gaussian lies two or more octaves further out.
    ends = [int(i) + 1 for i in np.nonzero(np.diff(octaves) > 1)[0]]
    parts, start = [], 0
    for end in ends:
        group = ordered[start:end]
        missing = -len(group) % COMPRESSED_PLY_CHUNK
        filler = group[torch.full((missing,), len(group) - 1)]
        filler.opacity_logits = torch.full_like(filler.opacity_logits, TRANSPARENT_LOGIT)
        parts += [group, filler]
        start = end
    return Gaussians.cat([*parts, ordered[start:]])


def encode(g: Gaussians, fmt: ShareFormat) -> bytes:
    """``g`` in a gaussforge format, encoded from its arrays (no .ply in between)."""
    import gaussforge

    if fmt.gaussforge == "compressed.ply":
        g = compressed_ply_chunks(g)
    arrays = {name: np.ascontiguousarray(a, dtype="<f4") for name, a in g.to_numpy().items()}
    sh = arrays["sh"]
    rest = sh[:, 1:, :]
    if fmt.gaussforge == "compressed.ply":
        # gaussforge 0.6 writes a compressed.ply's f_rest in its arrays' order, coefficient
        # by coefficient, where the format (SuperSplat, gsply, our reader, and its own plain
        # .ply writer) goes channel by channel: hand it the coefficients transposed.
        rest = rest.transpose(0, 2, 1)
    ir = {
        "numPoints": len(g),
        "positions": arrays["means"].tobytes(),
        "scales": arrays["log_scales"].tobytes(),
        "rotations": arrays["quats"].tobytes(),  # (w, x, y, z), as .ply's rot_0..3
        "alphas": arrays["opacity_logits"].tobytes(),
        "colors": np.ascontiguousarray(sh[:, 0, :]).tobytes(),  # the DC term, f_dc
        "sh": np.ascontiguousarray(rest).tobytes(),  # (N, coefficient, channel)
        "meta": {"shDegree": g.sh_degree},
    }
    assert fmt.gaussforge is not None
    result = gaussforge.GaussForge().write(ir, fmt.gaussforge, spz_version=SPZ_VERSION)
    if "error" in result:
        raise RuntimeError(f"gaussforge could not write {fmt.gaussforge}: {result['error']}")
    return bytes(result["data"])


def write(g: Gaussians, out: Path, fmt: ShareFormat) -> None:
    """Write ``g`` to ``out`` in ``fmt``, atomically."""
    if fmt.gaussforge is None:
        ply4d.write_ply(out, g)  # atomic itself
        return
    data = encode(g, fmt)
    with atomic_path(out) as tmp:
        tmp.write_bytes(data)
        tmp.chmod(0o644)  # as the .ply writer leaves it: mkstemp's 0600 hides it from others


def export(
    scene: Path,
    out: Path,
    fmt_name: str | None = None,
    time: int | None = None,
    sequence: bool = False,
    on_time: Callable[[], None] = lambda: None,
) -> list[Path]:
    """Write timestamp ``time`` (default 0) of ``scene`` to the file ``out``, or with
    ``sequence`` every timestamp into the new folder ``out`` as ``frame_0000.<ext>``….
    ``fmt_name`` None takes the format from ``out``'s ending. Returns the files written;
    ``on_time`` is called after each timestamp."""
    if sequence and time is not None:
        raise ExportArgumentError(
            f"--sequence writes every timestamp; it takes no --time (got --time {time})"
        )
    fmt = check_format(fmt_name if fmt_name is not None else format_of(out))
    source = ply4d.open(scene)
    if not sequence:
        write(source.at(0 if time is None else time), out, fmt)
        on_time()
        return [out]
    if out.exists() and not (out.is_dir() and not any(out.iterdir())):
        raise ExportArgumentError(f"{out} exists and is not an empty folder; choose a new one")
    out.parent.mkdir(parents=True, exist_ok=True)
    # Built beside its place and renamed into it: a failure leaves no half-written sequence.
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        tmp.chmod(0o755)  # mkdtemp's 0700 would hide the frames from a web server's user
        names = [f"frame_{t:04d}{fmt.suffix}" for t in range(source.num_times)]
        for t, name in enumerate(names):
            write(source.at(t), tmp / name, fmt)
            on_time()
        if out.exists():
            out.rmdir()
        tmp.rename(out)
    except BaseException as error:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(error, OSError) and error.errno == errno.ENOSPC:
            # Named by the folder asked for, not the hidden one it was being built in.
            raise OSError(error.errno, error.strerror, str(out)) from error
        raise
    return [out / name for name in names]
