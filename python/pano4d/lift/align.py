"""Spatial-Temporal Geometry Alignment (4K4DGen, Eq. 4).

Per frame k: one spherical depth D_k on icosphere points, parameterised as log ray length so
that 0.1 … 10⁴ trains stably; per view i a scale softplus(α_i) and a per-pixel shift β_i
that map the monocular view depth Θ_i onto it:

    L = λ_depth L_depth + λ_scale L_scale + λ_shift L_shift
    L_depth = Σ_i mean_pixels |D_k seen by view i − (softplus(α_i) Θ_i + β_i)| / D_k
    L_scale = |α_k − α_{k−1}| + |softplus(α_k) − 1|
    L_shift = TV(β_k) + |β_k − β_{k−1}|

L_depth sums over views (Eq. 4's Σ_i) while the regularisers average over them: the scale
prior then anchors the overall scale without dragging each view's scale towards 1.

A per-pixel shift with nothing to hold it can explain any depth, so for the first half of the
iterations α and β stay at the identity (scale 1, shift 0) and only D_k moves: it settles on
the consensus of the views. The second half frees α and β together with their regularisers.
β is stored in units of the view's near depth (its 10th percentile), so one learning rate
and one λ_shift fit every scene scale.

What holds β is the TV term, so λ_shift must make it matter: a view whose Θ is off by a
scale s and a shift b is explained either by (s, constant β = b), which costs the scale
prior λ_scale·|s − 1| and no TV, or by (1, β bent to follow the scale error), which costs
TV. With TV a mean over pixels, λ_shift = 0.01 made bending ~100× cheaper: β absorbed the
scale errors, planted shifts never came back and a step in β was not smoothed
(tests/test_align.py). At λ_shift = 10 a constant shift wins, and TV removes structure in
β narrower than a few pixels while keeping wide steps (TV-L1 is edge-preserving).

Frame k > 0 starts from frame k − 1's solution, and D_k changes only at points in the
(dilated) moving region: the static geometry stays bit-identical across frames, which is what
lets the static Gaussians be shared by every timestamp.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from pano4d.camera import Camera
from pano4d.resample import sphere_sampler, sphere_to_equirect
from pano4d.sphere import Icosphere, icosphere, icosphere_frequency_for_spacing

LAMBDA_DEPTH, LAMBDA_SCALE, LAMBDA_SHIFT = 1.0, 0.1, 10.0
IDENTITY_ALPHA = math.log(math.e - 1.0)  # softplus(IDENTITY_ALPHA) = 1
LOG_DEPTH_RANGE = (math.log(1e-2), math.log(1e5))  # clamp on the parameter, far beyond use


@dataclass
class FrameAlignment:
    """One frame: sphere log ray length (N,), raw scales α (n,), relative shifts β (n, h, w)."""

    log_depth: torch.Tensor
    alpha: torch.Tensor
    beta: torch.Tensor
    loss: float

    def scales(self) -> torch.Tensor:
        return F.softplus(self.alpha)

    def detach(self) -> FrameAlignment:
        return FrameAlignment(
            self.log_depth.detach().clone(),
            self.alpha.detach().clone(),
            self.beta.detach().clone(),
            self.loss,
        )

    def to_dict(self) -> dict[str, torch.Tensor | float]:
        return {
            "log_depth": self.log_depth.cpu(),
            "alpha": self.alpha.cpu(),
            "beta": self.beta.cpu(),
            "loss": self.loss,
        }

    @staticmethod
    def from_dict(d: dict, device: torch.device | str = "cpu") -> FrameAlignment:
        return FrameAlignment(
            d["log_depth"].to(device), d["alpha"].to(device), d["beta"].to(device), float(d["loss"])
        )


def sphere_for_views(cameras: list[Camera]) -> Icosphere:
    """An icosphere with about one point per view pixel."""
    cam = cameras[0]
    pixel_angle = math.radians(cam.fov_deg()[0]) / cam.width
    return icosphere(icosphere_frequency_for_spacing(pixel_angle))


def total_variation(x: torch.Tensor) -> torch.Tensor:
    """Mean absolute neighbour difference over the last two axes."""
    return (x[..., 1:, :] - x[..., :-1, :]).abs().mean() + (
        x[..., :, 1:] - x[..., :, :-1]
    ).abs().mean()


class DepthAligner:
    """Fits spherical depth frame by frame from per-view ray-length depth (n, h, w)."""

    def __init__(
        self,
        cameras: list[Camera],
        ico: Icosphere | None = None,
        iterations: int = 3000,
        warm_iterations: int | None = None,
        lr: float = 0.02,
        device: torch.device | str = "cpu",
    ) -> None:
        if iterations < 2:
            raise ValueError(f"alignment needs at least 2 iterations, got {iterations}")
        self.cameras = cameras
        self.ico = ico if ico is not None else sphere_for_views(cameras)
        self.iterations = iterations
        self.warm_iterations = warm_iterations if warm_iterations is not None else iterations // 2
        self.lr = lr
        self.device = torch.device(device)
        self.samplers = [
            sphere_sampler(cam.world_directions(torch.float64), self.ico).to(self.device)
            for cam in cameras
        ]
        self.index = torch.stack([s.index for s in self.samplers])  # (n, h, w, 3)
        self.weight = torch.stack([s.weight for s in self.samplers])
        self.shape = (len(cameras), cameras[0].height, cameras[0].width)

    def sphere_to_views(self, values: torch.Tensor) -> torch.Tensor:
        """Sphere signal (N,) as seen by every view: (n, h, w)."""
        flat = self.index.reshape(len(self.cameras), -1, 3)
        w = self.weight.reshape(len(self.cameras), -1, 3)
        return (values[flat] * w).sum(-1).reshape(self.shape)

    def views_to_sphere(self, values: torch.Tensor) -> torch.Tensor:
        """Average of per-view values (n, h, w) over the views that see each sphere point."""
        total = torch.zeros(len(self.ico), device=values.device)
        count = torch.zeros(len(self.ico), device=values.device)
        for i, s in enumerate(self.samplers):
            total += s.adjoint(values[i])
            count += s.coverage_weight()
        seen = count > 1e-6
        fill = values.mean()
        return torch.where(seen, total / count.clamp(min=1e-6), fill)

    def equirect_depth(self, alignment: FrameAlignment, width: int, height: int) -> torch.Tensor:
        """The frame's aligned ray-length depth on a width×height equirect grid."""
        log_eq = sphere_to_equirect(alignment.log_depth, self.ico, width, height)
        return log_eq.exp()

    def fit(
        self,
        view_depth: torch.Tensor,
        previous: FrameAlignment | None = None,
        moving: torch.Tensor | None = None,
        on_iteration: Callable[[int, int, float], None] | None = None,
    ) -> FrameAlignment:
        """Align one frame. ``view_depth`` (n, h, w) ray length from Θ.

        ``previous``: frame k − 1's solution (warm start, temporal terms). ``moving`` (N,)
        bool: sphere points allowed to change; required with ``previous``.
        ``on_iteration(i, total, loss)`` is called after every step.
        """
        if tuple(view_depth.shape) != self.shape:
            raise ValueError(f"expected view depth {self.shape}, got {tuple(view_depth.shape)}")
        if not torch.isfinite(view_depth).all() or (view_depth <= 0).any():
            raise ValueError("view depth must be finite and positive")
        target = view_depth.to(self.device, torch.float32)
        n = self.shape[0]
        unit = self.shift_unit(target)
        if previous is None:
            log_depth = self.views_to_sphere(target.log())
            alpha = torch.full((n,), IDENTITY_ALPHA, device=self.device)
            beta = torch.zeros(self.shape, device=self.device)
            iterations, free_from = self.iterations, self.iterations // 2
        else:
            if moving is None:
                raise ValueError("a warm-started frame needs the moving-point mask")
            log_depth, alpha, beta = (
                previous.log_depth.to(self.device),
                previous.alpha.to(self.device),
                previous.beta.to(self.device),
            )
            iterations, free_from = self.warm_iterations, 0
        if iterations == 0 and previous is not None:
            return previous.detach()
        fixed_log_depth = log_depth.detach().clone()
        prev_alpha, prev_beta = alpha.detach().clone(), beta.detach().clone()
        free = moving.to(self.device) if moving is not None else None

        p_log_depth = log_depth.detach().clone().requires_grad_(True)
        p_alpha = alpha.detach().clone().requires_grad_(True)
        p_beta = beta.detach().clone().requires_grad_(True)
        optimiser = torch.optim.Adam([p_log_depth, p_alpha, p_beta], lr=self.lr)
        loss_value = math.nan
        for step in range(iterations):
            calibrate = step >= free_from
            log_d = p_log_depth.clamp(*LOG_DEPTH_RANGE)
            if free is not None:
                log_d = torch.where(free, log_d, fixed_log_depth)
            seen = self.sphere_to_views(log_d).exp()
            if calibrate:
                predicted = F.softplus(p_alpha)[:, None, None] * target + p_beta * unit
            else:
                predicted = target
            relative = (seen - predicted).abs() / seen.detach()
            loss = LAMBDA_DEPTH * relative.mean(dim=(1, 2)).sum()
            if calibrate:
                scale_term = (F.softplus(p_alpha) - 1.0).abs().mean()
                shift_term = total_variation(p_beta)
                if previous is not None:
                    scale_term = scale_term + (p_alpha - prev_alpha).abs().mean()
                    shift_term = shift_term + (p_beta - prev_beta).abs().mean()
                loss = loss + LAMBDA_SCALE * scale_term + LAMBDA_SHIFT * shift_term
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            if not calibrate:
                p_alpha.grad = None
                p_beta.grad = None
            optimiser.step()
            loss_value = float(loss.detach())
            if on_iteration is not None:
                on_iteration(step, iterations, loss_value)
        with torch.no_grad():
            final = p_log_depth.clamp(*LOG_DEPTH_RANGE)
            if free is not None:
                final = torch.where(free, final, fixed_log_depth)
        return FrameAlignment(final.detach(), p_alpha.detach(), p_beta.detach(), loss_value)

    def shift_unit(self, view_depth: torch.Tensor) -> torch.Tensor:
        """Per view (n, 1, 1): the depth unit β is stored in (the 10th-percentile depth)."""
        flat = view_depth.to(self.device, torch.float32).reshape(self.shape[0], -1)
        return torch.quantile(flat, 0.1, dim=1)[:, None, None]

    def shifts(self, alignment: FrameAlignment, view_depth: torch.Tensor) -> torch.Tensor:
        """β (n, h, w) in the depth's own units."""
        return alignment.beta * self.shift_unit(view_depth)
