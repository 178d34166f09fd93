"""What cameras see of a synthetic world: the panorama from the origin and the displaced
ground-truth views (the novel-view test set), all drawn by the world's ray caster."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from pano4d.camera import Camera
from pano4d.sphere import check_panorama_size, equirect_directions
from pano4d.synth.world import LABEL_SKY, Hits, World

VIEW_FOV_DEG = 75.0
VIEW_FRACTIONS = (0.01, 0.05)  # camera displacement / median scene depth, alternating
DEPTH_PROBE_SIZE = (512, 256)  # panorama size used to measure the median scene depth


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


def render_view(world: World, camera: Camera, time: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Ray-cast a perspective camera: image (h, w, 3) and z-depth (h, w)."""
    dirs = camera.world_directions().reshape(-1, 3)
    origin = camera.position.to(torch.float32)
    hits = world.cast(origin, dirs)
    rgb = world.shade(origin, dirs, hits, time)
    z = hits.depth.view(camera.height, camera.width) / camera.z_to_ray_factor()
    return rgb.view(camera.height, camera.width, 3), z


def render_panorama(
    world: World, width: int, height: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, Hits, torch.Tensor]:
    """Panorama at time 0 from the origin: image, depth, labels, hits and directions (flat)."""
    check_panorama_size(width, height)
    dirs = equirect_directions(width, height).view(-1, 3)
    hits = world.cast(torch.zeros(3), dirs)
    rgb = world.shade(torch.zeros(3), dirs, hits, 0)
    return (
        rgb.view(height, width, 3),
        hits.depth.view(height, width),
        hits.label.view(height, width),
        hits,
        dirs,
    )


def median_scene_depth(world: World) -> float:
    """Median ray length of everything but the sky, cast (not shaded) on a small fixed
    panorama so the views of a seed do not depend on the panorama's resolution."""
    width, height = DEPTH_PROBE_SIZE
    hits = world.cast(torch.zeros(3), equirect_directions(width, height).view(-1, 3))
    return float(hits.depth[hits.label != LABEL_SKY].median())


def make_views(world: World, count: int, size: int) -> list[SynthView]:
    """``count`` square views, displaced by VIEW_FRACTIONS (alternating) of the median scene
    depth in a random direction, random yaw, pitch within ±8°, random time index."""
    gen = torch.Generator().manual_seed(world.seed + 7919)  # independent of the scene's draws
    median = median_scene_depth(world)
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
        time = int(torch.randint(0, world.frames, (), generator=gen))
        image, depth = render_view(world, camera, time)
        views.append(SynthView(camera, time, image, depth, fraction))
    return views
