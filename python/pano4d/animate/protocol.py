"""What the Panoramic Denoiser needs from a perspective image-to-video model Φ.

A backend turns per-view condition images into an opaque condition, predicts the clean
latent video x̂₀ from a noisy one at a noise level σ, and maps images ↔ latents. It never
advances the sampler itself: the sampler arithmetic (an EDM / Euler-discrete step) lives
in one place, ``pano4d.animate.denoiser.euler_step``, and works on the sphere.

Shapes: condition images (B, 3, h, w) float in [0, 1]; latent videos (B, L, c, h/s, w/s)
with s = ``scale_factor``; latents live in the sampler's space (the VAE's scaled latent).
"""

from __future__ import annotations

from typing import Protocol

import torch


class ViewCondition(Protocol):
    """Per-view conditioning (embeddings, image latents, masks), sliceable along views."""

    def select(self, views: slice) -> ViewCondition: ...


class ImageToVideoDenoiser(Protocol):
    latent_channels: int
    scale_factor: int  # image pixels per latent pixel
    size_multiple: int  # view images must have sides divisible by this
    device: torch.device
    dtype: torch.dtype  # what the networks compute in

    def schedule(self, steps: int) -> tuple[torch.Tensor, float]:
        """Noise levels σ (steps + 1,), float64, decreasing to 0, and the initial noise scale."""
        ...

    def encode_condition(
        self, images: torch.Tensor, frames: int, masks: torch.Tensor | None, seed: int
    ) -> ViewCondition:
        """Condition for each view image; ``masks`` (B, h/s, w/s) bool marks what may move."""
        ...

    def predict_x0(
        self, latents: torch.Tensor, sigma: float, condition: ViewCondition
    ) -> torch.Tensor:
        """Denoised prediction x̂₀ (B, L, c, h, w) float32 for noisy latents at level σ."""
        ...

    def encode(self, images: torch.Tensor) -> torch.Tensor:
        """Images (B, 3, h, w) in [0, 1] → sampler-space latents (B, c, h/s, w/s) float32."""
        ...

    def decode(self, latents: torch.Tensor) -> torch.Tensor:
        """Latent videos (B, L, c, h, w) → videos (B, L, 3, h·s, w·s) float32 in [0, 1]."""
        ...
