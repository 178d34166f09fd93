"""The outdoor scene kind: a meadow with a lake, hills, mountains, objects and clouds.

A procedural outdoor scene, deterministic from a seed: a flat meadow around the camera with
a lake, a ring of hills and snow-capped mountains (``terrain``), a few solid objects
(spheres, boxes, poles: ``objects``) standing on the ground, and a sky sphere with drifting
clouds (``shading``). All of it is analytic, so a ray from ANY camera position on the
meadow has an exact answer: what it hits, how far, which colour.

World frame (docs/design.md): +z up, the panorama's camera at the origin, the ground plane
at z = −camera_height. Motion: the water (waves travelling in one direction) and the clouds
(drifting towards +u, i.e. eastwards in the image) move, periodically with period L frames
so the animation loops; everything else is static and bit-identical in every frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import torch

from pano4d.synth.objects import OBJECT_COLOURS, OBJECT_KINDS, SceneObject
from pano4d.synth.shading import (
    CLOUD_REPEATS,
    Sky,
    Water,
    cloud_texture,
    fog,
    ground_albedo,
    lighting,
)
from pano4d.synth.terrain import FLAT_RADIUS, Terrain
from pano4d.synth.textures import TiledNoise, fft_noise, normalize, periodic, rgb
from pano4d.synth.world import (
    LABEL_SKY,
    SKY_DEPTH,
    Hits,
    MotionHint,
    shade_split,
    world_metadata,
)

CAMERA_HEIGHT = 2.0

# Labels of what a ray hit (after the sky's LABEL_SKY); object i gets LABEL_OBJECT + i.
LABEL_TERRAIN, LABEL_WATER, LABEL_OBJECT = 1, 2, 3

WATER_WAVES = 7


class Landscape:
    """The analytic scene of one seed: geometry, materials, lighting and motion.

    ``frames`` is the loop period L: every moving thing is a periodic function of the
    time index with period L.
    """

    moving_parts = "water and clouds"

    def __init__(self, seed: int, frames: int, camera_height: float = CAMERA_HEIGHT) -> None:
        if frames < 1:
            raise ValueError(f"frames must be >= 1, got {frames}")
        if not camera_height > 0:
            raise ValueError(f"camera_height must be positive, got {camera_height}")
        self.seed = int(seed)
        self.frames = int(frames)
        self.camera_height = float(camera_height)
        # Every draw comes from this one generator, in this order: a seed is a scene.
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
        self.terrain = Terrain(gen, self.camera_height)
        detail = torch.stack([fft_noise(gen, 512, 512, e, largest=128.0) for e in (1.2, 0.9)])
        self.detail = TiledNoise(periodic(detail))
        clouds = cloud_texture(gen)

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
        wave_vectors = torch.stack([k * torch.cos(angles), k * torch.sin(angles)], -1)
        wave_slopes = torch.empty(WATER_WAVES).uniform_(0.04, 0.10, generator=gen)
        wave_cycles = torch.randint(1, 3, (WATER_WAVES,), generator=gen).float()
        wave_phases = torch.empty(WATER_WAVES).uniform_(0, 2 * math.pi, generator=gen)
        self.sky = Sky(self.sun, clouds, self.detail, cover=rand(0.35, 0.6))
        self.water = Water(wave_vectors, wave_slopes, wave_cycles, wave_phases, self.sky)

        self.objects = self._place_objects(gen)

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
                on_shore = self.lake_level(torch.tensor([x]), torch.tensor([y]), footprint)
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

    def motion_hint(self) -> MotionHint:
        return MotionHint(0.0, self.cloud_speed_deg, "cloud drift")

    def metadata(self) -> dict[str, Any]:
        return world_metadata(
            self,
            lake={
                "centre": list(self.lake_centre),
                "axes": list(self.lake_axes),
                "angle_deg": math.degrees(self.lake_angle),
            },
            cloud_drift={"direction_deg": 0.0, "speed_deg_per_frame": self.cloud_speed_deg},
            wave_direction_deg=math.degrees(self.wave_direction),
            objects=[o.to_dict() for o in self.objects],
        )

    # --- surfaces ------------------------------------------------------------------------
    def lake_level(self, x: torch.Tensor, y: torch.Tensor, margin: float = 0.0) -> torch.Tensor:
        """< 1 inside the lake (shore noise included), > 1 outside; ``margin`` metres widen it.

        The shore noise moves the level by at most 0.1, so beyond 1.3 (well past the sand)
        it is left out: there the level is the plain elliptical distance."""
        cx, cy = self.lake_centre
        c, s = math.cos(self.lake_angle), math.sin(self.lake_angle)
        dx, dy = x - cx, y - cy
        a, b = self.lake_axes[0] + margin, self.lake_axes[1] + margin
        level = torch.sqrt(((c * dx + s * dy) / a) ** 2 + ((-s * dx + c * dy) / b) ** 2)
        near = (level < 1.3).nonzero()[:, 0]
        shore = self.detail.at(x[near], y[near], 150.0, 0).clamp(-2.0, 2.0)
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
        res[ground] = z[ground] - self.terrain.height(x[ground], y[ground])
        water = label == LABEL_WATER
        res[water] = z[water] + self.camera_height
        for i, obj in enumerate(self.objects):
            sel = label == LABEL_OBJECT + i
            res[sel] = obj.residual(points[sel])
        return res

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
        wet = self.lake_level(px[idx], py[idx]) < 1.0
        label[idx] = torch.where(wet, LABEL_WATER, LABEL_TERRAIN).to(torch.uint8)

        march = self.terrain.candidates(o, d) & ~on_meadow
        idx = march.nonzero()[:, 0]
        t_hit, hit = self.terrain.march(o, d[idx])
        idx = idx[hit]
        depth[idx] = t_hit[hit]
        label[idx] = LABEL_TERRAIN

        normal = torch.zeros(n, 3)
        for i, obj in enumerate(self.objects):
            near = obj.rays_near(o, d)
            idx, t_obj, n_obj = obj.intersect(o, d[near])
            idx = near[idx]
            closer = t_obj < depth[idx]
            idx = idx[closer]
            depth[idx], label[idx], normal[idx] = t_obj[closer], LABEL_OBJECT + i, n_obj[closer]

        normal[label == LABEL_SKY] = -d[label == LABEL_SKY]
        normal[label == LABEL_WATER] = torch.tensor([0.0, 0.0, 1.0])
        ground = (label == LABEL_TERRAIN).nonzero()[:, 0]
        gp = o + depth[ground, None] * d[ground]
        normal[ground] = self.terrain.normal(gp[:, 0], gp[:, 1])
        return Hits(depth, label, normal)

    # --- shading -------------------------------------------------------------------------
    def moves(self, label: torch.Tensor) -> torch.Tensor:
        """Which labels change over time: the sky (clouds) and the water."""
        return (label == LABEL_SKY) | (label == LABEL_WATER)

    def shade(self, o: torch.Tensor, d: torch.Tensor, hits: Hits, time: float) -> torch.Tensor:
        """Colour (N, 3) in [0, 1] of every ray at time ``time`` (frames, real-valued)."""
        return shade_split(self, self.shade_static, o, d, hits, time)

    def shade_static(self, o: torch.Tensor, d: torch.Tensor, hits: Hits) -> torch.Tensor:
        """Colour of rays that hit terrain or objects (no time dependence)."""
        p = o + hits.depth[:, None] * d
        albedo = torch.empty_like(p)
        ground = hits.label == LABEL_TERRAIN
        albedo[ground] = ground_albedo(
            p[ground], hits.normal[ground], hits.depth[ground], self.detail, self.lake_level,
            self.camera_height,
        )  # fmt: skip
        for i, obj in enumerate(self.objects):
            sel = hits.label == LABEL_OBJECT + i
            colour = rgb(*obj.colour).expand(int(sel.sum()), 3)
            if obj.kind == "pole":  # painted bands every half metre
                band = torch.floor((p[sel, 2] - obj.centre[2]) / 0.5).remainder(2)
                colour = torch.where(band[:, None] > 0, colour, colour * 0.25 + 0.7)
            albedo[sel] = colour
        lit = lighting(hits.normal, self.object_shadow(p), self.sun)
        return fog(albedo * lit, hits.depth).clamp(0.0, 1.0)

    def moving_shader(
        self, o: torch.Tensor, d: torch.Tensor, hits: Hits
    ) -> Callable[[float], torch.Tensor]:
        """time -> colour (N, 3) of rays that hit the sky or the water; what does not depend on
        time is computed once, here."""
        sky = (hits.label == LABEL_SKY).nonzero()[:, 0]
        water = (hits.label != LABEL_SKY).nonzero()[:, 0]
        # The sky is drawn by direction from the origin, so every camera sees the same dome.
        sky_rays = self.sky.rays((o + hits.depth[sky, None] * d[sky]) / SKY_DEPTH)
        water_points = o + hits.depth[water, None] * d[water]
        water_dirs, water_dist = d[water], hits.depth[water]

        def at(time: float) -> torch.Tensor:
            phase = self._phase(time)
            colour = torch.empty_like(d)
            colour[sky] = self.sky.colour(sky_rays, phase)
            colour[water] = self.water.colour(water_points, water_dirs, water_dist, phase)
            return colour.clamp(0.0, 1.0)

        return at

    def _phase(self, time: float) -> float:
        """Position in the loop, in [0, 1): exact periodicity, frame L is frame 0."""
        return (time % self.frames) / self.frames

    def object_shadow(self, p: torch.Tensor) -> torch.Tensor:
        """1 where the sun reaches point p, 0 where an object blocks it."""
        lit = torch.ones(p.shape[0])
        origin = p + 1e-3 * self.sun  # off the surface so a point does not shadow itself
        # Sun rays are parallel: a point's ray passes near an object's centre when their
        # projections onto the plane across the sun are close.
        across = normalize(torch.linalg.cross(self.sun, torch.tensor([0.0, 0.0, 1.0])))
        basis = torch.stack([across, torch.linalg.cross(self.sun, across)], -1)  # (3, 2)
        flat, along = origin @ basis, origin @ self.sun
        for obj in self.objects:
            centre = torch.tensor(obj.centre)
            radius = obj.bounding_radius()
            offset = flat - centre @ basis
            near = ((offset * offset).sum(-1) < radius**2) & (along < centre @ self.sun + radius)
            near = near.nonzero()[:, 0]
            idx, _, _ = obj.intersect(origin[near], self.sun[None])
            lit[near[idx]] = 0.0
        return lit
