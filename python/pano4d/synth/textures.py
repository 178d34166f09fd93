"""Procedural textures and colour arithmetic for the synthetic scenes.

Fractal noise made in the Fourier domain (periodic by construction), bilinear texture
lookups, and small helpers for colours (…, 3) and their blends.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from pano4d.smoothstep import smoothstep


def rgb(*values: float) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.float32)


def lerp(a: torch.Tensor, b: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """a + (b − a)·w with colours (…, 3) and a weight (…,)."""
    return torch.lerp(a, b, w[..., None])


def normalize(v: torch.Tensor) -> torch.Tensor:
    return v / torch.linalg.norm(v, dim=-1, keepdim=True).clamp_min(1e-12)


def fft_noise(
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


def sample(texture: torch.Tensor, gx: torch.Tensor, gy: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup of a (C, R, C') texture at normalised coordinates in [-1, 1] → (N, C)."""
    grid = torch.stack([gx, gy], dim=-1).view(1, 1, -1, 2)
    out = F.grid_sample(
        texture[None], grid, mode="bilinear", padding_mode="border", align_corners=True
    )
    return out[0, :, 0].T


def periodic(texture: torch.Tensor) -> torch.Tensor:
    """(C, R, C') texture with its first row and column repeated at the end, for wrap-around."""
    return F.pad(texture[None], (0, 1, 0, 1), mode="circular")[0]


def wrap(x: torch.Tensor) -> torch.Tensor:
    """Fractional part mapped to the [-1, 1] coordinates of a ``periodic`` texture."""
    return torch.remainder(x, 1.0) * 2.0 - 1.0


@dataclass(frozen=True)
class TiledNoise:
    """Channels of periodic noise tiled over the plane: ``at(x, y, period, channel)`` looks
    up one channel with one tile every ``period`` units of x and y."""

    texture: torch.Tensor  # (C, R + 1, C' + 1), from ``periodic``

    def at(self, x: torch.Tensor, y: torch.Tensor, period: float, channel: int) -> torch.Tensor:
        tex = self.texture[channel : channel + 1]
        return sample(tex, wrap(x / period), wrap(y / period))[:, 0]


def pulse_coverage(
    x: torch.Tensor, period: float, width: float, footprint: torch.Tensor
) -> torch.Tensor:
    """A pulse train (1 on [kP, kP + width), 0 elsewhere, P = ``period``) box-filtered over
    ``footprint`` (N,) around each position x (N,): the fraction of the footprint the pulses
    cover. Exact for a box filter, so thin lines fade to their mean grey instead of aliasing."""
    f = footprint.clamp_min(1e-5)

    def integral(t: torch.Tensor) -> torch.Tensor:  # ∫_0^t pulses
        cells = torch.floor(t / period)
        return cells * width + (t - cells * period).clamp(0.0, width)

    return ((integral(x + f / 2) - integral(x - f / 2)) / f).clamp(0.0, 1.0)


def detail_fade(footprint: torch.Tensor, wavelength: float) -> torch.Tensor:
    """1 where a pattern of ``wavelength`` spans at least 4 footprints, 0 at 2 or fewer: how
    much of it to keep before it would alias."""
    return 1.0 - smoothstep(0.25, 0.5, footprint / wavelength)


def cell_blend(
    x: torch.Tensor, period: float, footprint: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Cells of ``period`` along x, box-filtered over ``footprint``: the cells at both ends of
    the footprint (lower, upper) and the upper one's share. A per-cell value v then filters
    to lerp(v[lower], v[upper], share): no hard edge finer than a pixel between cells."""
    f = footprint.clamp_min(1e-5)
    lower = torch.floor((x - f / 2) / period)
    upper = torch.floor((x + f / 2) / period)
    share = ((x + f / 2 - upper * period) / f).clamp(0.0, 1.0)
    return lower, upper, share
