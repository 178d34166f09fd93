"""``smoothstep``: the one smooth ramp, for the animation's blend border, the flow
animator's decorrelation and the synthetic scenes' materials."""

from __future__ import annotations

import torch


def smoothstep(
    lo: float | torch.Tensor, hi: float | torch.Tensor, x: torch.Tensor
) -> torch.Tensor:
    """0 below ``lo``, 1 above ``hi``, and 3s² − 2s³ of s = (x − lo) / (hi − lo) between:
    a ramp with zero slope at both ends."""
    s = ((x - lo) / (hi - lo)).clamp(0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)
