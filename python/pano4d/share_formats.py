"""``pano4d export``: a .ply4d at one time, or every timestamp as a numbered sequence, in
the formats people share splats in: plain 3DGS .ply, SuperSplat's .compressed.ply, Niantic's
SPZ (version 4), PlayCanvas's SOG (the bundled .sog zip) and .splat.

The plain .ply is our own writer (``ply4d``: bit-exact float32); the others are encoded by
gaussforge from our arrays. gaussforge writes every format at SH degree 0, but refuses to
read (and so to convert) an SH-0 .ply, which every draft scene is: so nothing goes through
a .ply on the way. A 4D scene is shared as a folder of ``frame_0000.<ext>``…, the numbered
sequence SuperSplat's timeline plays.

Every other viewer draws classic (docs/rasterizer.md): the 0.3 px² low-pass without the
antialiased mode's opacity compensation. A scene trained antialiased is therefore handed to
them with that compensation baked into its opacities (``for_classic_viewers``): here, in
``ply4d.Ply4dFile.export`` and in ``pano4d serve``/``web`` (``web.add_scene``).
"""

from __future__ import annotations

import errno
import math
import shutil
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pano4d import ply4d
from pano4d.camera import focal_length
from pano4d.errors import InputError
from pano4d.fsutil import atomic_path
from pano4d.gaussians import Gaussians
from pano4d.raster_torch import LOW_PASS, NEAR_PLANE, antialiasing_factor, covariance_factor


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


def bake_antialiasing(g: Gaussians, viewpoint: Sequence[float], focal_px: float) -> Gaussians:
    """``g``, trained in the antialiased mode, with its opacities scaled for a classic
    rasteriser: each Gaussian seen from ``viewpoint`` at a focal length of ``focal_px``
    pixels then draws the integral (opacity × area) the antialiased mode draws. Only
    opacities change. (The shapes differ by the two modes' filters, Σ2D + LOW_PASS·I
    against Σ2D + MIP_FILTER·I: a sub-pixel Gaussian comes out a little wider and fainter.)

    The factor sqrt(det Σ2D / det(Σ2D + LOW_PASS·I)) depends on the view. Σ2D is taken here
    as (f/d)²·P Σ Pᵀ: the 3D covariance Σ projected onto an orthonormal pair P across the
    line of sight from ``viewpoint`` (distance d), which is exactly what a pinhole camera
    there sees of a Gaussian at its image centre. Towards a pinhole image's edges the
    pixels grow denser (by 1/cos³ of the angle off the axis, in area), and from elsewhere
    the factor differs again: there the bake is approximate.

    A Gaussian with a non-finite parameter (which every pano4d render culls) or nearer
    ``viewpoint`` than NEAR_PLANE (which no camera there draws) is kept as it is; one whose
    footprint has no area (det Σ2D ≤ 0: the antialiased mode draws nothing of it) becomes
    transparent.
    """
    if not (math.isfinite(focal_px) and focal_px > 0):
        raise ValueError(f"focal_px must be finite and positive, got {focal_px}")
    origin = torch.as_tensor(viewpoint, dtype=torch.float64, device=g.device)
    if origin.shape != (3,) or not torch.isfinite(origin).all():
        raise ValueError(f"viewpoint must be three finite numbers, got {viewpoint}")
    means, log_scales, quats, logits = (
        t.to(torch.float64) for t in (g.means, g.log_scales, g.quats, g.opacity_logits)
    )
    finite = torch.stack(
        [torch.isfinite(t.reshape(len(g), -1)).all(-1) for t in g.tensors().values()], dim=-1
    ).all(-1)
    offset = means - origin
    distance = torch.linalg.norm(offset, dim=-1)
    baked = finite & (distance >= NEAR_PLANE)
    # The rows not baked may hold NaN from here on: the last line keeps their logits.
    sight = offset / distance[:, None]
    # Any orthonormal pair across the line of sight will do: the factor depends only on
    # Σ2D's determinant and trace. The helper axis is one far from the line of sight.
    z_axis, x_axis = torch.eye(3, dtype=torch.float64, device=g.device)[[2, 0]]
    helper = torch.where(sight[:, 2:].abs() < 0.9, z_axis, x_axis)
    across = torch.nn.functional.normalize(torch.linalg.cross(sight, helper), dim=-1)
    P = torch.stack([across, torch.linalg.cross(sight, across)], dim=1)  # (N, 2, 3)
    T = (focal_px / distance)[:, None, None] * (P @ covariance_factor(log_scales, quats))
    cov2d = T @ T.transpose(1, 2)
    a, b, c = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    factor = antialiasing_factor(a * c - b * b, (a + LOW_PASS) * (c + LOW_PASS) - b * b)
    # logit(σ(o)·k) = log k + log σ(o) − log(1 − k·σ(o)), with 1 − k·σ(o) written as
    # (1 − k) + k·σ(−o), which stays accurate for an opaque Gaussian (σ(o) → 1). The
    # factor is at most 1: the minimum with o only catches 1 − k·σ(o) rounding to 0.
    k = torch.where(factor > 0, factor, torch.ones_like(factor))
    compensated = torch.minimum(
        torch.log(k)
        + torch.nn.functional.logsigmoid(logits)
        - torch.log((1 - k) + k * torch.sigmoid(-logits)),
        logits,
    )
    compensated = torch.where(factor > 0, compensated, torch.full_like(k, TRANSPARENT_LOGIT))
    new_logits = torch.where(baked, compensated.to(g.opacity_logits), g.opacity_logits)
    return Gaussians(g.means, g.log_scales, g.quats, new_logits, g.sh)


def for_classic_viewers(g: Gaussians, scene: ply4d.Ply4dFile) -> Gaussians:
    """``g``, a set of ``scene``, as a viewer that draws classic must receive it: unchanged
    for a classic scene; for an antialiased one, baked (``bake_antialiasing``) at its
    training views' pixel density, from the panorama's position they all look out from."""
    if not scene.antialiased:
        return g
    camera = scene.header.get("camera", {})
    params = camera.get("params", {})
    try:
        viewpoint = [float(v) for v in camera["position"]]
        fov_deg, view_size = float(params["fov_deg"]), float(params["view_size"])
    except (KeyError, TypeError, ValueError) as e:
        raise ply4d.FormatError(
            f"{scene.path}: an antialiased scene needs camera.position and camera.params "
            f"fov_deg and view_size (its training views) to be drawn by other viewers; "
            f"got camera {camera}"
        ) from e
    if not (
        0 < fov_deg < 180
        and 0 < view_size < math.inf
        and len(viewpoint) == 3
        and all(math.isfinite(v) for v in viewpoint)
    ):
        raise ply4d.FormatError(
            f"{scene.path}: camera.params fov_deg {fov_deg} and view_size {view_size} (or "
            f"camera.position {viewpoint}) are not a training view's"
        )
    return bake_antialiasing(g, viewpoint, focal_length(fov_deg, view_size))


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
    time: float | None = None,
    sequence: bool = False,
    on_time: Callable[[], None] = lambda: None,
) -> list[Path]:
    """Write ``scene`` at ``time`` (frames, default 0: ``ply4d.Ply4dFile.at``, a version-2
    scene evaluated at that real time) to the file ``out``, or with ``sequence`` every
    timestamp into the new folder ``out`` as ``frame_0000.<ext>``….
    ``fmt_name`` None takes the format from ``out``'s ending. Returns the files written;
    ``on_time`` is called after each timestamp."""
    if sequence and time is not None:
        raise ExportArgumentError(
            f"--sequence writes every timestamp; it takes no --time (got --time {time:g})"
        )
    fmt = check_format(fmt_name if fmt_name is not None else format_of(out))
    source = ply4d.open(scene)
    if not sequence:
        write(for_classic_viewers(source.at(0.0 if time is None else time), source), out, fmt)
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
            write(for_classic_viewers(source.at(t), source), tmp / name, fmt)
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
