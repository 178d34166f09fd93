"""The reference losses of the lifting optimisation (4K4DGen), in torch.

    L = L_rgb + λ_temporal L_temporal + λ_sem L_sem + λ_geo L_geo
    L_rgb      = (1 − λ_dssim) L1 + λ_dssim (1 − SSIM)        (kornia SSIM, 11×11 window)
    L_temporal = L1 between the render of G_t and that of G_{t−1} in the same view
    L_geo      = 1 − Pearson(rendered depth, Θ's depth)
    L_sem      = 1 − cos(CLS(render at the view), CLS(render at the view moved by δ)),
                 δ ∈ [−α, α]³ × median scene depth, α = 0.05 / 0.1 / 0.2 from 54 / 66 / 90 %
                 of the iterations; only with a feature backend (DINOv2).

This module owns the terms' definitions (SSIM, Pearson, the L_sem schedule and its moved
camera) and the order of the loss sums outside a window (``OUTSIDE_SUMS``). The torch
trainer (``lift.torch_trainer``) sums them into L; the device's loss passes
(crates/splat-core/src/train/losses.rs and losses.wgsl) compute the same terms and are
checked against these step for step (tests/test_resident_train.py). The λ are knobs
(``lift.trainer.Knobs``); the SSIM window and the L_sem schedule are constants here: the
papers' choices, not something a scene needs changed.
"""

from __future__ import annotations

import torch

from pano4d.camera import Camera

# kornia's SSIM window (σ = 1.5). The device has its own copy, which must match:
# SSIM_WINDOW in crates/splat-core/src/train/losses.rs.
SSIM_WINDOW = 11
SEM_SCHEDULE = ((0.54, 0.05), (0.66, 0.1), (0.90, 0.2))  # (fraction of iterations, α)

# The loss sums over the pixels of a view outside the window a step renders (``TrainViews.
# outside``; lift.windows computes them): Σ w·mean|x − t|, Σ w·SSIM, Σ w·mean|x − prev|,
# L_geo's covered weight Σ c, the means of the rendered and of Θ's depth over it, and the
# sums Σ c·da², Σ c·db², Σ c·da·db about those means. The device's LossParams has them in
# this order (crates/splat-core/src/train/losses.rs, OUTSIDE_SUMS).
OUTSIDE_SUMS = (
    "l1", "ssim", "temporal", "covered", "mean_depth", "mean_target_depth",
    "var_depth", "var_target_depth", "cov_depth",
)  # fmt: skip


def ssim_map(rendered: torch.Tensor, target: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """The (h, w) SSIM map of (h, w, 3) images, averaged over the channels; pixels of weight
    0 take no part (``ssim_loss``)."""
    import kornia

    unsupervised = (weight <= 0)[..., None]
    fixed = rendered.detach()
    rendered = torch.where(unsupervised, fixed, rendered)
    target = torch.where(unsupervised, fixed, target)
    window = min(SSIM_WINDOW, (min(rendered.shape[:2]) // 2) * 2 - 1)
    return kornia.metrics.ssim(
        rendered.permute(2, 0, 1)[None], target.permute(2, 0, 1)[None], window
    )[0].mean(0)


def ssim_loss(
    rendered: torch.Tensor,
    target: torch.Tensor,
    weight: torch.Tensor,
    weight_sum: torch.Tensor | None = None,
    outside: torch.Tensor | float = 0.0,
) -> torch.Tensor:
    """1 − weighted mean SSIM of (h, w, 3) images (over a whole view of ``weight_sum`` and
    Σ w·SSIM ``outside`` these pixels when they are a window of it).

    Pixels of weight 0 take no part: an 11-pixel window reaches across the mask's edge, so
    there the rendered value stands in for the target and carries no gradient. Otherwise the
    static set would learn from what the moving region shows (tests/test_split.py)."""
    if weight_sum is None:
        weight_sum = weight.sum().clamp(min=1e-6)
    return 1.0 - ((ssim_map(rendered, target, weight) * weight).sum() + outside) / weight_sum


def pearson_loss(
    a: torch.Tensor, b: torch.Tensor, weight: torch.Tensor, outside: torch.Tensor | None = None
) -> torch.Tensor:
    """1 − weighted Pearson correlation of two maps; ``outside``: OUTSIDE_SUMS[3:] (covered
    weight, means, centred sums) of the rest of the view when the maps are a window of it."""
    co, mean_a, mean_b, var_a, var_b, cov_ab = (
        [torch.zeros((), dtype=a.dtype, device=a.device)] * 6 if outside is None else outside
    )
    covered = (weight.sum() + co).clamp(min=1e-6)
    ma = ((weight * a).sum() + co * mean_a) / covered
    mb = ((weight * b).sum() + co * mean_b) / covered
    da, db = a - ma, b - mb
    ea, eb = mean_a - ma, mean_b - mb  # the outside means about the view's
    cov = ((weight * da * db).sum() + cov_ab + co * ea * eb) / covered
    va = ((weight * da * da).sum() + var_a + co * ea * ea) / covered
    vb = ((weight * db * db).sum() + var_b + co * eb * eb) / covered
    return 1.0 - cov / (va * vb).clamp(min=1e-12).sqrt()


def sem_alpha(step: int, iterations: int) -> float:
    """The L_sem perturbation bound α at ``step`` (0 before the first threshold)."""
    alpha = 0.0
    for fraction, value in SEM_SCHEDULE:
        if step >= fraction * iterations:
            alpha = value
    return alpha


def moved_camera(camera: Camera, offset: torch.Tensor) -> Camera:
    """The same camera translated by ``offset`` (3,) in world space: L_sem's moved view (and
    the displaced views ``lift.export`` scores)."""
    w2c = camera.world_to_cam.clone()
    w2c[:3, 3] = w2c[:3, 3] - camera.R @ offset.to(torch.float64)
    return Camera(camera.K, w2c, camera.width, camera.height, camera.view_half_fov_tan)
