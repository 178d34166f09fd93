"""Image, depth, mask and video files (docs/design.md, "Conventions").

Inside the pipeline images are float32 (H, W, C) in [0, 1]: the file's values, no colour
conversion. 8/16-bit PNG and JPEG are divided by 255 / 65535; EXR keeps its float values.
Every reader raises ``ImageError`` (a ValueError) with the path and what is wrong; every
writer goes through a temporary file and a rename, so a reader never sees half a file.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from pano4d.errors import InputError
from pano4d.fsutil import atomic_path

PathLike = str | os.PathLike[str]

PANORAMA_MIN_WIDTH = 512
PANORAMA_MIN_HEIGHT = 256
WRITABLE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr")
JPEG_QUALITY = 95
# libpng's default tries all five row filters on every row and keeps the best; the "sub"
# filter alone with zlib level 1 writes a 16-bit frame crop of a 6144×3072 photo 2–3× faster
# than that at level 3, 10 % larger (bench/RESULTS.md, "The animating phase at the working
# size"). Level 3 with every filter was itself 3× faster than zlib's default 6.
PNG_ZLIB_LEVEL = 1
PNG_FILTER_SUB = 16  # libpng's PNG_FILTER_SUB
# A complete PNG ends with the IEND chunk; libpng reads the pixels without it and says
# nothing, so a copy cut off in the last few bytes would otherwise pass as whole.
_PNG_IEND = b"IEND\xaeB`\x82"
# ffmpeg's encoder arguments for write_video's codecs.
VIDEO_CODECS = {
    "h264": ("-c:v", "libx264"),
    "h265": ("-c:v", "libx265", "-tag:v", "hvc1", "-x265-params", "log-level=error"),
}


class ImageError(InputError, ValueError):
    """An image file that is missing, unreadable, or not what the pipeline needs."""


# --- reading ----------------------------------------------------------------------------
def read_image(path: PathLike) -> np.ndarray:
    """Read an image as float32 (H, W, C): [0, 1] for 8/16-bit files, stored values for float.

    Raises ImageError for a missing, unreadable, truncated or corrupt file.
    """
    path = _existing_file(path, "image")
    inp = oiio.ImageInput.open(str(path), _keep_alpha_as_stored())
    if inp is None:
        raise ImageError(f"{path}: cannot read this image: {_oiio_error() or 'unknown format'}")
    try:
        spec = inp.spec()
        base = spec.format.basetype
        if base == oiio.UINT8:
            raw = inp.read_image(0, 0, 0, spec.nchannels, "uint8")
            scale = 255.0
        elif base == oiio.UINT16:
            raw = inp.read_image(0, 0, 0, spec.nchannels, "uint16")
            scale = 65535.0
        else:
            raw = inp.read_image(0, 0, 0, spec.nchannels, "float")
            scale = 1.0
        # libjpeg fills a truncated file with grey and only warns: any message is fatal.
        error = inp.geterror()
    finally:
        inp.close()
    if raw is None or error:
        detail = " ".join((error or _oiio_error() or "read failed").split())
        raise ImageError(f"{path}: corrupt or truncated image ({detail})")
    if path.suffix.lower() == ".png" and _PNG_IEND not in _tail(path, 64):
        raise ImageError(f"{path}: truncated PNG (the file does not end with an IEND chunk)")
    image = np.asarray(raw)
    if image.ndim == 2:
        image = image[:, :, None]
    if scale == 1.0:
        return np.ascontiguousarray(image, dtype=np.float32)
    return image.astype(np.float32) / np.float32(scale)


def image_size(path: PathLike) -> tuple[int, int]:
    """(width, height) from the file's header, without decoding the pixels."""
    spec = _header(_existing_file(path, "image"))
    return int(spec.width), int(spec.height)


def below_panorama_minimum(width: int, height: int) -> bool:
    """Whether a width×height panorama is smaller than the least the pipeline reads
    (PANORAMA_MIN_WIDTH × PANORAMA_MIN_HEIGHT); ``pano4d synth`` refuses to write one."""
    return width < PANORAMA_MIN_WIDTH or height < PANORAMA_MIN_HEIGHT


def read_panorama(path: PathLike) -> np.ndarray:
    """Read an equirectangular panorama as float32 RGB (H, W, 3) in [0, 1].

    Checks the 2:1 aspect, the minimum size (512×256) and finite values in [0, 1]; grey
    is expanded to RGB and an alpha channel dropped.
    """
    image = read_image(path)
    height, width = image.shape[:2]
    if width != 2 * height:
        raise ImageError(f"{path}: {_aspect_problem(width, height)}")
    if below_panorama_minimum(width, height):
        raise ImageError(
            f"{path}: panorama is {width}×{height}, smaller than the minimum "
            f"{PANORAMA_MIN_WIDTH}×{PANORAMA_MIN_HEIGHT}; use a larger panorama "
            f"(upscale it to at least {PANORAMA_MIN_WIDTH}×{PANORAMA_MIN_HEIGHT})"
        )
    image = _to_rgb(image, path)
    _check_finite(image, path, "panorama")
    low, high = float(image.min()), float(image.max())
    if low < 0.0 or high > 1.0:
        raise ImageError(
            f"{path}: panorama values span [{low:.4g}, {high:.4g}], expected [0, 1]; "
            "tone-map an HDR panorama to an 8/16-bit PNG first"
        )
    return image


def read_depth(path: PathLike, png_metres_per_unit: float = 0.001) -> np.ndarray:
    """Read a one-channel depth map (H, W) float32.

    EXR: the stored floats. 16-bit PNG: integer steps of ``png_metres_per_unit`` (millimetres
    by default). Rejects NaN/Inf and non-positive depth with the count and a location.
    """
    path = Path(path)
    image = read_image(path)
    channels = image.shape[2]
    if channels != 1:
        raise ImageError(f"{path}: a depth map has one channel, this file has {channels}")
    depth = image[:, :, 0]
    if path.suffix.lower() == ".png":
        bits = _file_bits(path)
        if bits != 16:
            raise ImageError(
                f"{path}: a PNG depth map must be 16-bit, this one is {bits}-bit "
                "(too coarse for depth); write an EXR or a 16-bit PNG"
            )
        depth = (depth * np.float32(65535.0)).round() * np.float32(png_metres_per_unit)
    _check_finite(depth, path, "depth")
    nonpositive = depth <= 0.0
    if nonpositive.any():
        rows, cols = np.nonzero(nonpositive)
        raise ImageError(
            f"{path}: {int(nonpositive.sum())} depth values are ≤ 0 (first at row {rows[0]}, "
            f"column {cols[0]}: {depth[rows[0], cols[0]]:g}); depth must be positive "
            "(give sky and unbounded regions a finite far depth)"
        )
    return np.ascontiguousarray(depth, dtype=np.float32)


def read_mask(path: PathLike, width: int, height: int) -> np.ndarray:
    """Read a mask as bool (height, width): True where the file is white (> 0.5).

    A mask of another size with the same aspect is resized with nearest neighbour; another
    aspect is an error. Colour masks use the mean of their colour channels.
    """
    image = read_image(path)
    mask_height, mask_width, channels = image.shape
    if channels in (2, 4):
        image = image[:, :, : channels - 1]
    mask = image.mean(axis=2) > 0.5
    if (mask_width, mask_height) == (width, height):
        return mask
    if mask_width * height != mask_height * width:
        raise ImageError(
            f"{path}: mask is {mask_width}×{mask_height}, expected {width}×{height} "
            "(or any size with the same aspect, which is resized)"
        )
    rows = ((np.arange(height) + 0.5) * mask_height / height).astype(np.int64)
    cols = ((np.arange(width) + 0.5) * mask_width / width).astype(np.int64)
    return mask[rows[:, None], cols[None, :]]


# --- writing ----------------------------------------------------------------------------
def write_image(path: PathLike, image: np.ndarray, bits: int | None = None) -> None:
    """Write float image data (H, W) or (H, W, C) atomically.

    .png: 8 (default) or 16 bits, values clipped to [0, 1] and rounded. .jpg: 8 bits,
    1 or 3 channels, quality 95. .exr: 32-bit float (default) or 16 (half), values as given.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in WRITABLE_SUFFIXES:
        raise ImageError(
            f"{path}: cannot write '{suffix}' files; use one of {', '.join(WRITABLE_SUFFIXES)}"
        )
    allowed_bits = {".png": (8, 16), ".jpg": (8,), ".jpeg": (8,), ".exr": (16, 32)}[suffix]
    if bits is None:
        bits = allowed_bits[-1] if suffix == ".exr" else allowed_bits[0]
    if bits not in allowed_bits:
        raise ImageError(f"{path}: {suffix} files take bits in {allowed_bits}, got {bits}")
    pixels = _as_hwc(np.asarray(image), path)
    height, width, channels = pixels.shape
    if suffix in (".jpg", ".jpeg") and channels not in (1, 3):
        raise ImageError(f"{path}: JPEG stores 1 or 3 channels, got {channels}")
    if suffix == ".exr":
        data, fmt = pixels.astype(np.float32), ("half" if bits == 16 else "float")
    else:
        _check_finite(pixels, path, "image")
        top = (1 << bits) - 1
        dtype = np.uint8 if bits == 8 else np.uint16
        scaled = pixels.astype(np.float32) * np.float32(top)
        np.clip(scaled, 0.0, top, out=scaled)
        data = np.rint(scaled, out=scaled).astype(dtype)
        fmt = "uint8" if bits == 8 else "uint16"
    spec = _keep_alpha_as_stored(oiio.ImageSpec(width, height, channels, fmt))
    if suffix in (".jpg", ".jpeg"):
        spec.attribute("Compression", f"jpeg:{JPEG_QUALITY}")
    elif suffix == ".png":
        spec.attribute("png:compressionLevel", PNG_ZLIB_LEVEL)
        spec.attribute("png:filter", PNG_FILTER_SUB)
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise ImageError(f"{path}: no writer for {suffix}: {_oiio_error()}")
        try:
            written = out.open(str(tmp), spec) and out.write_image(np.ascontiguousarray(data))
            # The PNG writer reports a failed write (a full disk) only through geterror().
            error = out.geterror()
            if not written or error:
                raise ImageError(f"{path}: write failed: {' '.join(error.split()[:40])}")
        finally:
            out.close()


def write_video(
    path: PathLike, frames: Iterable[np.ndarray], fps: float, codec: str = "h264"
) -> int:
    """Encode frames (H, W, 3) float in [0, 1] or uint8 as an MP4 through ffmpeg, H.264 or
    (``codec="h265"``) H.265, tagged hvc1 as Apple's and headsets' players want it.

    Odd sizes are padded by one pixel (yuv420p needs even sizes). The file appears only
    when encoding succeeded. Returns the number of frames written.
    """
    path = Path(path)
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None:
        raise ImageError(
            f"{path}: ffmpeg is not on PATH; install it (apt-get install ffmpeg) to write videos"
        )
    if not (fps > 0 and math.isfinite(fps)):
        raise ImageError(f"{path}: fps must be a positive number, got {fps}")
    iterator = iter(frames)
    first = next(iterator, None)
    if first is None:
        raise ImageError(f"{path}: no frames to write")
    first = _video_frame(first, path, 0, None)
    height, width = first.shape[:2]
    count = 0
    with atomic_path(path) as tmp, tempfile.TemporaryFile() as log:
        command = [
            ffmpeg, "-hide_banner", "-loglevel", "error", "-y",
            "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}", "-r", f"{fps}",
            "-i", "-",
            "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2",
            *VIDEO_CODECS[codec], "-pix_fmt", "yuv420p", "-crf", "18",
            "-movflags", "+faststart", "-f", "mp4", str(tmp),
        ]  # fmt: skip
        process = subprocess.Popen(command, stdin=subprocess.PIPE, stderr=log)
        assert process.stdin is not None
        try:
            frame = first
            while frame is not None:
                process.stdin.write(frame.tobytes())
                count += 1
                following = next(iterator, None)
                frame = None if following is None else _video_frame(following, path, count, first)
            process.stdin.close()
        except BrokenPipeError:
            pass  # ffmpeg stopped early; its log below says why
        except BaseException:
            process.kill()
            process.wait()
            raise
        if process.wait() != 0:
            log.seek(0)
            message = log.read().decode(errors="replace").strip()
            raise ImageError(f"{path}: ffmpeg failed (exit {process.returncode}): {message}")
    return count


def write_contact_sheet(
    path: PathLike,
    images: Sequence[np.ndarray],
    columns: int,
    labels: Sequence[str] | None = None,
    bits: int | None = None,
) -> None:
    """Tile images into a grid (row-major, ``columns`` wide) and write it with write_image.

    Cells take the largest image size; smaller images sit at the cell's top-left on a dark
    grey background. Labels are drawn in the cell's top-left corner.
    """
    path = Path(path)
    if not images:
        raise ImageError(f"{path}: no images for the contact sheet")
    if columns < 1:
        raise ImageError(f"{path}: columns must be ≥ 1, got {columns}")
    if labels is not None and len(labels) != len(images):
        raise ImageError(f"{path}: {len(labels)} labels for {len(images)} images")
    tiles = [_to_rgb(_as_hwc(np.asarray(image, dtype=np.float32), path), path) for image in images]
    cell_h = max(tile.shape[0] for tile in tiles)
    cell_w = max(tile.shape[1] for tile in tiles)
    gap = 4
    rows = math.ceil(len(tiles) / columns)
    sheet = np.full(
        (rows * cell_h + (rows + 1) * gap, columns * cell_w + (columns + 1) * gap, 3),
        0.15,
        dtype=np.float32,
    )
    for index, tile in enumerate(tiles):
        top = gap + (index // columns) * (cell_h + gap)
        left = gap + (index % columns) * (cell_w + gap)
        sheet[top : top + tile.shape[0], left : left + tile.shape[1]] = tile
    if labels is not None:
        sheet = _draw_labels(sheet, labels, columns, cell_w, cell_h, gap)
    write_image(path, sheet, bits)


# --- helpers ----------------------------------------------------------------------------
def _existing_file(path: PathLike, what: str) -> Path:
    path = Path(path)
    if not path.exists():
        raise ImageError(f"{path}: {what} file not found")
    if not path.is_file():
        raise ImageError(f"{path}: expected an {what} file, found a directory or special file")
    return path


def _keep_alpha_as_stored(spec: oiio.ImageSpec | None = None) -> oiio.ImageSpec:
    """Ask OIIO not to premultiply PNG colour by alpha on read (nor divide on write)."""
    spec = spec if spec is not None else oiio.ImageSpec()
    spec.attribute("oiio:UnassociatedAlpha", 1)
    return spec


def _oiio_error() -> str:
    return " ".join(oiio.geterror().split())


def _tail(path: Path, size: int) -> bytes:
    with open(path, "rb") as f:
        f.seek(max(0, path.stat().st_size - size))
        return f.read()


def _header(path: Path) -> oiio.ImageSpec:
    """The file's image spec, read without decoding the pixels."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ImageError(f"{path}: cannot read this image: {_oiio_error()}")
    try:
        return oiio.ImageSpec(inp.spec())
    finally:
        inp.close()


def _file_bits(path: Path) -> int:
    return _header(path).format.size() * 8


def _aspect_problem(width: int, height: int) -> str:
    """Say why width×height is not 2:1 and the two exact sizes that would fix it."""
    if width > 2 * height:
        even_width = width + width % 2
        pad = f"pad it top and bottom to {even_width}×{even_width // 2}"
        crop = f"crop its width to {2 * height}×{height}"
    else:
        pad = f"pad it left and right to {2 * height}×{height}"
        half = width // 2
        crop = f"crop its height to {2 * half}×{half}"
    return (
        f"panorama is {width}×{height} (aspect {width / height:.3f}:1), an equirectangular "
        f"panorama must be exactly 2:1; {pad} or {crop}"
    )


def _to_rgb(image: np.ndarray, path: Path | PathLike) -> np.ndarray:
    channels = image.shape[2]
    if channels in (1, 2):
        return np.ascontiguousarray(np.repeat(image[:, :, :1], 3, axis=2))
    if channels in (3, 4):
        return np.ascontiguousarray(image[:, :, :3])
    raise ImageError(f"{path}: expected grey, grey+alpha, RGB or RGBA, got {channels} channels")


def _check_finite(values: np.ndarray, path: Path | PathLike, what: str) -> None:
    bad = ~np.isfinite(values)
    if bad.any():
        where = np.argwhere(bad)[0]
        location = f"row {where[0]}, column {where[1]}" if where.size >= 2 else f"index {where}"
        raise ImageError(
            f"{path}: {what} has {int(bad.sum())} NaN/Inf values (first at {location}: "
            f"{values[tuple(where)]}); every value must be finite"
        )


def _as_hwc(image: np.ndarray, path: Path | PathLike) -> np.ndarray:
    if image.ndim == 2:
        image = image[:, :, None]
    if image.ndim != 3 or image.shape[0] == 0 or image.shape[1] == 0:
        raise ImageError(f"{path}: expected an image array (H, W) or (H, W, C), got {image.shape}")
    if not np.issubdtype(image.dtype, np.floating):
        raise ImageError(
            f"{path}: expected float image data in [0, 1], got {image.dtype} "
            "(divide integer data by its maximum first)"
        )
    return image


def _video_frame(frame: np.ndarray, path: Path, index: int, first: np.ndarray | None) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3:
        raise ImageError(f"{path}: frame {index} has shape {frame.shape}, expected (H, W, 3)")
    if first is not None and frame.shape != first.shape:
        raise ImageError(
            f"{path}: frame {index} has shape {frame.shape}, the first frame {first.shape}"
        )
    if frame.dtype == np.uint8:
        return np.ascontiguousarray(frame)
    if not np.issubdtype(frame.dtype, np.floating):
        raise ImageError(f"{path}: frame {index} is {frame.dtype}, expected float or uint8")
    _check_finite(frame, path, f"frame {index}")
    return (np.clip(frame, 0.0, 1.0) * 255.0).round().astype(np.uint8)


def _draw_labels(
    sheet: np.ndarray, labels: Sequence[str], columns: int, cell_w: int, cell_h: int, gap: int
) -> np.ndarray:
    """Render each label (white on a dark box) at its cell's top-left with OIIO's font."""
    size = max(10, min(32, cell_h // 12))
    buf = oiio.ImageBuf(oiio.ImageSpec(sheet.shape[1], sheet.shape[0], 3, "float"))
    buf.set_pixels(oiio.ROI(), np.ascontiguousarray(sheet))
    for index, label in enumerate(labels):
        if not label:
            continue
        x = gap + (index % columns) * (cell_w + gap)
        y = gap + (index // columns) * (cell_h + gap)
        box = oiio.ImageBufAlgo.text_size(label, size)
        box_w = min(box.width + size // 2, cell_w) if box.defined else cell_w
        oiio.ImageBufAlgo.fill(
            buf, [0.0, 0.0, 0.0], oiio.ROI(x, x + box_w, y, min(y + size + size // 3, y + cell_h))
        )
        if not oiio.ImageBufAlgo.render_text(buf, x + size // 4, y + size, label, size):
            raise ImageError(f"cannot draw contact-sheet label {label!r}: {buf.geterror()}")
    return buf.get_pixels(oiio.FLOAT).reshape(sheet.shape)
