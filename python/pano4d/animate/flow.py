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
  local mean (Heitz & Neyret 2018), so mid-loop frames are not washed out. The visible
  motion fades to zero at the border through the soft blend weight.

Outside the regions every frame is the input, bit for bit; the soft border blends the two.
Frames are produced one at a time; memory is the full-resolution image and a few tensors
the size of the moving region, processed in chunks.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from pano4d.animate.frames import FrameBox
from pano4d.regions import Regions, angular_velocity_field
from pano4d.smoothstep import smoothstep
from pano4d.sphere import dir_to_equirect, equirect_directions

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
        self._waves = _perturbation_waves(seed)
        self._field = self._velocity_texture()
        self._backward, self._forward = self._trace_all()
        self._pixels = torch.nonzero(regions.blend.reshape(-1) > 0)[:, 0]
        # Colour times mask, and the mask, padded for sampling across the seam and poles.
        mask = regions.mask.to(torch.float32)
        image = self.panorama.permute(2, 0, 1) * mask
        self._image = _pad_sphere(torch.cat([image, mask[None]]), 1)
        self._local_mean = self._local_mean_texture(image, mask)

    def _local_mean_texture(self, image: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Padded trace-grid texture (4, h+2, w+2): the moving pixels' colour box-blurred
        twice over LOCAL_MEAN_DEG, filled in where no moving pixel is near (3), and how
        much of that neighbourhood moves (1): the local mean colour and its validity."""
        s = self.scale
        pooled = F.avg_pool2d(torch.cat([image, mask[None]])[None], s)[0]
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
        covered = self.regions.mask.view(h, s, w, s).to(torch.float64).mean(dim=(1, 3))
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
        h, w = self._field.shape[1] - 2, self._field.shape[2] - 2
        u, v = dir_to_equirect(dirs, w, h)
        return _sample(self._field, u, v, 1)

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
        height, width = self.regions.height, self.regions.width
        s = self.scale
        traces = _pad_sphere(torch.cat([self._backward[t], self._forward[t]]), 1)
        ahead = t / self.frames
        flat = self.panorama.reshape(-1, 3)
        if box is None:
            out, shape = flat.clone(), (height, width, 3)
        else:
            cropped = box.crop(self.panorama.numpy())
            out, shape = torch.from_numpy(cropped).reshape(-1, 3), cropped.shape
        blend = self.regions.blend.reshape(-1)
        for chunk in torch.split(self._pixels, CHUNK_PIXELS):
            u = (chunk % width).to(torch.float32) + 0.5
            v = (chunk // width).to(torch.float32) + 0.5
            ends = _sample(traces, u / s, v / s, 1)
            original = flat[chunk]
            back_dirs, front_dirs = _normalise(ends[:, :3]), _normalise(ends[:, 3:])
            back, back_mean, back_valid = self._sample_moving(back_dirs)
            front, front_mean, front_valid = self._sample_moving(front_dirs)
            # Each end counts as much as it sees moving texture (not a mountain it has
            # slid behind), within the loop's schedule 1 − t/L : t/L.
            back_weight = (1.0 - ahead) * (back_valid + 1e-3)
            front_weight = ahead * (front_valid + 1e-3)
            fade = front_weight / (back_weight + front_weight)
            # Variance-preserving cross-fade (Heitz & Neyret 2018): the local means blend
            # linearly and the detail is rescaled to keep its contrast, so mid-loop frames
            # are not washed out. Two samples close together (near a pole, where the flow
            # is slow) are correlated and need less rescaling.
            apart = torch.linalg.norm(back_dirs - front_dirs, dim=-1, keepdim=True)
            correlation = 1.0 - smoothstep(0.0, math.radians(DECORRELATION_DEG), apart)
            mean = (1.0 - fade) * back_mean + fade * front_mean
            detail = (1.0 - fade) * (back - back_mean) + fade * (front - front_mean)
            spread = (1.0 - fade) ** 2 + fade**2 + 2.0 * fade * (1.0 - fade) * correlation
            moved = (mean + detail / spread.sqrt()).clamp(0.0, 1.0)
            weight = blend[chunk, None]
            target = chunk if box is None else _index_in_box(chunk, width, box)
            out[target] = weight * moved + (1.0 - weight) * original
        return out.reshape(shape)

    def _sample_moving(self, dirs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """At directions (N, 3): the colour (N, 3) of the moving pixels there, completed by
        the local mean where static pixels are (behind which the texture goes on), the
        local mean (N, 3), and the fraction of moving pixels around (N, 1)."""
        height, width = self.regions.height, self.regions.width
        u, v = dir_to_equirect(dirs, width, height)
        sample = _sample(self._image, u, v, 1)
        local = _sample(self._local_mean, u / self.scale, v / self.scale, 1)
        mean, valid = local[:, :3], local[:, 3:]
        colour = sample[:, :3] + (1.0 - sample[:, 3:]) * mean
        return colour, mean, valid


# --- helpers -----------------------------------------------------------------------------
def _index_in_box(pixels: torch.Tensor, width: int, box: FrameBox) -> torch.Tensor:
    """Flat indices in ``box``'s crop of flat pixel indices of the whole (·, width) image."""
    rows = pixels // width - box.top
    columns = (pixels % width - box.left) % width
    return rows * box.count + columns


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
    return dirs / torch.linalg.norm(dirs, dim=-1, keepdim=True)


def _pad_sphere(texture: torch.Tensor, pad: int) -> torch.Tensor:
    """Pad an equirect texture (C, H, W) by ``pad`` pixels: columns wrap round the seam,
    rows beyond a pole continue on its far side (mirrored, half a turn round)."""
    width = texture.shape[2]
    top = torch.roll(torch.flip(texture[:, :pad], [1]), width // 2, dims=2)
    bottom = torch.roll(torch.flip(texture[:, -pad:], [1]), width // 2, dims=2)
    rows = torch.cat([top, texture, bottom], dim=1)
    return torch.cat([rows[:, :, -pad:], rows, rows[:, :, :pad]], dim=2)


def _sample(texture: torch.Tensor, u: torch.Tensor, v: torch.Tensor, pad: int) -> torch.Tensor:
    """Bilinear samples (N, C) of a ``_pad_sphere``-padded texture at unpadded pixel
    coordinates (u, v) (pixel centres at +0.5)."""
    _, rows, cols = texture.shape
    grid = torch.stack([2.0 * (u + pad) / cols - 1.0, 2.0 * (v + pad) / rows - 1.0], dim=-1)
    out = F.grid_sample(
        texture[None],
        grid.view(1, 1, -1, 2).to(texture.dtype),
        mode="bilinear",
        padding_mode="border",
        align_corners=False,
    )
    return out[0, :, 0].T
