"""Moving regions of a scene: one mask, a soft blend weight and a motion hint per pixel.

Both phases read the regions from here: the animating phase animates inside them, the
lifting phase gives them (and whatever else changes in the video) their own Gaussians.

Every region of scene.yaml (mask file, box or click; boxes may cross the 0°/360° seam, masks
may cover a pole) becomes a bool (H, W) mask (``region_mask``); their union is what moves.
Distances are angles on the sphere, measured in *equator pixels* (2π/W radians), so a
dilation or a border is as wide near a pole as at the horizon and wraps across the seam and
over the pole.

Motion hints become a rigid rotation of the sphere per region (an angular velocity vector
Ω, radians per frame): direction 0 (towards +u) is a rotation about the vertical axis, the
azimuthal drift of clouds, whose arc speed is ``speed`` at the horizon and falls off as
cos(latitude), smooth through the poles. Direction 90 (towards the zenith) is a rotation
about the horizontal axis perpendicular to the region's mean azimuth: at that azimuth,
things rise at ``speed``, pass over the zenith and set on the far side. A rotation moves
texture without compressing it, which is why hints are rotations and not per-pixel arrows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from pano4d.camera import Camera
from pano4d.config import ConfigError, Motion, Region, SceneConfig
from pano4d.images import read_mask
from pano4d.smoothstep import smoothstep
from pano4d.sphere import dir_to_equirect, equirect_directions, equirect_to_dir, views_seeing

# Views are chosen on a mask no wider than this (any-pooled, so nothing is lost).
ACTIVE_VIEWS_MAX_WIDTH = 1024
# The margin around what moves, degrees of arc, in both phases: the animating phase
# denoises the views that see it (the denoiser needs a little context around what moves,
# so a view touching only the margin still matters), the lifting phase gives it dynamic
# Gaussians, so that no static Gaussian's footprint reaches into what moves. 3° keeps the
# lifting's static/dynamic split where its former square margin of 2° put it (that square
# reached 2.8° along the diagonals); a 2° disc cost 0.5 dB of novel-view PSNR at draft.
MARGIN_DEG = 3.0


class RegionError(ConfigError):
    """The regions of a scene describe nothing that can move."""


@dataclass
class Regions:
    """The moving part of one panorama.

    ``masks[r]`` (H, W) bool per region, ``mask`` their union, ``blend`` (H, W) float32 the
    soft weight of the animation (0 outside ``mask``, rising to 1 over ``border_px``
    inside), ``omegas`` (R, 3) float64 each region's angular velocity in rad/frame.
    """

    masks: list[torch.Tensor]
    mask: torch.Tensor
    blend: torch.Tensor
    omegas: torch.Tensor
    border_px: int

    @property
    def width(self) -> int:
        return int(self.mask.shape[1])

    @property
    def height(self) -> int:
        return int(self.mask.shape[0])


def build_regions(
    cfg: SceneConfig, width: int, height: int, size: tuple[int, int] | None = None
) -> Regions:
    """Masks, blend weight and motion of the config's regions on a width×height panorama,
    or, with ``size`` (w, h), on that panorama area-downsampled to ``size``
    (``masks_at_size``; the border scaled with it)."""
    masks = region_masks(cfg, width, height)
    motions = [region.motion or Motion() for region in cfg.regions]
    if size is None or size == (width, height):
        return regions_from_masks(masks, motions, cfg.animate.border_px)
    border = round(cfg.animate.border_px * size[0] / width)
    return regions_from_masks(masks_at_size(masks, size), motions, border)


def masks_at_size(masks: list[torch.Tensor], size: tuple[int, int]) -> list[torch.Tensor]:
    """Bool masks of the panorama's size area-downsampled to ``size`` (w, h): a pixel is in
    a region that covers half of it, or, for a region covering no pixel that far (a few
    pixels at a pole, a sliver at the seam), in its most-covered pixels, so that every
    region keeps at least one pixel at every size."""
    w, h = size
    out = []
    for mask in masks:
        cover = F.interpolate(mask[None, None].float(), size=(h, w), mode="area")[0, 0]
        out.append(cover >= min(0.5, float(cover.max())))
    return out


def regions_from_masks(masks: list[torch.Tensor], motions: list[Motion], border_px: int) -> Regions:
    """Regions from bool (H, W) masks and one motion hint each."""
    if not masks:
        raise RegionError("no moving region: give at least one mask, box or click")
    if len(masks) != len(motions):
        raise ValueError(f"{len(masks)} masks for {len(motions)} motion hints")
    masks = [torch.as_tensor(m).to(torch.bool) for m in masks]
    union = torch.stack(masks).any(dim=0)
    if not union.any():
        raise RegionError("the region masks are empty (all black), so nothing would move")
    omegas = torch.stack(
        [region_angular_velocity(m, motion) for m, motion in zip(masks, motions, strict=True)]
    )
    return Regions(masks, union, blend_weight(union, border_px), omegas, border_px)


def region_mask(region: Region, width: int, height: int) -> np.ndarray:
    """One region as a bool (height, width) mask; a pixel is in a box if its centre is.

    A mask file is read and resized to the panorama (``images.read_mask``); one with no
    white pixel is an error."""
    if region.mask is not None:
        mask = read_mask(region.mask, width, height)
        if not mask.any():
            raise RegionError(f"{region.mask}: the mask has no white pixels, so nothing moves")
        return mask
    u0, v0, u1, v1 = region.pixel_box(width, height)
    cu = np.arange(width) + 0.5
    cv = np.arange(height) + 0.5
    cols = (cu >= u0) & (cu < u1) if u0 < u1 else (cu >= u0) | (cu < u1)
    rows = (cv >= v0) & (cv < v1)
    return rows[:, None] & cols[None, :]


def region_masks(cfg: SceneConfig, width: int, height: int) -> list[torch.Tensor]:
    """One bool (H, W) mask per region; raises RegionError if any region selects nothing."""
    if not cfg.regions:
        raise RegionError("the scene has no moving region: add a mask, box or click to 'regions'")
    masks = []
    for index, region in enumerate(cfg.regions):
        try:
            pixels = region_mask(region, width, height)
        except RegionError:
            raise
        except ConfigError as error:  # a box or click off the panorama
            raise RegionError(f"regions[{index}].{region.kind}: {error} ({cfg.panorama})") from None
        mask = torch.from_numpy(np.ascontiguousarray(pixels))
        if not mask.any():
            raise RegionError(
                f"regions[{index}] ({region.kind}) covers no pixel of the {width}×{height} "
                "panorama, so nothing would move"
            )
        masks.append(mask)
    return masks


def moving_mask(cfg: SceneConfig, width: int, height: int) -> torch.Tensor:
    """The union of all regions as a bool (H, W) mask."""
    return torch.stack(region_masks(cfg, width, height)).any(dim=0)


def moving_in_video(
    frames: torch.Tensor, regions: torch.Tensor | None, threshold: float = 1.0 / 255.0
) -> torch.Tensor:
    """(H, W) bool: pixels in the regions or changing anywhere in the video.

    ``frames`` (L, H, W, 3); ``regions`` (H, W) bool or None. The lifting phase gives these
    pixels their own Gaussians per timestamp: an animator may move a little beyond the
    regions it was given.
    """
    changed = (frames - frames[:1]).abs().amax(dim=(0, 3)) > threshold
    return changed if regions is None else changed | regions.to(changed.device)


# --- distances on the sphere -------------------------------------------------------------
def sphere_distance_px(mask: torch.Tensor, max_px: float) -> torch.Tensor:
    """Angular distance (H, W) from each pixel centre to the nearest True pixel centre, in
    equator pixels (2π/W rad), exact up to ``max_px`` and ``max_px`` beyond (or if no pixel
    is True).

    Separable like an exact Euclidean distance transform: a vertical pass along meridians
    (continuing over the pole, half a turn round), then a horizontal pass along each row
    with that row's spacing cos(latitude), wrapping across the seam. Within the distances
    used here (tens of pixels) this local flat metric is the great-circle distance.
    """
    height, width = mask.shape
    cap = float(max_px)
    reach = min(math.ceil(cap), height)
    mask = mask.to(torch.bool)
    # Row -k is row k-1 half a turn round (over the pole); row H-1+k is row H-k likewise.
    top = torch.roll(torch.flip(mask[:reach], [0]), width // 2, dims=1)
    bottom = torch.roll(torch.flip(mask[height - reach :], [0]), width // 2, dims=1)
    padded = torch.cat([top, mask, bottom])
    latitude = math.pi * (0.5 - (torch.arange(height, dtype=torch.float64) + 0.5) / height)
    out = torch.empty((height, width), dtype=torch.float32)
    # Bands of rows whose neighbourhood is all True or all False need no search.
    for start in range(0, height, _BAND_ROWS):
        stop = min(start + _BAND_ROWS, height)
        window = padded[start : stop + 2 * reach]
        if bool(window.all()):
            out[start:stop] = 0.0
        elif not bool(window.any()):
            out[start:stop] = cap
        else:
            vertical = _column_pass(window, stop - start, reach, cap)
            out[start:stop] = _row_pass(vertical.square(), latitude[start:stop], cap).sqrt()
    return out.clamp(max=cap)


_BAND_ROWS = 64


def _column_pass(window: torch.Tensor, rows: int, reach: int, cap: float) -> torch.Tensor:
    """Distance along the column to the nearest True within ``reach`` rows (else cap), for
    the ``rows`` middle rows of ``window`` (rows + 2·reach rows)."""
    # A min-plus filter like the row pass: the least cost + k over rows k away, the cost
    # 0 on a True pixel and cap elsewhere (so that no True pixel in reach reads cap).
    # Several times faster than filling the distance in where each shifted mask hits.
    cost = torch.where(window, 0.0, cap).to(torch.float32)
    vertical = cost[reach : reach + rows].clone()
    for k in range(1, reach + 1):
        near = torch.minimum(cost[reach - k : reach - k + rows], cost[reach + k : reach + k + rows])
        torch.minimum(vertical, near.add_(k), out=vertical)
    return vertical.clamp_(max=cap)


def _row_pass(squared: torch.Tensor, latitude: torch.Tensor, cap: float) -> torch.Tensor:
    """min over k of squared[j, i + k] + (k · cos latitude_j)², wrapping in i.

    A row whose spacing cos(lat) is below 1/2 is first min-pooled over blocks of 2^b
    columns so that its pooled spacing lies in (1/2, 1]: the search then spans at most
    2·cap + 1 columns on every row, and the pooling moves a distance by under one pixel.
    """
    width = squared.shape[1]
    spacing = torch.cos(latitude)
    level = torch.floor(torch.log2(1.0 / spacing)).long().clamp(min=0)
    while bool((width % (2 ** level.max())) != 0):  # pool only by factors of the width
        level = level.clamp(max=int(level.max()) - 1)
    out = torch.empty_like(squared)
    for b in torch.unique(level).tolist():
        rows = torch.nonzero(level == b)[:, 0]
        factor = 2**b
        pooled = squared[rows].view(rows.numel(), width // factor, factor).amin(dim=-1)
        step = (spacing[rows] * factor).to(torch.float32)[:, None]
        columns = pooled.shape[1]
        reach = min(columns // 2, math.ceil(cap / float(step.min())))
        # Wrapped once, so that each shift is a view instead of a copy (torch.roll).
        wrapped = torch.cat([pooled[:, columns - reach :], pooled, pooled[:, :reach]], dim=1)
        best = pooled.clone()
        for k in range(1, reach + 1):
            left = wrapped[:, reach - k : reach - k + columns]
            right = wrapped[:, reach + k : reach + k + columns]
            torch.minimum(best, torch.minimum(left, right).add_((k * step).square()), out=best)
        out[rows] = best.repeat_interleave(factor, dim=1)
    return out


def dilate(mask: torch.Tensor, radius_px: float) -> torch.Tensor:
    """The mask grown by ``radius_px`` equator pixels of angle, across seam and poles."""
    if radius_px <= 0:
        return mask.clone()
    return sphere_distance_px(mask, radius_px + 1.0) <= radius_px


def grow(mask: torch.Tensor, degrees: float = MARGIN_DEG) -> torch.Tensor:
    """The equirect mask (H, W) grown by ``degrees`` of arc (``dilate``): what either phase
    treats as moving around a region."""
    return dilate(mask, degrees * mask.shape[1] / 360.0)


def inside_distance_px(mask: torch.Tensor, max_px: float) -> torch.Tensor:
    """For pixels in the mask, the angular distance to the nearest pixel outside (≥ 1 px,
    capped at ``max_px``); 0 outside the mask."""
    distance = sphere_distance_px(~mask, max_px)
    # Near a pole the row pass pools columns, which can put an outside pixel at distance 0
    # from a pixel of the mask; a pixel of the mask is at least one pixel from the outside,
    # so a region a few pixels wide at a pole keeps a blend weight above 0.
    return torch.where(mask, distance.clamp(min=1.0), torch.zeros_like(distance))


def blend_weight(mask: torch.Tensor, border_px: float) -> torch.Tensor:
    """Soft weight (H, W) float32 of the animation: 0 outside the mask, rising smoothly
    over ``border_px`` equator pixels inside it to 1 (a hard 0/1 mask for border 0)."""
    if border_px <= 0:
        return mask.to(torch.float32)
    ramp = float(border_px) + 1.0
    return smoothstep(0.0, ramp, inside_distance_px(mask, ramp)).to(torch.float32)


# --- motion ------------------------------------------------------------------------------
def region_angular_velocity(mask: torch.Tensor, motion: Motion) -> torch.Tensor:
    """The region's rigid rotation Ω (3,) float64, radians per frame (see module doc)."""
    speed = math.radians(motion.speed)
    angle = math.radians(motion.direction_deg)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    # Increasing u turns the view from +x towards −y: a rotation about −z.
    east = -up
    # The horizontal axis whose rotation lifts the region's mean azimuth towards the zenith.
    dirs = _coarse_directions(mask)
    heading = dirs.sum(dim=0)
    heading[2] = 0.0
    if float(torch.linalg.norm(heading)) < 1e-6 * max(1, int(mask.sum())):
        heading = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)  # a cap round a pole
    heading = heading / torch.linalg.norm(heading)
    north = torch.linalg.cross(heading, up)
    return speed * (math.cos(angle) * east + math.sin(angle) * north)


def angular_velocity_field(regions: Regions, scale: int = 1) -> torch.Tensor:
    """The per-pixel motion hint: angular velocity (3, H/scale, W/scale) float64 in
    rad/frame, the area-weighted mean of the rotations of the regions covering each cell
    (0 where none does). ``scale`` must divide the height."""
    height, width = regions.height, regions.width
    if height % scale:
        raise ValueError(f"scale {scale} does not divide the height {height}")
    h, w = height // scale, width // scale
    omega = torch.zeros(3, h, w, dtype=torch.float64)
    count = torch.zeros(h, w, dtype=torch.float64)
    for mask, rotation in zip(regions.masks, regions.omegas, strict=True):
        coarse = mask.view(h, scale, w, scale).to(torch.float64).mean(dim=(1, 3))
        omega += coarse[None] * rotation[:, None, None]
        count += coarse
    return omega / count.clamp(min=1e-12)


def _coarse_directions(mask: torch.Tensor) -> torch.Tensor:
    """Directions (n, 3) of the mask's pixels, area-weighted, on a grid ≤ 512 wide."""
    height, width = mask.shape
    step = 1
    while width // step > 512 and height % (2 * step) == 0:
        step *= 2
    coarse = mask.view(height // step, step, width // step, step).float().mean(dim=(1, 3))
    dirs = equirect_directions(width // step, height // step, torch.float64)
    cos_lat = torch.sqrt(1.0 - dirs[..., 2].square())
    return (dirs * (coarse * cos_lat)[..., None].double()).reshape(-1, 3)


# --- views -------------------------------------------------------------------------------
def active_views(
    cameras: list[Camera], mask: torch.Tensor, dilation_deg: float = MARGIN_DEG
) -> list[int]:
    """Indices of the cameras that see some of the region grown by ``dilation_deg``.

    A view overlaps the region if it sees a point of the region's outline or if its
    centre lies in the region (then the view lies inside it). The outline is taken on the
    mask any-pooled to at most ACTIVE_VIEWS_MAX_WIDTH columns: every pixel corner between
    a covered and an uncovered coarse pixel, so a view misses at most a sliver one coarse
    pixel wide.
    """
    mask = torch.as_tensor(mask).to(torch.bool)
    if not mask.any():
        raise RegionError("the region mask is empty (all black), so nothing would move")
    height, width = mask.shape
    step = 1
    while width // step > ACTIVE_VIEWS_MAX_WIDTH and height % (2 * step) == 0:
        step *= 2
    coarse = F.max_pool2d(mask[None, None].float(), step)[0, 0] > 0
    coarse_h, coarse_w = coarse.shape
    grown = grow(coarse, dilation_deg)
    # Corners (H+1, W+1) touching a covered and an uncovered pixel (columns wrap).
    padded = torch.cat([grown[:, -1:], grown], dim=1).float()
    padded = F.pad(padded[None, None], (0, 0, 1, 1), mode="replicate")
    any_covered = F.max_pool2d(padded, 2, stride=1)[0, 0] > 0
    all_covered = -F.max_pool2d(-padded, 2, stride=1)[0, 0] > 0
    rows, cols = torch.nonzero(any_covered & ~all_covered, as_tuple=True)
    outline = equirect_to_dir(cols.double(), rows.double(), coarse_w, coarse_h)
    seen = views_seeing(cameras, outline).any(dim=1)
    centres = torch.stack([camera.forward for camera in cameras])
    u, v = dir_to_equirect(centres, coarse_w, coarse_h)
    row = v.long().clamp(0, coarse_h - 1)
    centred = grown[row, u.long().clamp(0, coarse_w - 1)]
    return [int(i) for i in torch.nonzero(seen | centred)[:, 0]]
