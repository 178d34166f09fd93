"""Figures of merit: of a panoramic video (``pano4d eval``; ``output/animate/metrics.json``)
and of a lifted scene's novel views (``output/metrics.json``).

Each video figure is a small function on (H, W, 3) float frames in [0, 1]; ``animate_metrics``
streams a video through all of them, holding only the first, previous and current frame.
``novel_view_metrics`` renders a scene at ground-truth cameras: PSNR and SSIM per view and
per camera displacement.

Optical flow is a dense pyramidal Lucas–Kanade in torch (``optical_flow``): coarse to fine,
at each level a few Gauss–Newton iterations of the 2×2 normal equations summed over a
square window, the second image warped by the current estimate. Motion is measured on a
copy of the frames at most FLOW_MAX_WIDTH wide and reported in full-resolution pixels and
in degrees of arc at the horizon (360° / W per pixel).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from pano4d.camera import Camera
from pano4d.resample import perspective_to_equirect

FLOW_MAX_WIDTH = 512
FLOW_WINDOW = 9  # Lucas–Kanade window, pixels at each pyramid level
FLOW_ITERATIONS = 4  # Gauss–Newton iterations per level
FLOW_COARSEST = 24  # the coarsest pyramid level is at least this many pixels high
FRAME_SUFFIXES = (".png", ".exr")

ArrayLike = np.ndarray | torch.Tensor


# --- optical flow ------------------------------------------------------------------------
def optical_flow(
    first: torch.Tensor,
    second: torch.Tensor,
    window: int = FLOW_WINDOW,
    iterations: int = FLOW_ITERATIONS,
) -> torch.Tensor:
    """Dense flow (2, H, W) = (du, dv) in pixels with second(x + flow) ≈ first(x).

    ``first`` and ``second`` are grey images (H, W). Pyramidal Lucas–Kanade: the flow can
    reach a few pixels times 2^(levels − 1), levels chosen so the coarsest is about
    FLOW_COARSEST pixels high.
    """
    if first.shape != second.shape or first.ndim != 2:
        raise ValueError(f"expected two grey images of one size, got {first.shape}, {second.shape}")
    a = first.to(torch.float32)[None, None]
    b = second.to(torch.float32)[None, None]
    levels = max(1, int(math.log2(max(1, min(a.shape[-2:]) // FLOW_COARSEST))) + 1)
    pyramid = [(a, b)]
    for _ in range(levels - 1):
        a, b = F.avg_pool2d(a, 2, ceil_mode=True), F.avg_pool2d(b, 2, ceil_mode=True)
        pyramid.append((a, b))
    flow = torch.zeros(1, 2, *pyramid[-1][0].shape[-2:])
    for level, (a, b) in enumerate(reversed(pyramid)):
        if level:
            flow = 2.0 * F.interpolate(
                flow, size=a.shape[-2:], mode="bilinear", align_corners=False
            )
        for _ in range(iterations):
            flow = flow + _lucas_kanade_step(a, b, flow, window)
    return flow[0]


def _lucas_kanade_step(
    a: torch.Tensor, b: torch.Tensor, flow: torch.Tensor, window: int
) -> torch.Tensor:
    """One Gauss–Newton update of the flow (1, 2, H, W) between images (1, 1, H, W)."""
    warped = _warp(b, flow)
    mean = 0.5 * (a + warped)
    gx = 0.5 * (
        F.pad(mean, (0, 1, 0, 0), mode="replicate")[..., 1:]
        - F.pad(mean, (1, 0, 0, 0), mode="replicate")[..., :-1]
    )
    gy = 0.5 * (
        F.pad(mean, (0, 0, 0, 1), mode="replicate")[..., 1:, :]
        - F.pad(mean, (0, 0, 1, 0), mode="replicate")[..., :-1, :]
    )
    gt = warped - a
    terms = torch.cat([gx * gx, gx * gy, gy * gy, gx * gt, gy * gt], dim=1)
    sums = F.avg_pool2d(terms, window, stride=1, padding=window // 2, count_include_pad=False)
    xx, xy, yy, xt, yt = sums.unbind(dim=1)
    # Tikhonov term: flat patches (no texture) keep their flow instead of exploding.
    ridge = 1e-4 + 1e-3 * (xx + yy)
    xx, yy = xx + ridge, yy + ridge
    det = xx * yy - xy * xy
    du = -(yy * xt - xy * yt) / det
    dv = -(xx * yt - xy * xt) / det
    return torch.stack([du, dv], dim=1)


def _warp(image: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """image(x + flow) for (1, C, H, W) and (1, 2, H, W), bilinear, border replicated."""
    _, _, height, width = image.shape
    ys, xs = torch.meshgrid(
        torch.arange(height, dtype=torch.float32) + 0.5,
        torch.arange(width, dtype=torch.float32) + 0.5,
        indexing="ij",
    )
    gx = 2.0 * (xs + flow[0, 0]) / width - 1.0
    gy = 2.0 * (ys + flow[0, 1]) / height - 1.0
    grid = torch.stack([gx, gy], dim=-1)[None]
    return F.grid_sample(image, grid, mode="bilinear", padding_mode="border", align_corners=False)


# --- single figures ----------------------------------------------------------------------
def seam_error(frame: ArrayLike) -> float:
    """Mean absolute difference between column 0 and column W−1 (neighbours on the sphere)."""
    f = _tensor(frame)
    return float((f[:, 0] - f[:, -1]).abs().mean())


def pole_error(frame: ArrayLike) -> float:
    """Mean absolute difference across each pole: the top (and bottom) row at u against the
    same row at u + W/2, which lies one pixel away over the pole."""
    f = _tensor(frame)
    half = f.shape[1] // 2
    top = (f[0] - torch.roll(f[0], half, dims=0)).abs().mean()
    bottom = (f[-1] - torch.roll(f[-1], half, dims=0)).abs().mean()
    return float(0.5 * (top + bottom))


def static_error(frame: ArrayLike, panorama: ArrayLike, mask: ArrayLike) -> float:
    """Largest absolute difference from the panorama outside the moving mask (must be 0)."""
    f, p, m = _tensor(frame), _tensor(panorama), _mask(mask)
    if bool(m.all()):
        return 0.0
    return float((f[~m] - p[~m]).abs().max())


def mean_abs_difference(a: ArrayLike, b: ArrayLike, mask: ArrayLike) -> float:
    """Mean absolute difference of two frames over the True pixels of ``mask`` (0 if none)."""
    m = _mask(mask)
    if not bool(m.any()):
        return 0.0
    return float((_tensor(a)[m] - _tensor(b)[m]).abs().mean())


def region_flow(a: ArrayLike, b: ArrayLike, mask: ArrayLike) -> tuple[float, float, float]:
    """Mean flow from frame a to frame b inside ``mask``: (mean length in full-resolution
    pixels, mean du, mean dv). Measured at most FLOW_MAX_WIDTH wide, away from the mask's
    border (where the window would straddle static pixels)."""
    ta, tb, m = _tensor(a), _tensor(b), _mask(mask)
    factor = _flow_factor(*m.shape)
    flow = optical_flow(_flow_grey(ta, factor), _flow_grey(tb, factor))
    return _mean_flow(flow, _flow_mask(m, factor), factor)


def _mean_flow(flow: torch.Tensor, inside: torch.Tensor, factor: int) -> tuple[float, float, float]:
    if not bool(inside.any()):
        return 0.0, 0.0, 0.0
    du, dv = flow[0][inside] * factor, flow[1][inside] * factor
    return float(torch.hypot(du, dv).mean()), float(du.mean()), float(dv.mean())


def cross_view_disagreement(
    views: torch.Tensor | Sequence[torch.Tensor], cameras: Sequence[Camera], width: int = 512
) -> float:
    """Mean absolute deviation, over directions seen by two or more views, of each view's
    value from the mean of all views seeing that direction.

    ``views`` (n, C, h, w) or n tensors (C, h_k, w_k): per-view images or latents in the
    cameras' pixel grids (before fusion). Measured on a width × width/2 equirect grid.
    """
    if len(views) != len(cameras):
        raise ValueError(f"{len(views)} views for {len(cameras)} cameras")
    if len(views) < 2:
        raise ValueError("cross-view disagreement needs at least two views")
    height = width // 2
    values, seen = [], []
    for view, camera in zip(views, cameras, strict=True):
        if tuple(view.shape[-2:]) != (camera.height, camera.width):
            raise ValueError(
                f"a view is {tuple(view.shape[-2:])}, its camera {camera.height}×{camera.width}"
            )
        pano, valid = perspective_to_equirect(view.detach().float().cpu(), camera, width, height)
        values.append(pano)
        seen.append(valid)
    stack = torch.stack(values)  # (n, C, H, W)
    count = torch.stack(seen).float()  # (n, H, W)
    total = count.sum(dim=0)
    overlap = total >= 2
    if not bool(overlap.any()):
        return 0.0
    mean = (stack * count[:, None]).sum(dim=0) / total.clamp(min=1)[None]
    deviation = ((stack - mean[None]).abs() * count[:, None]).sum(dim=(0, 1))
    per_pixel = deviation / (total * stack.shape[1]).clamp(min=1)
    return float(per_pixel[overlap].mean())


# --- whole videos ------------------------------------------------------------------------
class VideoMetrics:
    """Streaming accumulator: ``add(frame)`` for each frame in order, then ``result()``.

    ``add(frame, rows=(top, bottom))`` says the frame equals the first frame outside those
    rows (the animating phase's frames: only their box moves, ``pano4d.animate.frames``);
    then the figures that run over pixels look only at those rows, and give the whole
    frame's values (the same maxima; means up to the order of a float sum).
    """

    def __init__(self, panorama: ArrayLike, mask: ArrayLike) -> None:
        self.panorama = _tensor(panorama)
        self.mask = _mask(mask)
        if tuple(self.mask.shape) != tuple(self.panorama.shape[:2]):
            raise ValueError(
                f"mask is {tuple(self.mask.shape)}, panorama {tuple(self.panorama.shape[:2])}"
            )
        self.static = ~self.mask
        self.count = 0
        self.first: torch.Tensor | None = None
        self.previous: torch.Tensor | None = None
        self.seams: list[float] = []
        self.poles: list[float] = []
        self.static_max = 0.0
        self.nonfinite = 0
        self.steps_moving: list[float] = []
        self.steps_static: list[float] = []
        self.flows: list[tuple[float, float, float]] = []
        self._flow_factor = _flow_factor(*self.mask.shape)
        self._flow_mask = _flow_mask(self.mask, self._flow_factor)
        self._flow_previous: torch.Tensor | None = None  # the previous frame's flow input

    def add(self, frame: ArrayLike, rows: tuple[int, int] | None = None) -> None:
        f = _tensor(frame)
        if f.shape != self.panorama.shape:
            raise ValueError(
                f"frame {self.count} is {tuple(f.shape)}, panorama {tuple(self.panorama.shape)}"
            )
        first, end = (0, f.shape[0]) if rows is None or self.first is None else rows
        band = slice(first, end)
        if not bool(torch.isfinite(f[band]).all()):
            self.nonfinite += 1
            f = torch.nan_to_num(f, nan=0.0, posinf=1.0, neginf=0.0)
        self.seams.append(seam_error(f))
        self.poles.append(pole_error(f))
        error = static_error(f[band], self.panorama[band], self.mask[band])
        self.static_max = max(self.static_max, error)
        grey = self._flow_grey(f, first, end)
        if self.previous is not None and self._flow_previous is not None:
            moving = mean_abs_difference(self.previous[band], f[band], self.mask[band])
            still = mean_abs_difference(self.previous[band], f[band], self.static[band])
            # Outside the band the two frames are equal: the whole mean is the band's,
            # scaled by the band's share of the mask's pixels.
            self.steps_moving.append(moving * _share(self.mask, band))
            self.steps_static.append(still * _share(self.static, band))
            flow = optical_flow(self._flow_previous, grey)
            self.flows.append(_mean_flow(flow, self._flow_mask, self._flow_factor))
        else:
            self.first = f
        self.previous = f
        self._flow_previous = grey
        self.count += 1

    def _flow_grey(self, frame: torch.Tensor, first: int, end: int) -> torch.Tensor:
        """``_flow_grey`` of the frame: only the rows [first, end) of it, widened to whole
        pooling cells, computed anew; the rest is the previous frame's."""
        factor = self._flow_factor
        if self._flow_previous is None or (first, end) == (0, frame.shape[0]):
            return _flow_grey(frame, factor)
        top, bottom = first // factor, -(-end // factor)
        grey = self._flow_previous.clone()
        grey[top:bottom] = _flow_grey(frame[top * factor : bottom * factor], factor)
        return grey

    def result(self) -> dict[str, Any]:
        if self.count < 2 or self.first is None or self.previous is None:
            raise ValueError(f"metrics need at least 2 frames, got {self.count}")
        width = self.panorama.shape[1]
        length = float(np.mean([f[0] for f in self.flows]))
        du = float(np.mean([f[1] for f in self.flows]))
        dv = float(np.mean([f[2] for f in self.flows]))
        step = float(np.mean(self.steps_moving))
        loop = mean_abs_difference(self.previous, self.first, self.mask)
        seam_input, pole_input = seam_error(self.panorama), pole_error(self.panorama)
        return {
            "frames": self.count,
            "nonfinite_frames": self.nonfinite,
            "static_error": self.static_max,
            "seam_error": max(self.seams),
            "seam_error_input": seam_input,
            "seam_excess": max(0.0, max(self.seams) - seam_input),
            "pole_error": max(self.poles),
            "pole_error_input": pole_input,
            "pole_excess": max(0.0, max(self.poles) - pole_input),
            "motion_px_per_frame": length,
            "motion_deg_per_frame": length * 360.0 / width,
            "motion_direction_deg": math.degrees(math.atan2(-dv, du)) if length > 0 else 0.0,
            "flicker_static": float(np.mean(self.steps_static)),
            "flicker_moving": step,
            "flicker_per_px_of_motion": step / length if length > 0 else 0.0,
            "loop_error": loop,
            "loop_ratio": loop / step if step > 0 else 0.0,
            "moving_fraction": float(self.mask.float().mean()),
        }


def animate_metrics(
    frames: Iterable[ArrayLike], panorama: ArrayLike, mask: ArrayLike
) -> dict[str, Any]:
    """All figures of a video (frames (H, W, 3) in order) against its input panorama and the
    bool moving mask: see ``VideoMetrics.result`` for the keys.

    static_error is the largest difference outside the mask (0 when static pixels are
    bit-identical); seam_/pole_error are the largest over frames, with the input's own
    value beside them; motion is the mean optical-flow length inside the mask between
    consecutive frames; flicker_* the mean absolute step between consecutive frames in
    each part; loop_error the step from the last frame back to the first, and loop_ratio
    that step over the mean ordinary step (about 1 for a seamless loop).
    """
    metrics = VideoMetrics(panorama, mask)
    for frame in frames:
        metrics.add(frame)
    return metrics.result()


def frame_paths(folder: str | os.PathLike[str]) -> list[Path]:
    """The frame files of a folder (0000.png, 0001.png … or .exr), in order."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: frames folder not found")
    paths = sorted(
        p for p in folder.iterdir() if p.suffix.lower() in FRAME_SUFFIXES and p.stem.isdigit()
    )
    if not paths:
        raise FileNotFoundError(f"{folder}: no frames (0000.png, 0001.png, … or .exr)")
    return paths


def evaluate_frames(
    folder: str | os.PathLike[str],
    panorama: ArrayLike | str | os.PathLike[str],
    mask: ArrayLike | str | os.PathLike[str],
) -> dict[str, Any]:
    """``animate_metrics`` of the frames in ``folder`` (whole frames, or the animating
    phase's store of frame boxes: ``animate.frames.open_frames``); the panorama and mask may
    be arrays or image paths (a mask file: white = moves)."""
    from pano4d.animate.frames import open_frames
    from pano4d.images import read_mask, read_panorama

    if isinstance(panorama, str | os.PathLike):
        panorama = read_panorama(panorama)
    pano = _tensor(panorama)
    if isinstance(mask, str | os.PathLike):
        mask = read_mask(mask, pano.shape[1], pano.shape[0])

    paths = frame_paths(folder)
    frames = open_frames(Path(folder), len(paths), paths[0].suffix)
    return animate_metrics(frames.frames(), pano, mask)


# --- novel views -------------------------------------------------------------------------
def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    """Peak signal-to-noise ratio in dB of two images in [0, 1]."""
    return psnr_of_mse(float(((a - b) ** 2).mean()))


def psnr_of_mse(mse: float) -> float:
    """PSNR in dB of a mean squared error of values in [0, 1] (pooled over several images
    when they are summed first)."""
    return 10 * math.log10(1.0 / max(mse, 1e-12))


def ssim(a: torch.Tensor, b: torch.Tensor) -> float:
    """Mean SSIM (11×11 Gaussian window, kornia) of two (H, W, 3) images."""
    import kornia

    x, y = a.permute(2, 0, 1)[None].float(), b.permute(2, 0, 1)[None].float()
    return float(kornia.metrics.ssim(x, y, 11).mean())


def novel_view_metrics(scene: Any, views: list[dict[str, Any]], render: Callable) -> dict[str, Any]:
    """PSNR/SSIM of renders at the gt cameras, overall and per displacement fraction.

    ``scene`` is a ``ply4d.Scene4D``; each view has ``camera``, ``pixels`` (h, w, 3), ``time``
    and ``displacement_fraction`` (gt/views.json); ``render(gaussians, camera)`` draws one."""
    per_view, groups = [], {}
    for v in views:
        t = min(int(v["time"]), scene.num_times - 1)
        with torch.no_grad():
            rgb = render(scene.at(t), v["camera"]).rgb.clamp(0, 1).cpu()
        p, s = psnr(rgb, v["pixels"]), ssim(rgb, v["pixels"])
        fraction = float(v.get("displacement_fraction", 0.0))
        per_view.append(
            {
                "image": v["image"],
                "time": t,
                "displacement_fraction": fraction,
                "psnr": p,
                "ssim": s,
            }
        )
        groups.setdefault(f"{100 * fraction:g}%", []).append((p, s))
    summary = {
        k: {
            "psnr": float(np.mean([p for p, _ in g])),
            "ssim": float(np.mean([s for _, s in g])),
            "views": len(g),
        }
        for k, g in groups.items()
    }
    return {"views": per_view, "by_displacement": summary}


# --- helpers -----------------------------------------------------------------------------
def _tensor(image: ArrayLike) -> torch.Tensor:
    t = torch.as_tensor(np.asarray(image) if not isinstance(image, torch.Tensor) else image)
    return t.to(torch.float32)


def _mask(mask: ArrayLike) -> torch.Tensor:
    m = torch.as_tensor(np.asarray(mask) if not isinstance(mask, torch.Tensor) else mask)
    if m.ndim == 3:
        m = m[..., 0]
    return m.to(torch.bool)


def _flow_factor(height: int, width: int) -> int:
    """The power of two that brings the frames to at most FLOW_MAX_WIDTH wide."""
    factor = 1
    while width // factor > FLOW_MAX_WIDTH and height % (2 * factor) == 0:
        factor *= 2
    return factor


def _flow_grey(image: torch.Tensor, factor: int) -> torch.Tensor:
    """The grey image (H, W, C) or (H, W) the flow is measured on, pooled by ``factor``."""
    grey = (image.mean(dim=-1) if image.ndim == 3 else image)[None, None]
    return (F.avg_pool2d(grey, factor) if factor > 1 else grey)[0, 0]


def _flow_mask(mask: torch.Tensor, factor: int) -> torch.Tensor:
    """Where the flow is averaged: the mask pooled by ``factor`` and eroded by the window."""
    mf = mask[None, None].float()
    if factor > 1:
        mf = F.avg_pool2d(mf, factor)
    return (-F.max_pool2d(-mf, FLOW_WINDOW, stride=1, padding=FLOW_WINDOW // 2) >= 1.0)[0, 0]


def _share(mask: torch.Tensor, band: slice) -> float:
    """The fraction of ``mask``'s True pixels that lie in the rows ``band`` (1 if none)."""
    total = int(mask.sum())
    return int(mask[band].sum()) / total if total else 1.0
