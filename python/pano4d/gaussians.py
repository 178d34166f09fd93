"""A set of 3D Gaussians in the 3DGS parameterisation (see docs/design.md, "Conventions")."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import torch

SH_C0 = 0.28209479177387814


def sh_coeffs_for_degree(degree: int) -> int:
    if not 0 <= degree <= 3:
        raise ValueError(f"SH degree must be 0..3, got {degree}")
    return (degree + 1) ** 2


def sh_degree_for_coeffs(k: int) -> int:
    degree = math.isqrt(k) - 1
    if (degree + 1) ** 2 != k or not 0 <= degree <= 3:
        raise ValueError(f"{k} SH coefficients per channel is not (degree + 1)^2 for degree 0..3")
    return degree


def rgb_to_sh_dc(rgb: torch.Tensor) -> torch.Tensor:
    """Colour in [0, 1] to the DC coefficient that renders it (3DGS: rgb = 0.5 + C0 * dc)."""
    return (rgb - 0.5) / SH_C0


@dataclass
class Gaussians:
    """N Gaussians. All fields are torch tensors on one device.

    means (N, 3); log_scales (N, 3); quats (N, 4) as (w, x, y, z), normalised on use;
    opacity_logits (N,); sh (N, K, 3) with K = (degree + 1)^2, coefficient-major.
    """

    means: torch.Tensor
    log_scales: torch.Tensor
    quats: torch.Tensor
    opacity_logits: torch.Tensor
    sh: torch.Tensor

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        expected = {
            "means": (n, 3),
            "log_scales": (n, 3),
            "quats": (n, 4),
            "opacity_logits": (n,),
        }
        for name, shape in expected.items():
            got = tuple(getattr(self, name).shape)
            if got != shape:
                raise ValueError(f"Gaussians.{name} must have shape {shape}, got {got}")
        if self.sh.ndim != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3:
            raise ValueError(
                f"Gaussians.sh must have shape ({n}, K, 3), got {tuple(self.sh.shape)}"
            )
        sh_degree_for_coeffs(self.sh.shape[1])

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return sh_degree_for_coeffs(self.sh.shape[1])

    @property
    def device(self) -> torch.device:
        return self.means.device

    def tensors(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def map(self, fn) -> Gaussians:  # type: ignore[no-untyped-def]
        """Apply ``fn`` to every tensor (``g.map(lambda t: t.cuda())``)."""
        return Gaussians(**{k: fn(v) for k, v in self.tensors().items()})

    def to(self, *args, **kwargs) -> Gaussians:  # type: ignore[no-untyped-def]
        return self.map(lambda t: t.to(*args, **kwargs))

    def detach(self) -> Gaussians:
        return self.map(torch.Tensor.detach)

    def __getitem__(self, index: torch.Tensor | slice) -> Gaussians:
        return self.map(lambda t: t[index])

    @staticmethod
    def cat(sets: list[Gaussians]) -> Gaussians:
        if not sets:
            raise ValueError("Gaussians.cat needs at least one set")
        degree = max(g.sh_degree for g in sets)
        sets = [g.with_sh_degree(degree) for g in sets]
        return Gaussians(
            **{k: torch.cat([g.tensors()[k] for g in sets]) for k in sets[0].tensors()}
        )

    def with_sh_degree(self, degree: int) -> Gaussians:
        """Pad with zeros or truncate the SH coefficients to ``degree``."""
        k = sh_coeffs_for_degree(degree)
        sh = self.sh[:, :k]
        if sh.shape[1] < k:
            pad = sh.new_zeros(len(self), k - sh.shape[1], 3)
            sh = torch.cat([sh, pad], dim=1)
        return Gaussians(self.means, self.log_scales, self.quats, self.opacity_logits, sh)

    @staticmethod
    def empty(sh_degree: int = 0, device: torch.device | str = "cpu") -> Gaussians:
        k = sh_coeffs_for_degree(sh_degree)
        z = torch.zeros
        return Gaussians(
            z(0, 3, device=device),
            z(0, 3, device=device),
            z(0, 4, device=device),
            z(0, device=device),
            z(0, k, 3, device=device),
        )

    # --- numpy interchange (float32, C-contiguous): checkpoints, pano4d.extension ---------
    def to_numpy(self) -> dict[str, np.ndarray]:
        return {
            k: np.ascontiguousarray(v.detach().cpu().to(torch.float32).numpy())
            for k, v in self.tensors().items()
        }

    @staticmethod
    def from_numpy(arrays: dict[str, np.ndarray], device: torch.device | str = "cpu") -> Gaussians:
        return Gaussians(
            **{
                k: torch.from_numpy(np.asarray(arrays[k], dtype=np.float32)).to(device)
                for k in ("means", "log_scales", "quats", "opacity_logits", "sh")
            }
        )
