"""Procedural textures and colour arithmetic for the synthetic scenes.

Fractal noise made in the Fourier domain (periodic by construction), bilinear texture
lookups, and small helpers for colours (…, 3) and their blends.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F


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
