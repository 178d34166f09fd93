"""Synthetic 4D landscapes with exact ground truth (``pano4d synth``).

A procedural outdoor scene, deterministic from a seed: a flat meadow around the camera with
a lake, a ring of hills and snow-capped mountains (a heightfield), a few solid objects
(spheres, boxes, poles) standing on the ground, and a sky sphere with drifting clouds. All of
it is analytic, so a ray from ANY camera position has an exact answer (what it hits, how far,
which colour): the panorama, its ray-length depth, the animation and the displaced
perspective views (the novel-view test set) are all rendered by the same ray caster.

World frame (DESIGN.md): +z up, the panorama's camera at the origin, the ground plane at
z = −camera_height. Motion: the water (waves travelling in one direction) and the clouds
(drifting towards +u, i.e. eastwards in the image) move, periodically with period L frames so
the animation loops; everything else is static and bit-identical in every frame.

Terrain: heights on a regular grid, bilinearly interpolated (``Landscape.terrain_height`` is
that exact surface). Inside ``FLAT_RADIUS`` it is exactly the plane, which rays hit
analytically; beyond, rays are marched with geometric steps and the first sign change is
refined by bisection and false position, so the reported depth lies on the drawn surface to
float32 precision.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from pano4d.camera import Camera
from pano4d.fsutil import write_json_atomic, write_text_atomic
from pano4d.sphere import check_panorama_size, equirect_directions

SKY_DEPTH = 1000.0  # the sky is a sphere of this radius around the origin (finite far depth)
CAMERA_HEIGHT = 2.0

# Labels of what a ray hit; object i gets LABEL_OBJECT + i.
LABEL_SKY, LABEL_TERRAIN, LABEL_WATER, LABEL_OBJECT = 0, 1, 2, 3

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

# The cloud field repeats CLOUD_REPEATS times around the sky; over L frames it drifts by one
# repeat, so the drift loops.
CLOUD_REPEATS = 6
CLOUD_TEXELS = 384  # texels per repeat along the azimuth
CLOUD_LOG_RHO = (-3.0, 5.5)  # log of the cloud-plane radius (cot of elevation) covered

WATER_WAVES = 7
VIEW_FOV_DEG = 75.0
VIEW_FRACTIONS = (0.01, 0.05)  # camera displacement / median scene depth, alternating
DEPTH_PROBE_SIZE = (512, 256)  # panorama size used to measure the median scene depth

OBJECT_KINDS = ("sphere", "box", "pole", "sphere", "box", "pole")
OBJECT_COLOURS = (
    (0.75, 0.12, 0.10), (0.90, 0.85, 0.75), (0.85, 0.20, 0.15),
    (0.15, 0.30, 0.70), (0.55, 0.35, 0.20), (0.95, 0.95, 0.92),
)  # fmt: skip


# --- small helpers ---------------------------------------------------------------------
def _smoothstep(
    lo: float | torch.Tensor, hi: float | torch.Tensor, x: torch.Tensor
) -> torch.Tensor:
    s = ((x - lo) / (hi - lo)).clamp(0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def _rgb(*values: float) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.float32)


def _lerp(a: torch.Tensor, b: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """a + (b − a)·w with colours (…, 3) and a weight (…,)."""
    return torch.lerp(a, b, w[..., None])


def _normalize(v: torch.Tensor) -> torch.Tensor:
    return v / torch.linalg.norm(v, dim=-1, keepdim=True).clamp_min(1e-12)


def _fft_noise(
    gen: torch.Generator, rows: int, cols: int, exponent: float, largest: float
) -> torch.Tensor:
    """Periodic fractal noise (rows, cols), zero mean, unit std: amplitude ∝ k^-exponent.

    ``largest`` is the longest wavelength kept, in texels; longer ones are flattened so a
    texture does not turn into one big gradient.
    """
    fy = torch.fft.fftfreq(rows)[:, None]
    fx = torch.fft.rfftfreq(cols)[None, :]
    k = torch.sqrt(fy * fy + fx * fx)
    amp = k.clamp_min(1.0 / largest) ** -exponent
    amp[0, 0] = 0.0
    re = torch.randn(rows, cols // 2 + 1, generator=gen)
    im = torch.randn(rows, cols // 2 + 1, generator=gen)
    noise = torch.fft.irfft2(torch.complex(re, im) * amp, s=(rows, cols))
    return (noise - noise.mean()) / noise.std()


def _sample(texture: torch.Tensor, gx: torch.Tensor, gy: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup of a (C, R, C') texture at normalised coordinates in [-1, 1] → (N, C)."""
    grid = torch.stack([gx, gy], dim=-1).view(1, 1, -1, 2)
    out = F.grid_sample(
        texture[None], grid, mode="bilinear", padding_mode="border", align_corners=True
    )
    return out[0, :, 0].T


def _periodic(texture: torch.Tensor) -> torch.Tensor:
    """(C, R, C') texture with its first row and column repeated at the end, for wrap-around."""
    return F.pad(texture[None], (0, 1, 0, 1), mode="circular")[0]


def _wrap(x: torch.Tensor) -> torch.Tensor:
    """Fractional part mapped to the [-1, 1] coordinates of a ``_periodic`` texture."""
    return torch.remainder(x, 1.0) * 2.0 - 1.0


# --- scene description -----------------------------------------------------------------
@dataclass(frozen=True)
class SceneObject:
    """A solid object standing on the ground.

    ``size``: sphere (radius, radius, radius); box half extents (x, y, z) before the yaw;
    pole (radius, radius, half height). ``centre`` is the object's centre in world metres.
    """

    kind: str
    centre: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw_deg: float
    colour: tuple[float, float, float]

    def bounding_radius(self) -> float:
        if self.kind == "sphere":
            return self.size[0]
        if self.kind == "pole":
            return math.hypot(self.size[0], self.size[2])
        return math.hypot(*self.size)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "centre": list(self.centre),
            "size": list(self.size),
            "yaw_deg": self.yaw_deg,
            "colour": list(self.colour),
        }


@dataclass
class _SkyRays:
    """Per sky ray: colour without clouds and the cloud lookup's time-independent inputs."""

    base: torch.Tensor  # (N, 3)
    cloud_x: torch.Tensor  # (N,) azimuth in cloud repeats
    cloud_y: torch.Tensor  # (N,) texture row in [-1, 1]
    threshold: torch.Tensor  # (N,) noise level where the cloud starts
    fade: torch.Tensor  # (N,)
    sunward: torch.Tensor  # (N,)


@dataclass
class Hits:
    """What rays from one origin hit: ray length, label and surface normal per ray."""

    depth: torch.Tensor  # (N,) float32
    label: torch.Tensor  # (N,) uint8
    normal: torch.Tensor  # (N, 3) float32, geometric (water's waves are added when shading)

    def subset(self, index: torch.Tensor) -> Hits:
        return Hits(self.depth[index], self.label[index], self.normal[index])


class Landscape:
    """The analytic scene of one seed: geometry, materials, lighting and motion.

    ``frames`` is the loop period L: every moving thing is a periodic function of the
    time index with period L.
    """

    def __init__(self, seed: int, frames: int, camera_height: float = CAMERA_HEIGHT) -> None:
        if frames < 1:
            raise ValueError(f"frames must be >= 1, got {frames}")
        if not camera_height > 0:
            raise ValueError(f"camera_height must be positive, got {camera_height}")
        self.seed = int(seed)
        self.frames = int(frames)
        self.camera_height = float(camera_height)
        gen = torch.Generator().manual_seed(self.seed)
        rand = lambda lo, hi: lo + (hi - lo) * float(torch.rand((), generator=gen))  # noqa: E731

        sun_azimuth, sun_elevation = rand(0.0, 2 * math.pi), math.radians(rand(22.0, 42.0))
        self.sun = torch.tensor(
            [
                math.cos(sun_elevation) * math.cos(sun_azimuth),
                math.cos(sun_elevation) * math.sin(sun_azimuth),
                math.sin(sun_elevation),
            ],
            dtype=torch.float32,
        )
        self._build_terrain(gen)
        self._build_textures(gen)

        # Lake: an ellipse on the meadow with a noisy shore, its long axis pointing away from
        # the camera, which stands a few metres from the water.
        lake_azimuth = rand(0.0, 2 * math.pi)
        self.lake_axes = (rand(22.0, 28.0), rand(12.0, 17.0))
        lake_distance = self.lake_axes[0] + rand(3.0, 6.0)
        self.lake_centre = (
            lake_distance * math.cos(lake_azimuth),
            lake_distance * math.sin(lake_azimuth),
        )
        self.lake_angle = lake_azimuth + rand(-0.3, 0.3)

        # Waves: directions spread around one travel direction, integer cycles per loop.
        self.wave_direction = rand(0.0, 2 * math.pi)
        angles = self.wave_direction + torch.empty(WATER_WAVES).uniform_(-0.5, 0.5, generator=gen)
        wavelengths = torch.empty(WATER_WAVES).uniform_(0.6, 4.0, generator=gen)
        k = 2 * math.pi / wavelengths
        self.wave_vectors = torch.stack([k * torch.cos(angles), k * torch.sin(angles)], -1)
        self.wave_slopes = torch.empty(WATER_WAVES).uniform_(0.04, 0.10, generator=gen)
        self.wave_cycles = torch.randint(1, 3, (WATER_WAVES,), generator=gen).float()
        self.wave_phases = torch.empty(WATER_WAVES).uniform_(0, 2 * math.pi, generator=gen)
        self.cloud_cover = rand(0.35, 0.6)

        self.objects = self._place_objects(gen)

    # --- construction ------------------------------------------------------------------
    def _build_terrain(self, gen: torch.Generator) -> None:
        n = TERRAIN_GRID
        axis = torch.linspace(-TERRAIN_EXTENT, TERRAIN_EXTENT, n)
        yy, xx = torch.meshgrid(axis, axis, indexing="ij")
        r = torch.hypot(xx, yy)
        cell = 2 * TERRAIN_EXTENT / (n - 1)
        hills = _fft_noise(gen, n, n, 2.4, largest=220.0 / cell)
        ridges = 1.0 - _fft_noise(gen, n, n, 2.3, largest=300.0 / cell).abs().clamp(max=2.0) / 2.0
        peaks = _fft_noise(gen, n, n, 2.6, largest=500.0 / cell)
        hill_height = 28.0 * _smoothstep(HILLS_START, 170.0, r) * (0.55 + 0.45 * hills).clamp_min(0)
        mountain_height = (
            180.0
            * _smoothstep(220.0, 460.0, r)
            * (0.35 + 0.45 * ridges**2 + 0.25 * peaks).clamp_min(0.3)
        )
        above_ground = hill_height + mountain_height
        above_ground[r <= HILLS_START] = 0.0  # exactly flat: the meadow is the plane
        self.terrain_z = above_ground - self.camera_height  # world z of the grid vertices
        self._terrain_tex = self.terrain_z[None].contiguous()
        self.terrain_z_max = float(self.terrain_z.max())

        gy, gx = torch.gradient(self.terrain_z, spacing=cell)
        self._terrain_normal_tex = _normalize(torch.stack([-gx, -gy, torch.ones_like(gx)], -1))
        self._terrain_normal_tex = self._terrain_normal_tex.permute(2, 0, 1).contiguous()
        # Skyline bound: blocks of SKYLINE_BLOCK² vertices, each with its highest vertex
        # (bilinear patches never rise above their corners) and the farthest any point of
        # the block, or of a patch reaching out of it, can be from its centre.
        k = SKYLINE_BLOCK
        self._block_top = F.max_pool2d(self.terrain_z[None], k, stride=k).reshape(-1)
        self._block_xy = torch.stack(
            [F.avg_pool2d(c[None], k, stride=k).reshape(-1) for c in (xx, yy)], -1
        )
        self._block_reach = (k + 1) * cell * math.sqrt(2.0) / 2
        # March bounds: the steepest slope of any bilinear patch (no steeper than its
        # steepest edges in x and y).
        edge_x = (self.terrain_z[:, 1:] - self.terrain_z[:, :-1]).abs()
        edge_y = (self.terrain_z[1:] - self.terrain_z[:-1]).abs()
        patch_slope = torch.hypot(
            torch.maximum(edge_x[:-1], edge_x[1:]), torch.maximum(edge_y[:, :-1], edge_y[:, 1:])
        ) * (1.001 / cell)
        self._terrain_max_slope = float(patch_slope.max())
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

    def _build_textures(self, gen: torch.Generator) -> None:
        detail = torch.stack([_fft_noise(gen, 512, 512, e, largest=128.0) for e in (1.2, 0.9)])
        self._detail_tex = _periodic(detail)
        rows = round(
            (CLOUD_LOG_RHO[1] - CLOUD_LOG_RHO[0]) / (2 * math.pi / CLOUD_REPEATS) * CLOUD_TEXELS
        )
        clouds = _fft_noise(gen, rows, CLOUD_TEXELS, 1.75, largest=CLOUD_TEXELS / 2)
        self._cloud_tex = _periodic(clouds[None])

    def _place_objects(self, gen: torch.Generator) -> list[SceneObject]:
        objects: list[SceneObject] = []
        h = self.camera_height
        for index, kind in enumerate(OBJECT_KINDS):
            for _ in range(200):
                u = torch.rand(8, generator=gen).tolist()
                distance, azimuth = 11.0 + 34.0 * u[0], 2 * math.pi * u[1]
                x, y = distance * math.cos(azimuth), distance * math.sin(azimuth)
                if kind == "sphere":
                    radius = 0.8 + 1.6 * u[2]
                    obj = SceneObject(
                        kind, (x, y, radius - h), (radius,) * 3, 0.0, OBJECT_COLOURS[index]
                    )
                elif kind == "box":
                    half = (0.6 + 1.6 * u[2], 0.6 + 1.6 * u[3], 0.6 + 1.8 * u[4])
                    obj = SceneObject(
                        kind, (x, y, half[2] - h), half, 360.0 * u[5], OBJECT_COLOURS[index]
                    )
                else:
                    radius, half_height = 0.12 + 0.1 * u[2], 2.5 + 2.0 * u[3]
                    size = (radius, radius, half_height)
                    obj = SceneObject(
                        kind, (x, y, half_height - h), size, 0.0, OBJECT_COLOURS[index]
                    )
                footprint = obj.bounding_radius() + 1.5
                on_shore = self._lake_level(torch.tensor([x]), torch.tensor([y]), footprint)
                apart = all(
                    math.dist(obj.centre[:2], o.centre[:2]) > footprint + o.bounding_radius() + 2.0
                    for o in objects
                )
                if bool(on_shore[0] > 1.0) and apart:
                    objects.append(obj)
                    break
            else:
                raise RuntimeError(f"seed {self.seed}: no room for object {index} ({kind})")
        return objects

    # --- metadata ------------------------------------------------------------------------
    @property
    def cloud_speed_deg(self) -> float:
        """Cloud drift in degrees of azimuth per frame (towards +u)."""
        return 360.0 / CLOUD_REPEATS / self.frames

    def metadata(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "frames": self.frames,
            "camera_height": self.camera_height,
            "sky_depth": SKY_DEPTH,
            "sun_direction": self.sun.tolist(),
            "lake": {
                "centre": list(self.lake_centre),
                "axes": list(self.lake_axes),
                "angle_deg": math.degrees(self.lake_angle),
            },
            "cloud_drift": {"direction_deg": 0.0, "speed_deg_per_frame": self.cloud_speed_deg},
            "wave_direction_deg": math.degrees(self.wave_direction),
            "objects": [o.to_dict() for o in self.objects],
        }

    # --- surfaces ------------------------------------------------------------------------
    def terrain_height(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """World z of the terrain surface (bilinear over the grid) at (x, y), any shape.

        The march (``_terrain_gap``) samples the same grid with the same arithmetic."""
        out = _sample(
            self._terrain_tex, x.reshape(-1) / TERRAIN_EXTENT, y.reshape(-1) / TERRAIN_EXTENT
        )
        return out[:, 0].view(x.shape)

    def _terrain_normal(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return _normalize(_sample(self._terrain_normal_tex, x / TERRAIN_EXTENT, y / TERRAIN_EXTENT))

    def _detail(
        self, x: torch.Tensor, y: torch.Tensor, period: float, channel: int
    ) -> torch.Tensor:
        tex = self._detail_tex[channel : channel + 1]
        return _sample(tex, _wrap(x / period), _wrap(y / period))[:, 0]

    def _detail_tex_at(self, gx: torch.Tensor, gy: torch.Tensor) -> torch.Tensor:
        """The coarse detail noise at texture coordinates (1 = one period)."""
        return _sample(self._detail_tex[:1], _wrap(gx), _wrap(gy))[:, 0]

    def _lake_level(self, x: torch.Tensor, y: torch.Tensor, margin: float = 0.0) -> torch.Tensor:
        """< 1 inside the lake (shore noise included), > 1 outside; ``margin`` metres widen it.

        The shore noise moves the level by at most 0.1, so beyond 1.3 (well past the sand)
        it is left out: there the level is the plain elliptical distance."""
        cx, cy = self.lake_centre
        c, s = math.cos(self.lake_angle), math.sin(self.lake_angle)
        dx, dy = x - cx, y - cy
        a, b = self.lake_axes[0] + margin, self.lake_axes[1] + margin
        level = torch.sqrt(((c * dx + s * dy) / a) ** 2 + ((-s * dx + c * dy) / b) ** 2)
        near = (level < 1.3).nonzero()[:, 0]
        shore = self._detail(x[near], y[near], 150.0, 0).clamp(-2.0, 2.0)
        level[near] += 0.05 * shore
        return level

    def surface_residual(self, points: torch.Tensor, label: torch.Tensor) -> torch.Tensor:
        """Signed distance-like residual (N,) of world points to the surface named by ``label``.

        Zero (to float precision) for a point on that surface: what the depth tests check.
        """
        res = torch.full(label.shape, float("nan"))
        x, y, z = points.unbind(-1)
        sky = label == LABEL_SKY
        res[sky] = torch.linalg.norm(points[sky], dim=-1) - SKY_DEPTH
        ground = label == LABEL_TERRAIN
        res[ground] = z[ground] - self.terrain_height(x[ground], y[ground])
        water = label == LABEL_WATER
        res[water] = z[water] + self.camera_height
        for i, obj in enumerate(self.objects):
            sel = label == LABEL_OBJECT + i
            local = self._to_object(obj, points[sel])
            sx, sy, sz = obj.size
            if obj.kind == "sphere":
                res[sel] = torch.linalg.norm(local, dim=-1) - sx
            elif obj.kind == "box":
                res[sel] = (local.abs() - torch.tensor([sx, sy, sz])).amax(dim=-1)
            else:
                radial = torch.hypot(local[:, 0], local[:, 1]) - sx
                res[sel] = torch.maximum(radial, local[:, 2].abs() - sz)
        return res

    @staticmethod
    def _to_object(obj: SceneObject, v: torch.Tensor, direction: bool = False) -> torch.Tensor:
        """World points (or directions) into the object's frame (centred, yaw undone)."""
        if not direction:
            v = v - torch.tensor(obj.centre, dtype=v.dtype)
        c, s = math.cos(math.radians(obj.yaw_deg)), math.sin(math.radians(obj.yaw_deg))
        return torch.stack([c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1], v[:, 2]], -1)

    # --- ray casting ---------------------------------------------------------------------
    def cast(self, origin: Sequence[float] | torch.Tensor, dirs: torch.Tensor) -> Hits:
        """Intersect rays from one ``origin`` (3,) along unit ``dirs`` (N, 3) with the scene."""
        o = torch.as_tensor(origin, dtype=torch.float32).reshape(3)
        if (
            float(torch.hypot(o[0], o[1])) >= FLAT_RADIUS - 1.0
            or not -self.camera_height < float(o[2]) < 50.0
        ):
            raise ValueError(
                f"camera position {o.tolist()} is outside the meadow the scene supports"
            )
        d = dirs.to(torch.float32).reshape(-1, 3)
        n = d.shape[0]
        # The sky sphere around the origin (exactly SKY_DEPTH for the panorama's camera).
        b = d @ o
        depth = -b + torch.sqrt(b * b - (float(o @ o) - SKY_DEPTH**2))
        label = torch.full((n,), LABEL_SKY, dtype=torch.uint8)

        # The meadow and the lake: the plane z = -h inside FLAT_RADIUS.
        down = d[:, 2] < 0
        t_plane = torch.where(
            down, (-self.camera_height - o[2]) / d[:, 2].clamp(max=-1e-12), torch.inf
        )
        px, py = o[0] + t_plane * d[:, 0], o[1] + t_plane * d[:, 1]
        on_meadow = down & (px * px + py * py < FLAT_RADIUS**2)
        depth = torch.where(on_meadow, t_plane, depth)
        idx = on_meadow.nonzero()[:, 0]
        wet = self._lake_level(px[idx], py[idx]) < 1.0
        label[idx] = torch.where(wet, LABEL_WATER, LABEL_TERRAIN).to(torch.uint8)

        march = self._terrain_candidates(o, d) & ~on_meadow
        idx = march.nonzero()[:, 0]
        t_hit, hit = self._march_terrain(o, d[idx])
        idx = idx[hit]
        depth[idx] = t_hit[hit]
        label[idx] = LABEL_TERRAIN

        normal = torch.zeros(n, 3)
        for i, obj in enumerate(self.objects):
            near = self._rays_near(obj, o, d)
            idx, t_obj, n_obj = self._intersect_object(obj, o, d[near])
            idx = near[idx]
            closer = t_obj < depth[idx]
            idx = idx[closer]
            depth[idx], label[idx], normal[idx] = t_obj[closer], LABEL_OBJECT + i, n_obj[closer]

        normal[label == LABEL_SKY] = -d[label == LABEL_SKY]
        normal[label == LABEL_WATER] = torch.tensor([0.0, 0.0, 1.0])
        ground = (label == LABEL_TERRAIN).nonzero()[:, 0]
        gp = o + depth[ground, None] * d[ground]
        normal[ground] = self._terrain_normal(gp[:, 0], gp[:, 1])
        return Hits(depth, label, normal)

    def _terrain_candidates(self, o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
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

    def _terrain_gap(self, o: torch.Tensor, d: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Height of the ray above the terrain at ray lengths t (negative: below)."""
        xy = (o[:2] + t[:, None] * d[:, :2]) * (1.0 / TERRAIN_EXTENT)
        out = F.grid_sample(
            self._terrain_tex[None], xy.view(1, 1, -1, 2), mode="bilinear",
            padding_mode="border", align_corners=True,
        )  # fmt: skip
        return o[2] + t * d[:, 2] - out.view(-1)

    def _march_terrain(self, o: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
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
        up_limit = (self.terrain_z_max - o[2]) / dz.clamp_min(1e-12)
        down_limit = (-self.camera_height - o[2]) / dz.clamp(max=-1e-12)
        t_end = torch.minimum(t_end, torch.where(dz > 0, up_limit, down_limit))
        # How fast a ray can close in on the terrain anywhere per unit length; <= 0: never.
        approach = self._terrain_max_slope * dxy - dz

        lo = torch.zeros(n)
        hi = torch.zeros(n)
        hit = torch.zeros(n, dtype=torch.bool)
        active = ((t_end > t_start) & (approach > 0)).nonzero()[:, 0]
        # The marching rays' state, compacted as rays finish.
        d_act, end, horiz, t = d[active], t_end[active], dxy[active], t_start[active]
        gap = self._terrain_gap(o, d_act, t)
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
            gap = self._terrain_gap(o, d_act, t_next)
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
            above = self._terrain_gap(o, dh, mid) > 0
            lo_h, hi_h = torch.where(above, mid, lo_h), torch.where(above, hi_h, mid)
        g_lo, g_hi = self._terrain_gap(o, dh, lo_h), self._terrain_gap(o, dh, hi_h)
        t = hi_h
        for _ in range(REFINE_SECANTS):
            t = lo_h + (hi_h - lo_h) * (g_lo / (g_lo - g_hi).clamp_min(1e-12))
            g = self._terrain_gap(o, dh, t)
            above = g > 0
            lo_h, g_lo = torch.where(above, t, lo_h), torch.where(above, g, g_lo)
            hi_h, g_hi = torch.where(above, hi_h, t), torch.where(above, g_hi, g)
        out = torch.zeros(n)
        out[idx] = t
        return out, hit

    @staticmethod
    def _rays_near(obj: SceneObject, o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """Indices of the rays from ``o`` that pass through the object's bounding sphere."""
        oc = o - torch.tensor(obj.centre)
        b = d @ oc
        disc = b * b - (float(oc @ oc) - obj.bounding_radius() ** 2)
        idx = (disc > 0).nonzero()[:, 0]
        return idx[(-b[idx] + torch.sqrt(disc[idx])) > 0]

    def _intersect_object(
        self, obj: SceneObject, o: torch.Tensor, d: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Rays hitting ``obj``: their indices, ray lengths and world normals.

        ``o`` is one origin (3,) or one per ray (N, 3); ``d`` (N, 3) or one shared (1, 3).
        Callers pass only rays near the object (``_rays_near``, ``_object_shadow``).
        """
        n = o.shape[0] if o.dim() == 2 else d.shape[0]
        o, d = o.expand(n, 3), d.expand(n, 3)
        ol = self._to_object(obj, o)
        dl = self._to_object(obj, d, direction=True)
        sx, sy, sz = obj.size
        if obj.kind == "sphere":
            bb = (dl * ol).sum(-1)
            disc_s = bb * bb - ((ol * ol).sum(-1) - sx * sx)
            t = -bb - torch.sqrt(disc_s.clamp_min(0))
            t = torch.where((disc_s >= 0) & (t > 0), t, torch.inf)
            local_n = ol + t[:, None].clamp(max=1e9) * dl
        elif obj.kind == "box":
            half = torch.tensor([sx, sy, sz])
            inv = 1.0 / torch.where(dl.abs() < 1e-12, torch.full_like(dl, 1e-12), dl)
            t1, t2 = (-half - ol) * inv, (half - ol) * inv
            t_near, axis = torch.minimum(t1, t2).max(dim=-1)
            t_far = torch.maximum(t1, t2).amin(dim=-1)
            t = torch.where((t_near <= t_far) & (t_near > 0), t_near, torch.inf)
            local_n = torch.zeros_like(dl)
            local_n.scatter_(1, axis[:, None], -torch.sign(dl.gather(1, axis[:, None])))
        else:
            # Side of the vertical cylinder, then its top cap (the bottom is underground).
            a = dl[:, 0] ** 2 + dl[:, 1] ** 2
            bb = ol[:, 0] * dl[:, 0] + ol[:, 1] * dl[:, 1]
            disc_c = bb * bb - a * (ol[:, 0] ** 2 + ol[:, 1] ** 2 - sx * sx)
            t_side = (-bb - torch.sqrt(disc_c.clamp_min(0))) / a.clamp_min(1e-12)
            z_side = ol[:, 2] + t_side * dl[:, 2]
            side = (disc_c >= 0) & (t_side > 0) & (z_side.abs() <= sz)
            dz = torch.where(dl[:, 2].abs() < 1e-12, torch.full_like(a, -1e-12), dl[:, 2])
            t_cap = (sz - ol[:, 2]) / dz
            cap_xy = ol[:, :2] + t_cap[:, None] * dl[:, :2]
            cap = (t_cap > 0) & ((cap_xy**2).sum(-1) <= sx * sx) & (dl[:, 2] < 0)
            t = torch.where(side, t_side, torch.where(cap, t_cap, torch.inf))
            p = ol + t[:, None].clamp(max=1e9) * dl
            local_n = torch.where(
                side[:, None],
                torch.stack([p[:, 0], p[:, 1], torch.zeros_like(a)], -1),
                torch.tensor([0.0, 0.0, 1.0]).expand_as(p),
            )
        c, s = math.cos(math.radians(obj.yaw_deg)), math.sin(math.radians(obj.yaw_deg))
        world_n = torch.stack(
            [
                c * local_n[:, 0] - s * local_n[:, 1],
                s * local_n[:, 0] + c * local_n[:, 1],
                local_n[:, 2],
            ],
            -1,
        )
        keep = torch.isfinite(t).nonzero()[:, 0]
        return keep, t[keep], _normalize(world_n[keep])

    # --- shading -------------------------------------------------------------------------
    def moves(self, label: torch.Tensor) -> torch.Tensor:
        """Which labels change over time: the sky (clouds) and the water."""
        return (label == LABEL_SKY) | (label == LABEL_WATER)

    def shade(self, o: torch.Tensor, d: torch.Tensor, hits: Hits, time: int) -> torch.Tensor:
        """Colour (N, 3) in [0, 1] of every ray at time index ``time``."""
        o = torch.as_tensor(o, dtype=torch.float32).reshape(3)
        rgb = torch.empty(d.shape[0], 3)
        moving = self.moves(hits.label)
        static = (~moving).nonzero()[:, 0]
        rgb[static] = self.shade_static(o, d[static], hits.subset(static))
        dyn = moving.nonzero()[:, 0]
        rgb[dyn] = self.shade_moving(o, d[dyn], hits.subset(dyn), time)
        return rgb

    def shade_static(self, o: torch.Tensor, d: torch.Tensor, hits: Hits) -> torch.Tensor:
        """Colour of rays that hit terrain or objects (no time dependence)."""
        p = o + hits.depth[:, None] * d
        albedo = torch.empty_like(p)
        ground = hits.label == LABEL_TERRAIN
        albedo[ground] = self._ground_albedo(p[ground], hits.normal[ground], hits.depth[ground])
        for i, obj in enumerate(self.objects):
            sel = hits.label == LABEL_OBJECT + i
            colour = _rgb(*obj.colour).expand(int(sel.sum()), 3)
            if obj.kind == "pole":  # painted bands every half metre
                band = torch.floor((p[sel, 2] - obj.centre[2]) / 0.5).remainder(2)
                colour = torch.where(band[:, None] > 0, colour, colour * 0.25 + 0.7)
            albedo[sel] = colour
        lit = self._lighting(p, hits.normal, self._object_shadow(p))
        return self._fog(albedo * lit, d, hits.depth).clamp(0.0, 1.0)

    def shade_moving(self, o: torch.Tensor, d: torch.Tensor, hits: Hits, time: int) -> torch.Tensor:
        """Colour of rays that hit the sky or the water at time index ``time``."""
        return self.moving_shader(o, d, hits)(time)

    def moving_shader(
        self, o: torch.Tensor, d: torch.Tensor, hits: Hits
    ) -> Callable[[int], torch.Tensor]:
        """time -> colour (N, 3) of rays that hit the sky or the water; what does not depend on
        time is computed once, here."""
        sky = (hits.label == LABEL_SKY).nonzero()[:, 0]
        water = (hits.label != LABEL_SKY).nonzero()[:, 0]
        # The sky is drawn by direction from the origin, so every camera sees the same dome.
        sky_rays = self._sky_rays((o + hits.depth[sky, None] * d[sky]) / SKY_DEPTH)
        water_points = o + hits.depth[water, None] * d[water]
        water_dirs, water_dist = d[water], hits.depth[water]

        def at(time: int) -> torch.Tensor:
            rgb = torch.empty_like(d)
            rgb[sky] = self._sky_colour(sky_rays, time)
            rgb[water] = self._water(water_points, water_dirs, water_dist, time)
            return rgb.clamp(0.0, 1.0)

        return at

    def _phase(self, time: int) -> float:
        """Position in the loop, in [0, 1): exact periodicity, frame L is frame 0."""
        return (int(time) % self.frames) / self.frames

    def _sky_gradient(self, d: torch.Tensor) -> torch.Tensor:
        elevation = torch.asin(d[:, 2].clamp(-1.0, 1.0))
        up = (elevation.clamp_min(0) / (math.pi / 2)) ** 0.45
        colour = _lerp(_rgb(0.80, 0.86, 0.92), _rgb(0.20, 0.40, 0.78), up)
        cos_sun = (d @ self.sun).clamp_min(0)
        glow = 0.35 * cos_sun**8 + 0.5 * cos_sun**300
        disk = (cos_sun > math.cos(math.radians(0.6))).float() * 2.0
        return colour + (glow + disk)[:, None] * _rgb(1.0, 0.93, 0.80)

    def _sky_rays(self, d: torch.Tensor) -> _SkyRays:
        """The time-independent part of the sky along unit directions d.

        Clouds live in log-polar coordinates on a cloud deck, so they keep their shape and
        shrink towards the horizon; the field repeats CLOUD_REPEATS times in azimuth."""
        azimuth = torch.atan2(-d[:, 1], d[:, 0])  # grows with u, like the equirect longitude
        horizontal = torch.hypot(d[:, 0], d[:, 1])
        rho = horizontal / d[:, 2].clamp_min(1e-4)
        log_rho = torch.log(rho.clamp_min(1e-6)).clamp(*CLOUD_LOG_RHO)
        cloud_y = (log_rho - CLOUD_LOG_RHO[0]) / (CLOUD_LOG_RHO[1] - CLOUD_LOG_RHO[0]) * 2 - 1
        # A static, non-repeating modulation of the cover hides the repeats.
        cover = self.cloud_cover + 0.25 * self._detail_tex_at(azimuth / (2 * math.pi), log_rho / 6)
        # Thin out near the zenith (the log-polar pole) and fade into the horizon haze.
        fade = _smoothstep(0.0, 0.12, d[:, 2]) * (1.0 - _smoothstep(0.8, 0.97, d[:, 2]))
        return _SkyRays(
            base=self._sky_gradient(d),
            cloud_x=azimuth * (CLOUD_REPEATS / (2 * math.pi)),
            cloud_y=cloud_y,
            threshold=1.2 - 2.0 * cover,
            fade=fade,
            sunward=(d @ self.sun).clamp_min(0),
        )

    def _sky_colour(self, rays: _SkyRays, time: int) -> torch.Tensor:
        drift = self._phase(time)  # one repeat per loop, towards +u
        noise = _sample(self._cloud_tex, _wrap(rays.cloud_x - drift), rays.cloud_y)[:, 0]
        density = _smoothstep(rays.threshold, rays.threshold + 1.1, noise) * rays.fade
        cloud = _lerp(
            _rgb(0.62, 0.65, 0.72), _rgb(1.0, 0.99, 0.97), (1 - density) * 0.6 + 0.3 * rays.sunward
        )
        return _lerp(rays.base, cloud, density * 0.95)

    def _sky(self, d: torch.Tensor, time: int) -> torch.Tensor:
        return self._sky_colour(self._sky_rays(d), time)

    def _ground_albedo(
        self, p: torch.Tensor, normal: torch.Tensor, dist: torch.Tensor
    ) -> torch.Tensor:
        x, y = p[:, 0], p[:, 1]
        height = p[:, 2] + self.camera_height
        slope = 1.0 - normal[:, 2]
        coarse = self._detail(x, y, 90.0, 0)
        fine = self._detail(x, y, 7.0, 1) * (1.0 - _smoothstep(30.0, 120.0, dist))
        grass = _lerp(
            _rgb(0.17, 0.32, 0.08), _rgb(0.42, 0.46, 0.17), _smoothstep(-1.2, 1.5, coarse)
        )
        grass = grass * (1.0 + 0.18 * fine)[:, None]
        rock = _rgb(0.44, 0.41, 0.35) * (1.0 + 0.12 * coarse + 0.1 * fine)[:, None]
        sand = _rgb(0.72, 0.66, 0.48) * (1.0 + 0.08 * fine)[:, None]
        snow = _rgb(0.94, 0.95, 0.98).expand_as(p)
        colour = _lerp(
            grass,
            rock,
            (_smoothstep(0.12, 0.3, slope + 0.04 * coarse) + _smoothstep(50.0, 90.0, height)).clamp(
                max=1.0
            ),
        )
        shore = 1.0 - _smoothstep(1.0, 1.08, self._lake_level(x, y))
        colour = _lerp(colour, sand, shore)
        snowy = _smoothstep(105.0, 125.0, height + 8.0 * coarse) * (
            1.0 - _smoothstep(0.35, 0.55, slope)
        )
        return _lerp(colour, snow, snowy)

    def _lighting(
        self, p: torch.Tensor, normal: torch.Tensor, shadow: torch.Tensor
    ) -> torch.Tensor:
        sun = (normal @ self.sun).clamp_min(0) * shadow
        sky = 0.55 + 0.45 * normal[:, 2]
        return sun[:, None] * _rgb(1.05, 0.98, 0.86) + sky[:, None] * _rgb(0.30, 0.36, 0.46)

    def _object_shadow(self, p: torch.Tensor) -> torch.Tensor:
        """1 where the sun reaches point p, 0 where an object blocks it."""
        lit = torch.ones(p.shape[0])
        origin = p + 1e-3 * self.sun  # off the surface so a point does not shadow itself
        # Sun rays are parallel: a point's ray passes near an object's centre when their
        # projections onto the plane across the sun are close.
        across = _normalize(torch.linalg.cross(self.sun, torch.tensor([0.0, 0.0, 1.0])))
        basis = torch.stack([across, torch.linalg.cross(self.sun, across)], -1)  # (3, 2)
        flat, along = origin @ basis, origin @ self.sun
        for obj in self.objects:
            centre = torch.tensor(obj.centre)
            radius = obj.bounding_radius()
            offset = flat - centre @ basis
            near = ((offset * offset).sum(-1) < radius**2) & (along < centre @ self.sun + radius)
            near = near.nonzero()[:, 0]
            idx, _, _ = self._intersect_object(obj, origin[near], self.sun[None])
            lit[near[idx]] = 0.0
        return lit

    def _water(
        self, p: torch.Tensor, d: torch.Tensor, dist: torch.Tensor, time: int
    ) -> torch.Tensor:
        phase = 2 * math.pi * self._phase(time)
        arg = p[:, :2] @ self.wave_vectors.T - phase * self.wave_cycles + self.wave_phases
        slope = torch.cos(arg) * self.wave_slopes  # d(height)/d(arg), scaled per wave
        k_unit = self.wave_vectors / torch.linalg.norm(self.wave_vectors, dim=-1, keepdim=True)
        grad = slope @ k_unit  # (N, 2) surface gradient
        # Far water is seen at grazing angles: the ripples average out, flatten them.
        grad = grad * (1.0 - 0.7 * _smoothstep(20.0, 70.0, dist))[:, None]
        normal = _normalize(torch.cat([-grad, torch.ones_like(grad[:, :1])], -1))
        cos_i = (-(d * normal).sum(-1)).clamp(0.0, 1.0)
        reflected = d + 2.0 * cos_i[:, None] * normal
        reflected = _normalize(torch.cat([reflected[:, :2], reflected[:, 2:].clamp_min(0.02)], -1))
        fresnel = 0.02 + 0.98 * (1.0 - cos_i) ** 5
        sky = self._sky(reflected, time)
        deep = _rgb(0.02, 0.09, 0.11) + 0.05 * _rgb(0.30, 0.36, 0.46)
        return self._fog(_lerp(deep.expand_as(sky), sky, fresnel), d, dist)

    def _fog(self, colour: torch.Tensor, d: torch.Tensor, dist: torch.Tensor) -> torch.Tensor:
        """Aerial perspective: far surfaces fade towards the horizon sky."""
        haze = 1.0 - torch.exp(-dist / 1400.0)
        return _lerp(colour, _rgb(0.78, 0.84, 0.90).expand_as(colour), haze)


# --- scenes ----------------------------------------------------------------------------
@dataclass
class SynthView:
    """A ground-truth perspective view from a camera displaced from the origin."""

    camera: Camera
    time: int
    image: torch.Tensor  # (h, w, 3) float32 in [0, 1]
    depth: torch.Tensor  # (h, w) float32, distance along the camera's z
    displacement_fraction: float  # |camera position| / median scene depth

    def to_dict(self) -> dict[str, Any]:
        return {
            **self.camera.to_dict(),
            "time": self.time,
            "position": self.camera.position.tolist(),
            "displacement_fraction": self.displacement_fraction,
        }


class SynthFrames:
    """The L animation frames, rendered on access: the static part is the panorama's,
    only the moving pixels are shaded again. Indexing gives one (H, W, 3) float32 tensor;
    ``to_tensor()`` stacks all of them (L·H·W·3 floats: 1.4 GB at 4096×2048×14)."""

    def __init__(
        self, landscape: Landscape, panorama: torch.Tensor, moving: torch.Tensor,
        dirs: torch.Tensor, hits: Hits,
    ) -> None:  # fmt: skip
        self._landscape = landscape
        self._panorama = panorama
        self._moving = moving  # flat indices of the moving pixels
        self._shade_moving = landscape.moving_shader(torch.zeros(3), dirs, hits)

    def __len__(self) -> int:
        return self._landscape.frames

    @property
    def shape(self) -> tuple[int, int, int, int]:
        return (len(self), *self._panorama.shape)

    def __getitem__(self, time: int) -> torch.Tensor:
        if not -len(self) <= time < len(self):
            raise IndexError(f"frame {time} out of range for {len(self)} frames")
        time %= len(self)
        if time == 0:
            return self._panorama.clone()
        frame = self._panorama.clone()
        frame.view(-1, 3)[self._moving] = self._shade_moving(time)
        return frame

    def __iter__(self) -> Iterator[torch.Tensor]:
        return (self[t] for t in range(len(self)))

    def to_tensor(self) -> torch.Tensor:
        return torch.stack(list(self))


@dataclass
class SynthScene:
    """A synthetic panorama with its exact ground truth (see the module docstring)."""

    panorama: torch.Tensor  # (H, W, 3) float32 in [0, 1], frame 0
    depth: torch.Tensor  # (H, W) float32 ray length; the sky at SKY_DEPTH
    mask: torch.Tensor  # (H, W) bool, True where pixels move (sky and water)
    frames: SynthFrames  # L frames (H, W, 3), frame 0 equals the panorama
    views: list[SynthView]
    labels: torch.Tensor  # (H, W) uint8: LABEL_SKY, LABEL_TERRAIN, LABEL_WATER, LABEL_OBJECT + i
    landscape: Landscape = field(repr=False)

    @property
    def seed(self) -> int:
        return self.landscape.seed

    @property
    def objects(self) -> list[SceneObject]:
        return self.landscape.objects


def render_view(
    landscape: Landscape, camera: Camera, time: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Ray-cast a perspective camera: image (h, w, 3) and z-depth (h, w)."""
    dirs = camera.world_directions().reshape(-1, 3)
    origin = camera.position.to(torch.float32)
    hits = landscape.cast(origin, dirs)
    rgb = landscape.shade(origin, dirs, hits, time)
    z = hits.depth.view(camera.height, camera.width) / camera.z_to_ray_factor()
    return rgb.view(camera.height, camera.width, 3), z


def render_panorama(
    landscape: Landscape, width: int, height: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, Hits, torch.Tensor]:
    """Panorama at time 0 from the origin: image, depth, labels, hits and directions (flat)."""
    check_panorama_size(width, height)
    dirs = equirect_directions(width, height).view(-1, 3)
    hits = landscape.cast(torch.zeros(3), dirs)
    rgb = landscape.shade(torch.zeros(3), dirs, hits, 0)
    return (
        rgb.view(height, width, 3),
        hits.depth.view(height, width),
        hits.label.view(height, width),
        hits,
        dirs,
    )


def median_scene_depth(landscape: Landscape) -> float:
    """Median ray length of everything but the sky, measured on a small fixed panorama so the
    views of a seed do not depend on the panorama's resolution."""
    _, depth, labels, _, _ = render_panorama(landscape, *DEPTH_PROBE_SIZE)
    return float(depth[labels != LABEL_SKY].median())


def make_views(landscape: Landscape, count: int, size: int) -> list[SynthView]:
    """``count`` square views, displaced by VIEW_FRACTIONS (alternating) of the median scene
    depth in a random direction, random yaw, pitch within ±8°, random time index."""
    gen = torch.Generator().manual_seed(landscape.seed + 7919)  # independent of the scene's draws
    median = median_scene_depth(landscape)
    views = []
    for i in range(count):
        fraction = VIEW_FRACTIONS[i % len(VIEW_FRACTIONS)]
        azimuth, rise, yaw, pitch = torch.rand(4, generator=gen, dtype=torch.float64).tolist()
        azimuth, rise = 2 * math.pi * azimuth, math.radians(20.0 * rise - 10.0)
        yaw, pitch = 2 * math.pi * yaw, math.radians(16.0 * pitch - 8.0)
        offset = fraction * median
        position = (
            offset * math.cos(rise) * math.cos(azimuth),
            offset * math.cos(rise) * math.sin(azimuth),
            offset * math.sin(rise),
        )
        forward = (
            math.cos(pitch) * math.cos(yaw),
            math.cos(pitch) * math.sin(yaw),
            math.sin(pitch),
        )
        camera = Camera.from_fov(VIEW_FOV_DEG, size, size, position, forward)
        time = int(torch.randint(0, landscape.frames, (), generator=gen))
        image, depth = render_view(landscape, camera, time)
        views.append(SynthView(camera, time, image, depth, fraction))
    return views


def make_scene(
    seed: int,
    width: int,
    height: int,
    frames: int,
    *,
    views: int = 8,
    view_size: int = 256,
    camera_height: float = CAMERA_HEIGHT,
    progress: Callable[[str], None] | None = None,
) -> SynthScene:
    """Render the synthetic scene of ``seed``: panorama, depth, mask, frames and views.

    Deterministic: the same arguments give bit-identical tensors. The frames are rendered
    lazily (see ``SynthFrames``). ``progress`` is called with a message after each stage.
    """
    if views < 0 or view_size < 1:
        raise ValueError(f"need views >= 0 and view_size >= 1, got {views} and {view_size}")
    report = progress or (lambda _message: None)
    landscape = Landscape(seed, frames, camera_height)
    report("built the landscape")
    panorama, depth, labels, hits, dirs = render_panorama(landscape, width, height)
    report("rendered the panorama")
    mask = landscape.moves(labels)
    moving = mask.view(-1).nonzero()[:, 0]
    animation = SynthFrames(landscape, panorama, moving, dirs[moving], hits.subset(moving))
    view_list = make_views(landscape, views, view_size)
    report("rendered the views")
    return SynthScene(panorama, depth, mask, animation, view_list, labels, landscape)


# --- files -----------------------------------------------------------------------------
SCENE_YAML = """\
# Synthetic scene written by `pano4d synth` (seed {seed}). Train with: pano4d train scene.yaml
panorama: panorama.png
regions:
  - mask: mask.png          # white = moves (water and clouds)
    motion: {{direction_deg: 0.0, speed: {speed:.6g}}}  # cloud drift, degrees of arc per frame
animate:
  backend: flow
  frames: {frames}
depth:
  backend: layout           # or {{backend: file, path: depth.exr}} to train on the exact depth
  camera_height: {camera_height:g}
preset: draft
seed: {seed}
output: output
"""


def write_scene(
    out_dir: str | Path,
    scene: SynthScene,
    seed: int | None = None,
    progress: Callable[[str], None] | None = None,
) -> Path:
    """Write the DESIGN.md file set of ``scene`` into ``out_dir``; returns scene.yaml's path.

    ``seed`` (optional) must be the scene's own; it is what scene.yaml records. Frame and
    view PNGs of an earlier run in the same folder are replaced, not left behind.
    """
    from pano4d.images import write_image

    if seed is not None and seed != scene.seed:
        raise ValueError(f"scene was made with seed {scene.seed}, not {seed}")
    report = progress or (lambda _message: None)
    out = Path(out_dir)
    gt = out / "gt"
    for folder in (gt / "frames", gt / "views"):
        if folder.exists():
            shutil.rmtree(folder)
    write_image(out / "panorama.png", scene.panorama.numpy())
    write_image(out / "depth.exr", scene.depth.numpy()[..., None])
    write_image(out / "mask.png", scene.mask.numpy().astype(np.float32)[..., None])
    report("wrote the panorama, depth and mask")
    for t, frame in enumerate(scene.frames):
        write_image(gt / "frames" / f"{t:04d}.png", frame.numpy())
        report(f"wrote frame {t}")
    entries = []
    for i, view in enumerate(scene.views):
        name = f"views/{i:04d}.png"
        write_image(gt / name, view.image.numpy())
        entries.append({"image": name, **view.to_dict()})
    write_json_atomic(
        gt / "views.json",
        {
            "seed": scene.seed,
            "frames": len(scene.frames),
            "scene": scene.landscape.metadata(),
            "views": entries,
        },
    )
    report("wrote the views")
    yaml_path = out / "scene.yaml"
    write_text_atomic(
        yaml_path,
        SCENE_YAML.format(
            seed=scene.seed,
            speed=scene.landscape.cloud_speed_deg,
            frames=len(scene.frames),
            camera_height=scene.landscape.camera_height,
        ),
    )
    return yaml_path


def run_synth(out: Path, width: int, height: int, frames: int, seed: int, views: int = 8) -> Path:
    """``pano4d synth``: make the scene and write it with a progress bar; returns scene.yaml."""
    from rich.progress import Progress

    steps = 3 + 1 + frames + 1  # make_scene stages, panorama files, frames, views
    with Progress(transient=True) as bar:
        task = bar.add_task(f"synth {width}x{height}, {frames} frames", total=steps)

        def advance(message: str) -> None:
            bar.update(task, advance=1, description=message)

        scene = make_scene(seed, width, height, frames, views=views, progress=advance)
        return write_scene(out, scene, progress=advance)
