"""The animation's frames on disk: the static panorama once, and each frame's moving box.

Outside the soft region blend every frame is the input, bit for bit (``run_animate``
enforces it), so a frame is stored as the crop of the blend's bounding box on the equirect
(``FrameBox``: rows, and columns that may wrap round the seam at u = W), and the panorama as
the frames hold it is stored once (docs/design.md, "Files a run writes")::

    output/animate/moving/static.png   every frame's pixels outside the box (16-bit PNG;
                                       32-bit float EXR for an EXR panorama)
    output/animate/moving/box.json     where the box sits: {"size": [W, H],
                                       "rows": [top, bottom], "columns": [left, count]}
    output/animate/moving/0000.png …   frame t inside the box, same format

``FrameStore.frame(t)`` composes a whole frame (bit-identical to writing the whole frame
in that format and reading it back), ``FrameStore.export`` writes them all as images
(``pano4d animate --frames-out DIR``), and ``FrameStore.area_downsampled`` gives the lifting
phase its working-resolution frames without composing whole full-resolution frames: the
static panorama is downsampled once and, per frame, only the output pixels whose area
windows reach into the box are recomputed, from a band of composed pixels aligned so that
each of those windows is exactly the window of the whole-frame computation.

A folder of whole frames (0000.png …, put there by hand; or ``export``'s output) is read
through the same interface (``open_frames``), so every reader takes either form.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from pano4d.errors import InputError
from pano4d.fsutil import write_json_atomic
from pano4d.images import ImageError, image_size, read_image, write_image

STATIC_NAME = "static"
BOX_NAME = "box.json"


def frame_suffix(panorama: str | Path) -> str:
    """Frames are EXR for an EXR panorama, PNG otherwise."""
    return ".exr" if Path(panorama).suffix.lower() == ".exr" else ".png"


def frame_name(t: int, suffix: str) -> str:
    return f"{t:04d}{suffix}"


def frame_bits(suffix: str) -> int | None:
    """What frames are written with: 16-bit PNG, or the EXR writer's float default."""
    return None if suffix == ".exr" else 16


# --- the box -----------------------------------------------------------------------------
@dataclass(frozen=True)
class FrameBox:
    """Rows [top, bottom) and the ``count`` columns from ``left`` (mod ``width``) of a
    ``width``×``height`` equirect: the smallest such box holding every True pixel."""

    width: int
    height: int
    top: int
    bottom: int
    left: int
    count: int

    @classmethod
    def around(cls, moving: torch.Tensor | np.ndarray) -> FrameBox:
        """The box around the True pixels of ``moving`` (H, W); the columns take the
        shorter way round the seam (the complement of the widest run of empty columns)."""
        grid = torch.as_tensor(moving).to(torch.bool)
        height, width = (int(n) for n in grid.shape)
        rows = torch.nonzero(grid.any(dim=1))[:, 0]
        used = torch.nonzero(grid.any(dim=0))[:, 0]
        if len(rows) == 0:
            raise ValueError("no moving pixel: a frame box needs at least one")
        top, bottom = int(rows[0]), int(rows[-1]) + 1
        # Gaps between consecutive used columns, the one across the seam included.
        following = torch.roll(used, -1)
        gaps = (following - used - 1) % width
        widest = int(torch.argmax(gaps))
        if int(gaps[widest]) == 0:
            return cls(width, height, top, bottom, 0, width)
        left = int(following[widest])
        return cls(width, height, top, bottom, left, width - int(gaps[widest]))

    def spans(self) -> list[tuple[int, int, int]]:
        """(first column, end column, offset in the box) of the one or two runs of columns
        the box covers (two when it wraps round the seam)."""
        end = self.left + self.count
        if end <= self.width:
            return [(self.left, end, 0)]
        return [(self.left, self.width, 0), (0, end - self.width, self.width - self.left)]

    def crop(self, image: np.ndarray) -> np.ndarray:
        """The box's pixels (bottom − top, count, C) of a whole image (H, W, C)."""
        rows = image[self.top : self.bottom]
        parts = [rows[:, start:end] for start, end, _ in self.spans()]
        return parts[0].copy() if len(parts) == 1 else np.concatenate(parts, axis=1)

    def paste(self, image: np.ndarray, crop: np.ndarray) -> None:
        """Write ``crop`` (the box's pixels) into the whole image, in place."""
        for start, end, offset in self.spans():
            image[self.top : self.bottom, start:end] = crop[:, offset : offset + end - start]

    def to_json(self) -> dict[str, Any]:
        return {
            "size": [self.width, self.height],
            "rows": [self.top, self.bottom],
            "columns": [self.left, self.count],
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> FrameBox:
        (width, height), (top, bottom), (left, count) = data["size"], data["rows"], data["columns"]
        box = cls(int(width), int(height), int(top), int(bottom), int(left), int(count))
        if not (
            0 <= box.top < box.bottom <= box.height
            and 0 <= box.left < box.width
            and 0 < box.count <= box.width
        ):
            raise ValueError(f"box {data} does not fit its size")
        return box


# --- reading and writing -----------------------------------------------------------------
class FrameStore:
    """The frames of one animation in ``folder`` as the static panorama and box crops."""

    def __init__(self, folder: Path, count: int, suffix: str) -> None:
        self.folder = Path(folder)
        self.count = count
        self.suffix = suffix

    @property
    def static_path(self) -> Path:
        return self.folder / f"{STATIC_NAME}{self.suffix}"

    @property
    def box_path(self) -> Path:
        return self.folder / BOX_NAME

    def crop_path(self, t: int) -> Path:
        return self.folder / frame_name(t, self.suffix)

    @property
    def paths(self) -> list[Path]:
        return [self.crop_path(t) for t in range(self.count)]

    def has_layout(self) -> bool:
        return self.box_path.is_file() and self.static_path.is_file()

    def complete(self) -> bool:
        return self.has_layout() and all(p.is_file() for p in self.paths)

    def box(self) -> FrameBox:
        try:
            return FrameBox.from_json(json.loads(self.box_path.read_text()))
        except (OSError, ValueError, KeyError, TypeError) as error:
            raise InputError(f"{self.box_path}: unreadable frame box ({error})") from error

    def write_layout(self, static: np.ndarray, box: FrameBox) -> None:
        """The static panorama, then the box: a store is a store once its box.json exists."""
        write_image(self.static_path, static, bits=frame_bits(self.suffix))
        write_json_atomic(self.box_path, box.to_json())

    def write_crop(self, t: int, crop: np.ndarray) -> None:
        write_image(self.crop_path(t), crop, bits=frame_bits(self.suffix))

    def read_static(self) -> np.ndarray:
        return read_image(self.static_path)[:, :, :3]

    def read_crop(self, t: int, box: FrameBox) -> np.ndarray:
        path = self.crop_path(t)
        if not path.is_file():
            raise ImageError(f"{path}: animation frame missing (run `pano4d animate` again)")
        crop = read_image(path)[:, :, :3]
        if crop.shape[:2] != (box.bottom - box.top, box.count):
            raise ImageError(
                f"{path}: frame crop is {crop.shape[1]}×{crop.shape[0]}, "
                f"{self.box_path} says {box.count}×{box.bottom - box.top}"
            )
        return crop

    def size(self) -> tuple[int, int]:
        box = self.box()
        return box.width, box.height

    def frames(self) -> Iterator[np.ndarray]:
        """The whole frames (H, W, 3) in order, the static panorama read once."""
        box = self.box()
        static = self.read_static()
        for t in range(self.count):
            frame = static.copy()
            box.paste(frame, self.read_crop(t, box))
            yield frame

    def export(self, folder: Path) -> list[Path]:
        """Write every frame whole into ``folder`` (0000.png …, this store's format)."""
        paths = []
        for t, frame in enumerate(self.frames()):
            path = Path(folder) / frame_name(t, self.suffix)
            write_image(path, frame, bits=frame_bits(self.suffix))
            paths.append(path)
        return paths

    def area_downsampled(self, size: tuple[int, int]) -> torch.Tensor:
        """Every frame (L, h, w, 3) area-downsampled to ``size`` (w, h), equal bit for bit
        to ``area_resize`` of the whole frame (see the module docstring)."""
        box = self.box()
        static = self.read_static()
        base = area_resize(torch.from_numpy(static), size)
        band = _band(box, size)
        rows = slice(band.input_rows[0], band.input_rows[1])
        static_band = static[rows][:, band.input_columns]
        crop_rows = slice(box.top - band.input_rows[0], box.bottom - band.input_rows[0])
        crop_columns = (box.left + np.arange(box.count) - band.input_columns[0]) % box.width
        frames = []
        for t in range(self.count):
            composed = static_band.copy()
            composed[crop_rows, crop_columns] = self.read_crop(t, box)
            pooled = area_resize(torch.from_numpy(composed), band.output_size)
            frame = base.clone()
            frame[band.output_rows[0] : band.output_rows[1], band.output_columns] = pooled
            frames.append(frame)
        return torch.stack(frames)


class WholeFrames:
    """A folder of whole frames 0000.png … (put there by hand, or ``FrameStore.export``'s)."""

    def __init__(self, folder: Path, count: int, suffix: str) -> None:
        self.folder = Path(folder)
        self.count = count
        self.suffix = suffix

    @property
    def paths(self) -> list[Path]:
        return [self.folder / frame_name(t, self.suffix) for t in range(self.count)]

    def complete(self) -> bool:
        return all(p.is_file() for p in self.paths)

    def size(self) -> tuple[int, int]:
        return image_size(self.paths[0])

    def frames(self) -> Iterator[np.ndarray]:
        for path in self.paths:
            if not path.is_file():
                raise ImageError(f"{path}: animation frame missing (run `pano4d animate` again)")
            yield read_image(path)[:, :, :3]

    def area_downsampled(self, size: tuple[int, int]) -> torch.Tensor:
        return torch.stack(
            [area_resize(torch.from_numpy(np.ascontiguousarray(f)), size) for f in self.frames()]
        )


def open_frames(folder: Path, count: int, suffix: str) -> FrameStore | WholeFrames:
    """The frames in ``folder``: a ``FrameStore`` where it holds a box.json (in the format
    of its static panorama: a working-size store is EXR whatever the input), else whole
    frames in ``suffix``'s format."""
    folder = Path(folder)
    if (folder / BOX_NAME).is_file():
        held = [s for s in (".exr", ".png") if (folder / f"{STATIC_NAME}{s}").is_file()]
        return FrameStore(folder, count, held[0] if held else suffix)
    return WholeFrames(folder, count, suffix)


# --- area downsampling -------------------------------------------------------------------
def area_resize(image: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """An image (H, W, C) area-averaged to ``size`` (w, h), float32 (itself at that size)."""
    w, h = size
    if image.shape[:2] == (h, w):
        return image.to(torch.float32)
    x = image.permute(2, 0, 1)[None].to(torch.float32)
    return F.interpolate(x, size=(h, w), mode="area")[0].permute(1, 2, 0).contiguous()


@dataclass(frozen=True)
class _Band:
    """The output pixels of an area downsampling that a box reaches, and the input pixels
    their windows cover: rows [first, end), columns as index arrays (they may wrap)."""

    output_rows: tuple[int, int]
    output_columns: np.ndarray
    input_rows: tuple[int, int]
    input_columns: np.ndarray

    @property
    def output_size(self) -> tuple[int, int]:
        return len(self.output_columns), self.output_rows[1] - self.output_rows[0]


def _band(box: FrameBox, size: tuple[int, int]) -> _Band:
    """Area downsampling (adaptive average pooling) of H input rows to h output rows takes
    output row i from input rows [⌊iH/h⌋, ⌈(i+1)H/h⌉); after p = h / gcd(H, h) output rows
    the pattern repeats exactly (P = H / gcd(H, h) input rows) and no window crosses the
    boundary between periods. A band of whole periods around the box, pooled on its own,
    therefore gives its output pixels from exactly the windows of the whole image (also
    across the seam, which is a period boundary). The same holds for the columns."""
    w, h = size
    rows_out, rows_in = _periods(box.height, h)
    columns_out, columns_in = _periods(box.width, w)
    # Periods holding the box's first and last row and column (columns unwrapped).
    first_row, end_row = box.top // rows_in, -(-box.bottom // rows_in)
    first_column = box.left // columns_in
    end_column = -(-(box.left + box.count) // columns_in)
    if end_column - first_column >= w // columns_out:
        first_column, end_column = 0, w // columns_out
    span = np.arange(first_column, end_column)[:, None]
    return _Band(
        output_rows=(first_row * rows_out, end_row * rows_out),
        output_columns=(span * columns_out + np.arange(columns_out)).reshape(-1) % w,
        input_rows=(first_row * rows_in, end_row * rows_in),
        input_columns=(span * columns_in + np.arange(columns_in)).reshape(-1) % box.width,
    )


def _periods(full: int, out: int) -> tuple[int, int]:
    """(output, input) pixels of one period of the area windows from ``full`` to ``out``."""
    common = math.gcd(full, out)
    return out // common, full // common
