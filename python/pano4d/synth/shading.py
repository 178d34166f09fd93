"""How the landscape looks: sky and clouds, water, ground materials, sunlight, haze.

Everything here is a function of a ray's direction, hit point and distance (and, for what
moves, of the position in the loop), so any camera sees the same world.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from pano4d.smoothstep import smoothstep
from pano4d.synth.textures import (
    TiledNoise,
    fft_noise,
    lerp,
    normalize,
    periodic,
    rgb,
    sample,
    wrap,
)

# The cloud field repeats CLOUD_REPEATS times around the sky; over L frames it drifts by one
# repeat, so the drift loops.
CLOUD_REPEATS = 6
CLOUD_TEXELS = 384  # texels per repeat along the azimuth
CLOUD_LOG_RHO = (-3.0, 5.5)  # log of the cloud-plane radius (cot of elevation) covered


def cloud_texture(gen: torch.Generator) -> torch.Tensor:
    """The periodic cloud texture a ``Sky`` drifts: (1, R + 1, CLOUD_TEXELS + 1), square
    texels over the log-polar cloud deck."""
    rows = round(
        (CLOUD_LOG_RHO[1] - CLOUD_LOG_RHO[0]) / (2 * math.pi / CLOUD_REPEATS) * CLOUD_TEXELS
    )
    return periodic(fft_noise(gen, rows, CLOUD_TEXELS, 1.75, largest=CLOUD_TEXELS / 2)[None])


@dataclass
class SkyRays:
    """Per sky ray: colour without clouds and the cloud lookup's time-independent inputs."""

    base: torch.Tensor  # (N, 3)
    cloud_x: torch.Tensor  # (N,) azimuth in cloud repeats
    cloud_y: torch.Tensor  # (N,) texture row in [-1, 1]
    threshold: torch.Tensor  # (N,) noise level where the cloud starts
    fade: torch.Tensor  # (N,)
    sunward: torch.Tensor  # (N,)


class Sky:
    """The sky dome around the origin: a gradient with the sun, and clouds on a deck that
    drift towards +u by one repeat per loop.

    ``clouds`` is the periodic cloud texture (1, R + 1, CLOUD_TEXELS + 1); ``cover_noise``
    modulates the cloud ``cover`` (0 … 1) so the repeats do not show.
    """

    def __init__(
        self, sun: torch.Tensor, clouds: torch.Tensor, cover_noise: TiledNoise, cover: float
    ) -> None:
        self.sun, self.clouds, self.cover_noise, self.cover = sun, clouds, cover_noise, cover

    def gradient(self, d: torch.Tensor) -> torch.Tensor:
        """The clear sky along unit directions d: blue over the horizon's haze, the sun."""
        elevation = torch.asin(d[:, 2].clamp(-1.0, 1.0))
        up = (elevation.clamp_min(0) / (math.pi / 2)) ** 0.45
        colour = lerp(rgb(0.80, 0.86, 0.92), rgb(0.20, 0.40, 0.78), up)
        cos_sun = (d @ self.sun).clamp_min(0)
        glow = 0.35 * cos_sun**8 + 0.5 * cos_sun**300
        disk = (cos_sun > math.cos(math.radians(0.6))).float() * 2.0
        return colour + (glow + disk)[:, None] * rgb(1.0, 0.93, 0.80)

    def rays(self, d: torch.Tensor) -> SkyRays:
        """The time-independent part of the sky along unit directions d.

        Clouds live in log-polar coordinates on a cloud deck, so they keep their shape and
        shrink towards the horizon; the field repeats CLOUD_REPEATS times in azimuth."""
        azimuth = torch.atan2(-d[:, 1], d[:, 0])  # grows with u, like the equirect longitude
        horizontal = torch.hypot(d[:, 0], d[:, 1])
        rho = horizontal / d[:, 2].clamp_min(1e-4)
        log_rho = torch.log(rho.clamp_min(1e-6)).clamp(*CLOUD_LOG_RHO)
        cloud_y = (log_rho - CLOUD_LOG_RHO[0]) / (CLOUD_LOG_RHO[1] - CLOUD_LOG_RHO[0]) * 2 - 1
        # A static, non-repeating modulation of the cover hides the repeats.
        cover = self.cover + 0.25 * self.cover_noise.at(
            azimuth / (2 * math.pi), log_rho / 6, 1.0, 0
        )
        # Thin out near the zenith (the log-polar pole) and fade into the horizon haze.
        fade = smoothstep(0.0, 0.12, d[:, 2]) * (1.0 - smoothstep(0.8, 0.97, d[:, 2]))
        return SkyRays(
            base=self.gradient(d),
            cloud_x=azimuth * (CLOUD_REPEATS / (2 * math.pi)),
            cloud_y=cloud_y,
            threshold=1.2 - 2.0 * cover,
            fade=fade,
            sunward=(d @ self.sun).clamp_min(0),
        )

    def colour(self, rays: SkyRays, phase: float) -> torch.Tensor:
        """The sky with its clouds at ``phase`` (position in the loop, [0, 1))."""
        drift = phase  # one repeat per loop, towards +u
        noise = sample(self.clouds, wrap(rays.cloud_x - drift), rays.cloud_y)[:, 0]
        density = smoothstep(rays.threshold, rays.threshold + 1.1, noise) * rays.fade
        cloud = lerp(
            rgb(0.62, 0.65, 0.72), rgb(1.0, 0.99, 0.97), (1 - density) * 0.6 + 0.3 * rays.sunward
        )
        return lerp(rays.base, cloud, density * 0.95)


@dataclass(frozen=True)
class Water:
    """The lake's surface: a sum of travelling waves (wave vectors (K, 2) in rad/m, maximum
    slopes, whole cycles per loop and phases (K,)) that reflects ``sky``."""

    vectors: torch.Tensor
    slopes: torch.Tensor
    cycles: torch.Tensor
    phases: torch.Tensor
    sky: Sky

    def colour(
        self, p: torch.Tensor, d: torch.Tensor, dist: torch.Tensor, phase: float
    ) -> torch.Tensor:
        """Colour of the water at points p (N, 3) seen along d at distance dist, at ``phase``
        (position in the loop, [0, 1)): the sky reflected in the waves, by Fresnel."""
        angle = 2 * math.pi * phase
        arg = p[:, :2] @ self.vectors.T - angle * self.cycles + self.phases
        slope = torch.cos(arg) * self.slopes  # d(height)/d(arg), scaled per wave
        k_unit = self.vectors / torch.linalg.norm(self.vectors, dim=-1, keepdim=True)
        grad = slope @ k_unit  # (N, 2) surface gradient
        # Far water is seen at grazing angles: the ripples average out, flatten them.
        grad = grad * (1.0 - 0.7 * smoothstep(20.0, 70.0, dist))[:, None]
        normal = normalize(torch.cat([-grad, torch.ones_like(grad[:, :1])], -1))
        cos_i = (-(d * normal).sum(-1)).clamp(0.0, 1.0)
        reflected = d + 2.0 * cos_i[:, None] * normal
        reflected = normalize(torch.cat([reflected[:, :2], reflected[:, 2:].clamp_min(0.02)], -1))
        fresnel = 0.02 + 0.98 * (1.0 - cos_i) ** 5
        sky = self.sky.colour(self.sky.rays(reflected), phase)
        deep = rgb(0.02, 0.09, 0.11) + 0.05 * rgb(0.30, 0.36, 0.46)
        return fog(lerp(deep.expand_as(sky), sky, fresnel), dist)


def ground_albedo(
    p: torch.Tensor,
    normal: torch.Tensor,
    dist: torch.Tensor,
    detail: TiledNoise,
    lake_level: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    camera_height: float,
) -> torch.Tensor:
    """Ground colour at points p (N, 3): grass, rock on slopes and heights, sand on the
    lake's shore (``lake_level`` < 1.08), snow on the high flat parts."""
    x, y = p[:, 0], p[:, 1]
    height = p[:, 2] + camera_height
    slope = 1.0 - normal[:, 2]
    coarse = detail.at(x, y, 90.0, 0)
    fine = detail.at(x, y, 7.0, 1) * (1.0 - smoothstep(30.0, 120.0, dist))
    grass = lerp(rgb(0.17, 0.32, 0.08), rgb(0.42, 0.46, 0.17), smoothstep(-1.2, 1.5, coarse))
    grass = grass * (1.0 + 0.18 * fine)[:, None]
    rock = rgb(0.44, 0.41, 0.35) * (1.0 + 0.12 * coarse + 0.1 * fine)[:, None]
    sand = rgb(0.72, 0.66, 0.48) * (1.0 + 0.08 * fine)[:, None]
    snow = rgb(0.94, 0.95, 0.98).expand_as(p)
    colour = lerp(
        grass,
        rock,
        (smoothstep(0.12, 0.3, slope + 0.04 * coarse) + smoothstep(50.0, 90.0, height)).clamp(
            max=1.0
        ),
    )
    shore = 1.0 - smoothstep(1.0, 1.08, lake_level(x, y))
    colour = lerp(colour, sand, shore)
    snowy = smoothstep(105.0, 125.0, height + 8.0 * coarse) * (1.0 - smoothstep(0.35, 0.55, slope))
    return lerp(colour, snow, snowy)


def lighting(
    normal: torch.Tensor, shadow: torch.Tensor, sun_direction: torch.Tensor
) -> torch.Tensor:
    """Light (N, 3) reaching surfaces with unit normals (N, 3): the sun where ``shadow`` is 1,
    plus the sky's blue light from above."""
    sun = (normal @ sun_direction).clamp_min(0) * shadow
    sky = 0.55 + 0.45 * normal[:, 2]
    return sun[:, None] * rgb(1.05, 0.98, 0.86) + sky[:, None] * rgb(0.30, 0.36, 0.46)


def fog(colour: torch.Tensor, dist: torch.Tensor) -> torch.Tensor:
    """Aerial perspective: far surfaces fade towards the horizon sky."""
    haze = 1.0 - torch.exp(-dist / 1400.0)
    return lerp(colour, rgb(0.78, 0.84, 0.90).expand_as(colour), haze)
