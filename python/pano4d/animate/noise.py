"""Pixel footprints on the sphere and white noise that stays white in every view.

A view pixel's *footprint* is the set of icosphere points whose direction falls inside it
(nearest-pixel assignment, each point to at most one pixel per view). With an icosphere a
few times finer than the view pixels every footprint is non-empty, and three linear maps
follow, all precomputed index tables applied with one gather + one ``index_add_``:

- ``project_mean``: a view pixel takes the mean of its footprint (signals: latents);
- ``project_white``: a view pixel takes the sum of its footprint over √count. For i.i.d.
  N(0, 1) point noise each pixel is then exactly N(0, 1) and pixels of one view are
  independent (disjoint footprints): the "integral noise" transport of "How I Warped
  Your Noise" (Chang et al. 2024) with the sphere as the fine grid. Bilinear
  interpolation of white noise would shrink the variance and correlate neighbours.
  Overlapping views share points, so their noise agrees where they overlap;
- ``fuse``: a point takes the window-weighted mean of the pixels (one per view) whose
  footprint holds it. For a single view ``project_mean(fuse(x)) == x``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from pano4d.camera import Camera
from pano4d.sphere import Icosphere, icosphere, icosphere_frequency_for_spacing

# Window weights never reach 0, so a point seen only near one view's border still fuses.
_WINDOW_FLOOR = 1e-3


@dataclass
class Footprints:
    """Nearest-pixel assignment of icosphere points to the pixels of a list of views.

    Entries are sorted by view; ``offsets[k]:offsets[k + 1]`` are view k's entries.
    """

    point: torch.Tensor  # (M,) int64: icosphere point index
    pixel: torch.Tensor  # (M,) int64: view * h * w + row * w + col
    window: torch.Tensor  # (M,) float32: fusion weight, falling off towards the view border
    count: torch.Tensor  # (n_views * h * w,) float32: points in each pixel's footprint
    offsets: list[int]
    n_points: int
    height: int
    width: int

    @property
    def n_views(self) -> int:
        return len(self.offsets) - 1

    def to(self, device: torch.device | str) -> Footprints:
        return Footprints(
            self.point.to(device),
            self.pixel.to(device),
            self.window.to(device),
            self.count.to(device),
            self.offsets,
            self.n_points,
            self.height,
            self.width,
        )

    def _entries(self, views: slice) -> tuple[slice, torch.Tensor, torch.Tensor, int, int]:
        """Entry range, point and view-local pixel indices, first view, number of views."""
        first, stop, _ = views.indices(self.n_views)
        entries = slice(self.offsets[first], self.offsets[stop])
        local_pixel = self.pixel[entries] - first * self.height * self.width
        return entries, self.point[entries], local_pixel, first, stop - first

    def _sum(self, signal: torch.Tensor, views: slice) -> tuple[torch.Tensor, torch.Tensor, int]:
        """Footprint sums (..., B·h·w) of a sphere signal (..., N), and each pixel's count."""
        _, point, pixel, first, n = self._entries(views)
        hw = self.height * self.width
        total = signal.new_zeros(*signal.shape[:-1], n * hw, dtype=torch.float32)
        total.index_add_(-1, pixel, signal[..., point].to(torch.float32))
        return total, self.count[first * hw : (first + n) * hw], n

    def _views_first(self, flat: torch.Tensor, n: int) -> torch.Tensor:
        """(..., B·h·w) → (B, ..., h, w)."""
        lead = flat.shape[:-1]
        out = flat.reshape(*lead, n, self.height, self.width)
        return out.movedim(len(lead), 0)

    def project_mean(self, signal: torch.Tensor, views: slice = slice(None)) -> torch.Tensor:
        """Sphere signal (..., N) → view images (B, ..., h, w): footprint means."""
        total, count, n = self._sum(signal, views)
        return self._views_first(total / count, n)

    def project_white(self, noise: torch.Tensor, views: slice = slice(None)) -> torch.Tensor:
        """Sphere noise (..., N) → view noise (B, ..., h, w): footprint sums / √count."""
        total, count, n = self._sum(noise, views)
        return self._views_first(total / count.sqrt(), n)

    def splat(self, images: torch.Tensor, views: slice, numerator: torch.Tensor) -> None:
        """Add window-weighted view images (B, ..., h, w) into ``numerator`` (..., N)."""
        entries, point, pixel, _, n = self._entries(views)
        flat = images.movedim(0, -3).reshape(*images.shape[1:-2], n * self.height * self.width)
        numerator.index_add_(-1, point, flat[..., pixel].to(torch.float32) * self.window[entries])

    def window_sum(self) -> torch.Tensor:
        """(N,) the summed window weight of all views at each point (0: no view sees it)."""
        total = torch.zeros(self.n_points, device=self.window.device)
        return total.index_add_(0, self.point, self.window)

    def fuse(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """All views' images (n_views, ..., h, w) → window-weighted mean on the sphere
        (..., N) and the bool (N,) of points some view sees (the mean is 0 elsewhere)."""
        numerator = images.new_zeros(*images.shape[1:-2], self.n_points, dtype=torch.float32)
        self.splat(images, slice(None), numerator)
        weight = self.window_sum()
        seen = weight > 0
        return numerator / torch.where(seen, weight, 1.0), seen


def _window(uv: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """Cosine window over the view, 1 at the centre, falling to the floor at the border."""
    wx = torch.sin(math.pi * uv[:, 0] / width).clamp(min=0)
    wy = torch.sin(math.pi * uv[:, 1] / height).clamp(min=0)
    return (wx * wy).clamp(min=_WINDOW_FLOOR)


def build_footprints(cameras: list[Camera], ico: Icosphere) -> Footprints:
    """Footprints of the pixels of ``cameras`` (all the same size) on the icosphere."""
    if not cameras:
        raise ValueError("footprints need at least one view")
    width, height = cameras[0].width, cameras[0].height
    if any((c.width, c.height) != (width, height) for c in cameras):
        raise ValueError("all views of one layout must have the same size")
    points, pixels, windows, offsets = [], [], [], [0]
    for k, cam in enumerate(cameras):
        uv, z = cam.project(cam.position + ico.points)
        inside = (
            (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)
        )
        idx = torch.nonzero(inside).squeeze(1)
        col = uv[idx, 0].floor().long().clamp(0, width - 1)
        row = uv[idx, 1].floor().long().clamp(0, height - 1)
        points.append(idx)
        pixels.append(k * width * height + row * width + col)
        windows.append(_window(uv[idx], width, height).float())
        offsets.append(offsets[-1] + idx.numel())
    pixel = torch.cat(pixels)
    count = torch.bincount(pixel, minlength=len(cameras) * width * height).float()
    return Footprints(
        torch.cat(points), pixel, torch.cat(windows), count, offsets, len(ico), height, width
    )


def footprints_for_views(
    cameras: list[Camera], oversampling: float = 3.0
) -> tuple[Icosphere, Footprints]:
    """The coarsest icosphere with every view pixel's footprint non-empty, and its footprints.

    Starts from a point spacing ``oversampling`` times finer than a pixel at the view centre
    (pixels at an 80° view's corners subtend about 0.4 of that) and refines until no
    footprint is empty, so ``project_mean`` and ``project_white`` are defined everywhere.
    """
    cam = cameras[0]
    pixel_rad = 1.0 / max(cam.fx, cam.fy)
    frequency = icosphere_frequency_for_spacing(pixel_rad / oversampling)
    while True:
        ico = icosphere(frequency)
        footprints = build_footprints(cameras, ico)
        if bool((footprints.count > 0).all()):
            return ico, footprints
        frequency = math.ceil(frequency * 1.25)


def sphere_white_noise(
    n_points: int, shape: tuple[int, ...], generator: torch.Generator
) -> torch.Tensor:
    """I.i.d. N(0, 1) noise (*shape, N) on the icosphere points (float32, on the CPU so the
    same seed gives the same noise on every device)."""
    return torch.randn(*shape, n_points, generator=generator, dtype=torch.float32)
