"""The landscape's terrain: a heightfield on a regular grid, and rays marched against it.

Heights on a regular grid, bilinearly interpolated (``Terrain.height`` is that exact
surface): a meadow that is exactly the plane z = −camera_height inside ``FLAT_RADIUS`` (rays
hit it analytically, see ``Landscape.cast``), a ring of hills and snow-capped mountains
beyond. Rays leaving the meadow are marched with geometric steps bounded by the terrain's
slope, and the first sign change is refined by bisection and false position, so the
reported depth lies on the drawn surface to float32 precision.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from pano4d.smoothstep import smoothstep
from pano4d.synth.textures import fft_noise, normalize, sample

# Terrain layout, metres. The grid spans [-TERRAIN_EXTENT, TERRAIN_EXTENT]^2.
TERRAIN_EXTENT = 600.0
TERRAIN_GRID = 2048
HILLS_START = 70.0  # heights are exactly zero inside this radius
FLAT_RADIUS = HILLS_START - 3 * (2 * TERRAIN_EXTENT / (TERRAIN_GRID - 1))  # grid cells all 0
DOMAIN_RADIUS = 580.0  # rays that get this far without hitting terrain see the sky
MARCH_MIN_STEP = 0.01  # fraction of the ray length: the shortest march step
MARCH_MAX_STEPS = 220  # > log(DOMAIN_RADIUS / FLAT_RADIUS) / log(1 + MARCH_MIN_STEP)
MARCH_LOOKAHEAD = 30.0  # metres of radius a march step may cover under one slope bound
SLOPE_RING = 4.0  # metres: radial resolution of the slope bound
SKYLINE_BINS = 2048
SKYLINE_BLOCK = 8  # grid vertices per side of a skyline block
REFINE_BISECTIONS = 8
REFINE_SECANTS = 6


class Terrain:
    """The heightfield of one seed (three fractal noises drawn from ``gen``), in world z."""

    def __init__(self, gen: torch.Generator, camera_height: float) -> None:
        self.camera_height = camera_height
        n = TERRAIN_GRID
        axis = torch.linspace(-TERRAIN_EXTENT, TERRAIN_EXTENT, n)
        yy, xx = torch.meshgrid(axis, axis, indexing="ij")
        r = torch.hypot(xx, yy)
        cell = 2 * TERRAIN_EXTENT / (n - 1)
        hills = fft_noise(gen, n, n, 2.4, largest=220.0 / cell)
        ridges = 1.0 - fft_noise(gen, n, n, 2.3, largest=300.0 / cell).abs().clamp(max=2.0) / 2.0
        peaks = fft_noise(gen, n, n, 2.6, largest=500.0 / cell)
        hill_height = 28.0 * smoothstep(HILLS_START, 170.0, r) * (0.55 + 0.45 * hills).clamp_min(0)
        mountain_height = (
            180.0
            * smoothstep(220.0, 460.0, r)
            * (0.35 + 0.45 * ridges**2 + 0.25 * peaks).clamp_min(0.3)
        )
        above_ground = hill_height + mountain_height
        above_ground[r <= HILLS_START] = 0.0  # exactly flat: the meadow is the plane
        self.z = above_ground - self.camera_height  # world z of the grid vertices
        self._tex = self.z[None].contiguous()
        self.z_max = float(self.z.max())

        gy, gx = torch.gradient(self.z, spacing=cell)
        self._normal_tex = normalize(torch.stack([-gx, -gy, torch.ones_like(gx)], -1))
        self._normal_tex = self._normal_tex.permute(2, 0, 1).contiguous()
        # Skyline bound: blocks of SKYLINE_BLOCK² vertices, each with its highest vertex
        # (bilinear patches never rise above their corners) and the farthest any point of
        # the block, or of a patch reaching out of it, can be from its centre.
        k = SKYLINE_BLOCK
        self._block_top = F.max_pool2d(self.z[None], k, stride=k).reshape(-1)
        self._block_xy = torch.stack(
            [F.avg_pool2d(c[None], k, stride=k).reshape(-1) for c in (xx, yy)], -1
        )
        self._block_reach = (k + 1) * cell * math.sqrt(2.0) / 2
        # March bounds: the steepest slope of any bilinear patch (no steeper than its
        # steepest edges in x and y).
        edge_x = (self.z[:, 1:] - self.z[:, :-1]).abs()
        edge_y = (self.z[1:] - self.z[:-1]).abs()
        patch_slope = torch.hypot(
            torch.maximum(edge_x[:-1], edge_x[1:]), torch.maximum(edge_y[:, :-1], edge_y[:, 1:])
        ) * (1.001 / cell)
        self._max_slope = float(patch_slope.max())
        # Steepest patch per ring of radius, then over each ring's look-ahead window: the
        # slope bound for a march step that stays within MARCH_LOOKAHEAD metres of radius.
        centres = 0.5 * (axis[1:] + axis[:-1])
        ring = (torch.hypot(centres[:, None], centres[None, :]) / SLOPE_RING).long()
        rings = int(ring.max()) + 1
        ring_slope = torch.zeros(rings).scatter_reduce(
            0, ring.view(-1), patch_slope.view(-1), "amax"
        )
        window = math.ceil(MARCH_LOOKAHEAD / SLOPE_RING) + 3  # ring before, rings after
        padded = torch.cat([ring_slope[:1], ring_slope, ring_slope[-1:].expand(window)])
        self._ring_slope_ahead = padded.unfold(0, window, 1)[:rings].amax(dim=-1)

    def height(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """World z of the terrain surface (bilinear over the grid) at (x, y), any shape.

        The march (``gap``) samples the same grid with the same arithmetic."""
        out = sample(self._tex, x.reshape(-1) / TERRAIN_EXTENT, y.reshape(-1) / TERRAIN_EXTENT)
        return out[:, 0].view(x.shape)

    def normal(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Unit normal (N, 3) of the surface at (x, y), from the grid's finite differences."""
        return normalize(sample(self._normal_tex, x / TERRAIN_EXTENT, y / TERRAIN_EXTENT))

    def candidates(self, o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """Rays that may hit the hills: below the skyline seen from ``o``, bounded per azimuth
        bin by the steepest block of the grid in it (spread over the bins it may cover)."""
        rel = self._block_xy - o[:2]
        dist = torch.linalg.norm(rel, dim=-1) - self._block_reach
        usable = dist > 1.0
        rel, dist = rel[usable], dist[usable]
        slope = (self._block_top[usable] - o[2]) / dist
        bins = SKYLINE_BINS
        azimuth = torch.atan2(rel[:, 1], rel[:, 0])
        b = ((azimuth + math.pi) * (bins / (2 * math.pi))).long().remainder(bins)
        skyline = torch.full((bins,), -torch.inf).scatter_reduce(0, b, slope, "amax")
        # A block at distance D spans about reach / D radians of azimuth either side.
        spread = math.ceil(self._block_reach / float(dist.min()) / (2 * math.pi / bins)) + 1
        padded = torch.cat([skyline[-spread:], skyline, skyline[:spread]])
        skyline = F.max_pool1d(padded[None, None], 2 * spread + 1, stride=1)[0, 0] + 1e-3
        horizontal = torch.hypot(d[:, 0], d[:, 1])
        ray_bin = ((torch.atan2(d[:, 1], d[:, 0]) + math.pi) * (bins / (2 * math.pi))).long()
        ray_bin = ray_bin.remainder(bins)
        return (horizontal > 1e-6) & (d[:, 2] <= skyline[ray_bin] * horizontal)

    def gap(self, o: torch.Tensor, d: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Height of the ray above the terrain at ray lengths t (negative: below)."""
        xy = (o[:2] + t[:, None] * d[:, :2]) * (1.0 / TERRAIN_EXTENT)
        out = F.grid_sample(
            self._tex[None], xy.view(1, 1, -1, 2), mode="bilinear",
            padding_mode="border", align_corners=True,
        )  # fmt: skip
        return o[2] + t * d[:, 2] - out.view(-1)

    def march(self, o: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """First crossing of the terrain for rays leaving the flat meadow: (t, hit).

        Steps are as long as the terrain's slope bound (per ring of radius, see
        ``_ring_slope_ahead``) allows without passing through it, but at least
        MARCH_MIN_STEP of the distance travelled (which may skip a sliver of ridge at grazing
        angles: what is drawn is then what the depth says)."""
        n = d.shape[0]
        dxy = torch.hypot(d[:, 0], d[:, 1])
        b = o[0] * d[:, 0] + o[1] * d[:, 1]
        r2 = float(o[0] ** 2 + o[1] ** 2)
        t_start = (-b + torch.sqrt(b * b - dxy**2 * (r2 - FLAT_RADIUS**2))) / dxy**2
        t_end = (-b + torch.sqrt(b * b - dxy**2 * (r2 - DOMAIN_RADIUS**2))) / dxy**2
        dz = d[:, 2]
        # Above the highest peak or below the plane nothing more can be hit.
        up_limit = (self.z_max - o[2]) / dz.clamp_min(1e-12)
        down_limit = (-self.camera_height - o[2]) / dz.clamp(max=-1e-12)
        t_end = torch.minimum(t_end, torch.where(dz > 0, up_limit, down_limit))
        # How fast a ray can close in on the terrain anywhere per unit length; <= 0: never.
        approach = self._max_slope * dxy - dz

        lo = torch.zeros(n)
        hi = torch.zeros(n)
        hit = torch.zeros(n, dtype=torch.bool)
        active = ((t_end > t_start) & (approach > 0)).nonzero()[:, 0]
        # The marching rays' state, compacted as rays finish.
        d_act, end, horiz, t = d[active], t_end[active], dxy[active], t_start[active]
        gap = self.gap(o, d_act, t)
        for _ in range(MARCH_MAX_STEPS):
            if active.numel() == 0:
                break
            # Within the look-ahead window the local slope bound holds.
            radius = torch.hypot(o[0] + t * d_act[:, 0], o[1] + t * d_act[:, 1])
            local = self._ring_slope_ahead[(radius / SLOPE_RING).long()]
            window = MARCH_LOOKAHEAD / horiz
            closing = local * horiz - d_act[:, 2]
            safe = torch.where(closing > 0, torch.minimum(gap / closing, window), window)
            t_next = torch.minimum(t + torch.maximum(safe, MARCH_MIN_STEP * t), end)
            gap = self.gap(o, d_act, t_next)
            crossed = gap <= 0
            idx = active[crossed]
            lo[idx], hi[idx], hit[idx] = t[crossed], t_next[crossed], True
            going = (~crossed & (t_next < end)).nonzero()[:, 0]
            active, d_act, end, horiz = active[going], d_act[going], end[going], horiz[going]
            t, gap = t_next[going], gap[going]
        if active.numel() > 0:
            raise RuntimeError(f"terrain march did not finish for {active.numel()} rays")

        idx = hit.nonzero()[:, 0]
        dh, lo_h, hi_h = d[idx], lo[idx], hi[idx]
        for _ in range(REFINE_BISECTIONS):
            mid = 0.5 * (lo_h + hi_h)
            above = self.gap(o, dh, mid) > 0
            lo_h, hi_h = torch.where(above, mid, lo_h), torch.where(above, hi_h, mid)
        g_lo, g_hi = self.gap(o, dh, lo_h), self.gap(o, dh, hi_h)
        t = hi_h
        for _ in range(REFINE_SECANTS):
            t = lo_h + (hi_h - lo_h) * (g_lo / (g_lo - g_hi).clamp_min(1e-12))
            g = self.gap(o, dh, t)
            above = g > 0
            lo_h, g_lo = torch.where(above, t, lo_h), torch.where(above, g, g_lo)
            hi_h, g_hi = torch.where(above, hi_h, t), torch.where(above, g_hi, g)
        out = torch.zeros(n)
        out[idx] = t
        return out, hit
