"""The embedded default animator ``flow``: a looping cinemagraph from an Eulerian motion field.

After Holynski et al., "Animating Pictures with Eulerian Motion Fields" (CVPR 2021), on the
sphere instead of the image plane:

* **Motion field.** A static velocity field v(d) tangent to the sphere: each region's rigid
  rotation Ω × d (see ``pano4d.regions``; between and beyond regions Ω is filled in smoothly),
  plus a small divergence-free low-frequency perturbation d × ∇ψ(d) so the texture swirls
  a little instead of sliding rigidly. Everything is a function of the 3D direction, so
  there is no seam and no pole.
* **Integration.** Positions are traced through v with midpoint (RK2) sub-steps, on a grid
  at most TRACE_MAX_WIDTH wide (the field is smooth; the traces are interpolated to full
  resolution): B_t = the point that flows to x in t frames (trace −v), F_t = where x flows
  in L − t frames (trace +v).
* **Rendering.** Backward warping from both ends of the loop: frame t is
  (1 − t/L)·I(B_t) + (t/L)·I(F_t). Frame 0 is the input and "frame L" would be the input
  again, so the video loops with no jump. Only moving pixels are sampled: the motion does
  not stop at a region's border (a speed falling to zero there shears the texture into
  streaks along every edge), so a trace may end behind a static object, where the moving
  texture is unknown. There the local mean colour stands in, and the other end of the
  loop, if it sees moving texture, takes over (each end is weighted by how much moving
  texture surrounds it). The cross-fade preserves the texture's contrast around its
  local mean (Heitz & Neyret 2018), so mid-loop frames are not washed out; how
  correlated the two ends are (close together, they need less rescaling) is a smooth
  function of the traces, taken on the trace grid and interpolated with them. The
  visible motion fades to zero at the border through the soft blend weight.

Outside the regions every frame is the input, bit for bit; the soft border blends the two.
Frames are produced one at a time; memory is the full-resolution image and a few tensors
the size of the moving region, processed in chunks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F

from pano4d.animate.frames import FrameBox
from pano4d.regions import Regions, angular_velocity_field
from pano4d.smoothstep import smoothstep
from pano4d.sphere import equirect_directions

TRACE_MAX_WIDTH = 512  # traces are computed on a grid at most this wide
PERTURBATION = 0.08  # rms of the swirl, relative to the region's speed
PERTURBATION_WAVES = 8
PERTURBATION_WAVENUMBERS = (3.0, 8.0)  # radians⁻¹ on the unit sphere: 45°–120° wavelengths
MAX_SUBSTEP_CELLS = 1.0  # one integration sub-step moves at most this many trace cells
LOCAL_MEAN_DEG = 8.0  # width of the local mean that the cross-fade keeps the contrast around
DECORRELATION_DEG = 3.0  # texture samples this far apart count as independent in the fade
CHUNK_PIXELS = 1 << 20  # full-resolution pixels rendered at once


class FlowAnimator:
    """Render the frames of one looping cinemagraph.

    ``panorama`` (H, W, 3) float32, ``regions`` for the same size, ``frames`` the loop length
    L, ``seed`` fixes the perturbation. ``frame(t)`` gives (H, W, 3) float32 for 0 ≤ t < L.
    """

    def __init__(self, panorama: torch.Tensor, regions: Regions, frames: int, seed: int) -> None:
        height, width = regions.height, regions.width
        if tuple(panorama.shape) != (height, width, 3):
            raise ValueError(
                f"panorama is {tuple(panorama.shape)}, the regions are for ({height}, {width}, 3)"
            )
        if frames < 2:
            raise ValueError(f"a loop needs at least 2 frames, got {frames}")
        self.panorama = panorama.to(torch.float32).contiguous()
        self.regions = regions
        self.frames = frames
        self.scale = _trace_scale(width, height)
        self._to_grid = _angles_to_grid(width // self.scale, height // self.scale)
        self._waves = _perturbation_waves(seed)
        self._field = self._velocity_texture()
        self._backward, self._forward = self._trace_all()
        # The pixels rendered, and where they sample the trace grid: the same every frame.
        rows, columns = torch.nonzero(regions.blend > 0).unbind(1)
        self._pixels = rows * width + columns
        self._trace_grid = _pixel_grid(rows, columns, width, height, self.scale)
        self._box_targets: tuple[FrameBox, torch.Tensor] | None = None
        # Colour times mask, and the mask, padded for sampling across the seam and poles
        # by one trace cell, s pixels, so that an angle has the same grid_sample
        # coordinates here as in the trace-grid textures (``_angles_to_grid``). Written in
        # place, as this is the one texture the size of the panorama.
        s = self.scale
        self._image = torch.empty(4, height + 2 * s, width + 2 * s, dtype=torch.float32)
        mask = regions.mask.to(torch.float32)
        torch.mul(self.panorama.permute(2, 0, 1), mask, out=self._image[:3, s:-s, s:-s])
        self._image[3, s:-s, s:-s] = mask
        _fill_sphere_border(self._image, s)
        self._local_mean = self._local_mean_texture(self._image[:, s:-s, s:-s])

    def _local_mean_texture(self, image: torch.Tensor) -> torch.Tensor:
        """Padded trace-grid texture (4, h+2, w+2) of the moving pixels' colour times mask
        and mask ``image`` (4, H, W): their colour box-blurred twice over LOCAL_MEAN_DEG,
        filled in where no moving pixel is near (3), and how much of that neighbourhood
        moves (1): the local mean colour and its validity."""
        s = self.scale
        h, w = image.shape[1] // s, image.shape[2] // s
        # Means over s columns, then over s rows: on a view into the padded image, where
        # avg_pool2d is several times slower.
        pooled = image.unflatten(2, (w, s)).mean(dim=3).unflatten(1, (h, s)).mean(dim=2)
        radius = max(1, round(LOCAL_MEAN_DEG / 2 * pooled.shape[2] / 360.0))
        for _ in range(2):
            padded = _pad_sphere(pooled, radius)
            pooled = F.avg_pool2d(padded[None], 2 * radius + 1, stride=1)[0]
        mean = _push_pull(pooled[:3], pooled[3])
        return _pad_sphere(torch.cat([mean, pooled[3:]]), 1)

    # --- the motion field ----------------------------------------------------------------
    def _velocity_texture(self) -> torch.Tensor:
        """(3, h+2, w+2) padded velocity on the trace grid, radians per frame.

        Defined everywhere, not only inside the regions: a cloud passing behind a mountain
        keeps moving there, and comes out on the other side.
        """
        height, width = self.regions.height, self.regions.width
        s = self.scale
        h, w = height // s, width // s
        omega = angular_velocity_field(self.regions, s)
        # Pooled in float32: a sum of at most s² ones is exact there.
        covered = F.avg_pool2d(self.regions.mask[None].to(torch.float32), s)[0].to(torch.float64)
        omega = _push_pull(omega * covered, covered)
        dirs = equirect_directions(w, h, torch.float64).reshape(-1, 3)
        speed = torch.linalg.norm(omega, dim=0).reshape(-1, 1)
        velocity = torch.linalg.cross(omega.reshape(3, -1).T, dirs) + speed * self._swirl(dirs)
        self._cell_rad = 2.0 * math.pi / w
        self._max_speed = float(speed.max())
        return _pad_sphere(velocity.T.reshape(3, h, w).to(torch.float32), 1)

    def _swirl(self, dirs: torch.Tensor) -> torch.Tensor:
        """Divergence-free tangent field d × ∇ψ, ψ = Σ a_i sin(k_i·d + φ_i), rms PERTURBATION."""
        wavevectors, amplitudes, phases = self._waves
        out = torch.zeros_like(dirs)
        for k, a, phase in zip(wavevectors, amplitudes, phases, strict=True):
            out += (a * torch.cos(dirs @ k + phase))[:, None] * torch.linalg.cross(
                dirs, k.expand_as(dirs)
            )
        return PERTURBATION * out

    def velocity(self, dirs: torch.Tensor) -> torch.Tensor:
        """Velocity (N, 3) in radians per frame at unit directions (N, 3)."""
        return _grid_sample(self._field, self._grid(dirs.unbind(-1))).T

    # --- integration ---------------------------------------------------------------------
    def _trace_all(self) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
        """B_t (t = 0..L−1) and F_t (t = 0..L−1) on the trace grid, each (3, h, w).

        Only grid points next to animated pixels are traced; the rest stay in place.
        """
        h, w = self._field.shape[1] - 2, self._field.shape[2] - 2
        start = equirect_directions(w, h).reshape(-1, 3)
        animated = F.max_pool2d((self.regions.blend > 0)[None, None].float(), self.scale)
        moving = (F.max_pool2d(animated, 3, stride=1, padding=1)[0, 0] > 0).reshape(-1)
        top_speed = self._max_speed * (1.0 + 3.0 * PERTURBATION)
        substeps = max(1, math.ceil(top_speed / (MAX_SUBSTEP_CELLS * self._cell_rad)))

        def trace(direction: float, count: int) -> list[torch.Tensor]:
            points, steps = start[moving], [start[moving]]
            for _ in range(count):
                points = self._advance(points, direction / substeps, substeps)
                steps.append(points)
            grids = []
            for p in steps:
                grid = start.clone()
                grid[moving] = p
                grids.append(grid.T.reshape(3, h, w))
            return grids

        backward = trace(-1.0, self.frames - 1)
        ahead = trace(1.0, self.frames)
        return backward, [ahead[self.frames - t] for t in range(self.frames)]

    def _advance(self, dirs: torch.Tensor, step: float, substeps: int) -> torch.Tensor:
        for _ in range(substeps):
            half = _normalise(dirs + 0.5 * step * self.velocity(dirs))
            dirs = _normalise(dirs + step * self.velocity(half))
        return dirs

    # --- rendering -----------------------------------------------------------------------
    def frame(self, t: int, box: FrameBox | None = None) -> torch.Tensor:
        """Frame t (H, W, 3) float32, or only its pixels in ``box`` (rows, columns, 3)
        (``pano4d.animate.frames``; the box must hold the blend); static pixels are the
        panorama's, bit for bit. Only the blend's pixels are computed either way."""
        if not 0 <= t < self.frames:
            raise IndexError(f"frame {t} out of range for a {self.frames}-frame loop")
        traces = self._trace_texture(t)
        ahead = t / self.frames
        if box is None:
            out = self.panorama.reshape(-1, 3).clone()
            shape: tuple[int, ...] = tuple(self.panorama.shape)
            targets = self._pixels
        else:
            cropped = box.crop(self.panorama.numpy())
            out, shape = torch.from_numpy(cropped).reshape(-1, 3), cropped.shape
            targets = self._targets_in(box)
        blend = self.regions.blend.reshape(-1)
        for pixels, grid, target in zip(
            *(torch.split(x, CHUNK_PIXELS) for x in (self._pixels, self._trace_grid, targets)),
            strict=True,
        ):
            # Channels first, (C, N), so that every step below runs on contiguous rows.
            ends = _grid_sample(traces, grid)
            back, back_local = self._sample_moving(ends[:3])
            front, front_local = self._sample_moving(ends[3:6])
            # Each end counts as much as it sees moving texture (not a mountain it has
            # slid behind), within the loop's schedule 1 − t/L : t/L.
            back_weight = (1.0 - ahead) * (back_local[3:] + 1e-3)
            front_weight = ahead * (front_local[3:] + 1e-3)
            fade = front_weight / (back_weight + front_weight)
            keep = 1.0 - fade
            # Variance-preserving cross-fade (Heitz & Neyret 2018): the local means μ
            # blend linearly and the detail c − μ is rescaled by g = 1/√spread to keep its
            # contrast, so mid-loop frames are not washed out (``_trace_texture`` says how
            # correlated the ends are). With an end's colour c = a + (1 − m)·μ (a the
            # moving colour times mask m sampled there), keep·(μ_b + g·(c_b − μ_b)) +
            # fade·(μ_f + g·(c_f − μ_f)) is μ_b·(keep − g·keep·m_b) + a_b·g·keep + the same
            # for f: per-pixel factors first, then four multiply-adds over the colours.
            gain = (keep.square() + fade.square() + 2.0 * fade * keep * ends[6:]).rsqrt()
            back_gain, front_gain = gain * keep, gain * fade
            moved = back_local[:3] * (keep - back_gain * back[3:])
            moved.addcmul_(front_local[:3], fade - front_gain * front[3:])
            moved.addcmul_(back[:3], back_gain).addcmul_(front[:3], front_gain)
            # out holds the panorama there; lerp is exactly the moving colour where the
            # blend is 1. index_select and index_copy_ rather than indexing: several
            # times faster on these long sorted index lists.
            weight = blend.index_select(0, pixels)[:, None]
            mixed = torch.lerp(out.index_select(0, target), moved.clamp_(0.0, 1.0).T, weight)
            out.index_copy_(0, target, mixed)
        return out.reshape(shape)

    def _targets_in(self, box: FrameBox) -> torch.Tensor:
        """Flat indices of the rendered pixels in ``box``'s crop, kept for the next frame
        (a run asks for every frame in the same box)."""
        if self._box_targets is None or self._box_targets[0] != box:
            width = self.regions.width
            rows, columns = self._pixels // width - box.top, self._pixels % width - box.left
            self._box_targets = (box, rows * box.count + columns % width)
        return self._box_targets[1]

    def _trace_texture(self, t: int) -> torch.Tensor:
        """Padded trace-grid texture (7, h+2, w+2) of frame t: B_t (3), F_t (3) and how
        correlated the texture at the two ends is (1).

        Two samples close together (near a pole, where the flow is slow) are correlated,
        and the cross-fade rescales them less. The correlation is a smooth function of the
        traces, so it is taken on the trace grid, where the traces are unit vectors, and
        interpolated like them: no per-pixel normalisation."""
        back, front = self._backward[t], self._forward[t]
        apart = (back - front).square().sum(dim=0, keepdim=True).sqrt()
        correlation = 1.0 - smoothstep(0.0, math.radians(DECORRELATION_DEG), apart)
        return _pad_sphere(torch.cat([back, front, correlation]), 1)

    def _sample_moving(self, dirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """At directions (3, N), unit or not: the moving pixels' colour times mask and the
        mask (4, N) (where static pixels are, the local mean stands in for the texture
        behind them), and the local mean colour and fraction of moving pixels around (4, N).
        """
        grid = self._grid(dirs)
        return _grid_sample(self._image, grid), _grid_sample(self._local_mean, grid)

    def _grid(self, dirs: Sequence[torch.Tensor]) -> torch.Tensor:
        """``grid_sample``'s coordinates (N, 2) of directions (x, y, z), unit or not, in
        the trace-grid textures and in the image."""
        x, y, z = dirs
        # Scaled before they are interleaved: a product broadcast over a last axis of 2 is
        # several times slower.
        longitude = torch.atan2(-y, x).mul_(self._to_grid[0])
        latitude = torch.atan2(z, torch.hypot(x, y)).mul_(self._to_grid[1])
        return torch.stack([longitude, latitude], dim=-1)


# --- helpers -----------------------------------------------------------------------------
def _angles_to_grid(width: int, height: int) -> tuple[float, float]:
    """Factors from longitude φ and latitude θ (as in ``dir_to_equirect``) to
    ``grid_sample``'s coordinates in a texture width×height padded by one pixel
    (``_pad_sphere``): with u and v as there, 2(u + 1)/(W + 2) − 1 = φ·W/(π(W + 2)), and
    likewise for v. Unlike there, u = W (φ = π) is not wrapped to 0: the padding holds
    column 0 there.
    """
    return width / (math.pi * (width + 2)), -2.0 * height / (math.pi * (height + 2))


def _pixel_grid(
    rows: torch.Tensor, columns: torch.Tensor, width: int, height: int, scale: int
) -> torch.Tensor:
    """``grid_sample``'s coordinates (N, 2) of the centres of pixels (rows, columns) of the
    width×height image in a trace-grid texture (width/scale × height/scale, padded by one
    cell): 2(u/scale + 1)/(w + 2) − 1 at u = column + 1/2, and likewise for the row."""
    w, h = width // scale, height // scale
    u = columns * (2.0 / (scale * (w + 2))) + ((1.0 / scale + 2.0) / (w + 2) - 1.0)
    v = rows * (2.0 / (scale * (h + 2))) + ((1.0 / scale + 2.0) / (h + 2) - 1.0)
    return torch.stack([u, v], dim=-1)


def _push_pull(premultiplied: torch.Tensor, coverage: torch.Tensor) -> torch.Tensor:
    """Fill a texture (C, h, w) known with weight ``coverage`` (h, w): the normalised values
    where coverage is full, blended towards coarser and coarser averages where it is not
    (pull-push, Gortler et al. 1996). Columns wrap round the seam at every level."""
    if min(coverage.shape) < 2:
        total = coverage.sum()
        mean = premultiplied.sum(dim=(1, 2), keepdim=True) / total.clamp(min=1e-12)
        return mean.expand_as(premultiplied).clone()
    coarse_values = F.avg_pool2d(premultiplied[None], 2, ceil_mode=True)[0]
    coarse_coverage = F.avg_pool2d(coverage[None, None], 2, ceil_mode=True)[0, 0]
    filled = _push_pull(coarse_values, coarse_coverage)
    wrapped = torch.cat([filled[:, :, -1:], filled, filled[:, :, :1]], dim=2)
    up = F.interpolate(wrapped[None], scale_factor=2, mode="bilinear", align_corners=False)[0]
    up = up[:, : coverage.shape[0], 2 : 2 + coverage.shape[1]]
    known = coverage.clamp(0.0, 1.0)
    own = premultiplied / coverage.clamp(min=1e-12)
    return torch.where(known[None] > 0, known * own + (1.0 - known) * up, up)


def _trace_scale(width: int, height: int) -> int:
    """Largest integer factor ≤ width / TRACE_MAX_WIDTH that divides the height."""
    scale = max(1, width // TRACE_MAX_WIDTH)
    while height % scale:
        scale -= 1
    return scale


def _perturbation_waves(seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Random wave vectors (n, 3), amplitudes and phases of ψ, scaled so that the swirl
    d × ∇ψ has unit rms over the sphere (mean of |d × k|² cos² is |k|²/3)."""
    gen = torch.Generator().manual_seed(int(seed) + 104729)
    n = PERTURBATION_WAVES
    axes = torch.randn(n, 3, generator=gen, dtype=torch.float64)
    axes = axes / torch.linalg.norm(axes, dim=-1, keepdim=True)
    low, high = PERTURBATION_WAVENUMBERS
    wavenumbers = low + (high - low) * torch.rand(n, generator=gen, dtype=torch.float64)
    phases = 2 * math.pi * torch.rand(n, generator=gen, dtype=torch.float64)
    amplitudes = math.sqrt(3.0 / n) / wavenumbers
    wavevectors = axes * wavenumbers[:, None]
    return wavevectors, amplitudes, phases


def _normalise(dirs: torch.Tensor) -> torch.Tensor:
    # Not torch.linalg.norm: its reduction over a last axis of 3 is many times slower.
    return dirs * dirs.square().sum(dim=-1, keepdim=True).rsqrt()


def _pad_sphere(texture: torch.Tensor, pad: int) -> torch.Tensor:
    """Pad an equirect texture (C, H, W) by ``pad`` pixels: columns wrap round the seam,
    rows beyond a pole continue on its far side (mirrored, half a turn round)."""
    channels, height, width = texture.shape
    out = texture.new_empty(channels, height + 2 * pad, width + 2 * pad)
    out[:, pad:-pad, pad:-pad] = texture
    _fill_sphere_border(out, pad)
    return out


def _fill_sphere_border(texture: torch.Tensor, pad: int) -> None:
    """Write the ``pad``-pixel border of a padded texture (C, H + 2·pad, W + 2·pad) from
    its inside, as ``_pad_sphere`` describes."""
    inside = texture[:, pad:-pad, pad:-pad]
    width = inside.shape[2]
    texture[:, :pad, pad:-pad] = torch.roll(torch.flip(inside[:, :pad], [1]), width // 2, dims=2)
    texture[:, -pad:, pad:-pad] = torch.roll(torch.flip(inside[:, -pad:], [1]), width // 2, dims=2)
    texture[:, :, :pad] = texture[:, :, width : width + pad]
    texture[:, :, -pad:] = texture[:, :, pad : 2 * pad]


def _grid_sample(texture: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """Bilinear samples (C, N) of a texture (C, rows, cols) at ``grid_sample``'s
    coordinates (N, 2) in [−1, 1]."""
    out = F.grid_sample(
        texture[None],
        grid.view(1, 1, -1, 2).to(texture.dtype),
        mode="bilinear",
        padding_mode="border",
        align_corners=False,
    )
    return out[0, :, 0]
