"""The densification policy both trainers follow: when to densify and prune, and which
Gaussians to split, clone or drop (``split_and_prune``, one decision for the torch and the
resident trainer).

Densify and prune (when enabled) run every ``densify_every`` steps between 20 % and 50 % of
the iterations (the second half lets the last children settle, as in 3DGS's schedule): prune
near-transparent Gaussians, split (large) or clone (small) those whose mean screen-space
position gradient is over DENSIFY_GRADIENT, and keep the count within ``max_gaussians``.
Adam's moments move with their Gaussians (``Densified.carry``): survivors keep theirs,
split children and clones start at zero, the step count goes on. A spacetime set is decided
on by its canonical Gaussians (at full presence), and its time parameters move with them
(``Densified.with_time``): children and clones take their parent's, so a split Gaussian's
children appear, fade and move as it did. The thresholds are
constants here: the papers' choices, not something a scene needs changed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F

from pano4d.gaussians import Gaussians
from pano4d.lift.diagnosis import DensifyStats
from pano4d.lift.trainer import Knobs
from pano4d.raster_torch import quat_to_rotation
from pano4d.spacetime import SpacetimeGaussians

PRUNE_OPACITY = 0.005
# Densification (3DGS's rule in screen-space units that do not depend on the view's size).
# A Gaussian's statistic is its mean ‖∂L/∂o‖ across the ray over the steps that saw it (o:
# its position offset in units of its initial distance; the views look out from the origin,
# so that is per radian of its direction on the screen, as 3DGS's 2-D mean), times the
# view's pixels and radians per pixel (Knobs.gradient_scale): how much the loss summed over
# the view's pixels changes when the Gaussian moves by one pixel. A Gaussian fitted to what
# the pixels can show (a pixel-sized edge) changes the sum by its contrast times a pixel or
# two; over DENSIFY_GRADIENT the fit is not done there. (3DGS's 2·10⁻⁴ per NDC unit of the
# mean loss, on its ≈ 1.2-MPixel images, is ≈ 0.3 in these units.)
DENSIFY_GRADIENT = 0.3
SPLIT_PIXELS = 1.0  # σ over this many working pixels: split; smaller: clone
SPLIT_FACTOR = 1.6


def screen_gradient(grad: torch.Tensor, means: torch.Tensor) -> torch.Tensor:
    """‖grad‖ across the ray from the origin to ``means`` (N, 3): the part of a position
    gradient that moves a Gaussian on the screen of the views, which look out from the
    origin (the densification statistic's step; adam.wgsl computes the same)."""
    ray = F.normalize(means, dim=-1)
    return torch.linalg.norm(grad - (grad * ray).sum(-1, keepdim=True) * ray, dim=-1)


def densify_due(knobs: Knobs, step: int) -> bool:
    """Whether densification runs after ``step`` steps: every ``densify_every`` steps
    between 20 % and 50 % of the iterations, when enabled."""
    if not knobs.densify or knobs.densify_every <= 0:
        return False
    return (
        0.2 * knobs.iterations <= step <= 0.5 * knobs.iterations
        and step % knobs.densify_every == 0
    )


@dataclass
class Densified:
    """The Gaussians after one densify-and-prune, with where each row came from."""

    gaussians: Gaussians
    unit: torch.Tensor  # (M,) offset units, carried from the source Gaussian
    source: torch.Tensor  # (M,) row of the Gaussian before, that each row comes from
    child: torch.Tensor  # (M,) bool: one of the two children of a split
    stats: DensifyStats  # the counts, for the run's diagnosis

    def carry(self, state: torch.Tensor) -> torch.Tensor:
        """Per-Gaussian optimiser state (one row per Gaussian) moved with the Gaussians:
        survivors keep theirs, split children start at zero (as 3DGS's densification)."""
        rows = state[self.source]
        child = self.child.reshape(-1, *([1] * (state.dim() - 1)))
        return torch.where(child, torch.zeros_like(rows), rows)

    def with_time(self, before: SpacetimeGaussians) -> SpacetimeGaussians:
        """The densified Gaussians with the time parameters of ``before`` (the spacetime set
        whose canonical Gaussians were decided on): each row takes its source's, survivors
        their own and children and clones their parent's."""
        return replace(before[self.source], canonical=self.gaussians)


def split_and_prune(
    g: Gaussians,
    unit: torch.Tensor,
    grad_accum: torch.Tensor,
    grad_count: torch.Tensor,
    knobs: Knobs,
    generator: torch.Generator,
    step: int,
) -> Densified:
    """One densify-and-prune (both trainers call this, after ``step`` steps).

    Drop the near-transparent Gaussians; densify every survivor whose mean position gradient
    reached DENSIFY_GRADIENT (the fit is not done there): split it into two smaller jittered
    children when it spans more than SPLIT_PIXELS working pixels, else clone it (a copy whose
    Adam moments start at zero, so the two part). When the budget has no room for all of
    them, the ones with the largest gradients go first. Keep at most ``max_gaussians`` (the
    most opaque)."""
    keep = torch.sigmoid(g.opacity_logits) > PRUNE_OPACITY
    mean_grad = grad_accum / grad_count.clamp(min=1) * knobs.gradient_scale
    room = max(knobs.max_gaussians - int(keep.sum()), 0)
    candidates = keep & (mean_grad >= DENSIFY_GRADIENT)
    n_candidates = int(candidates.sum())
    chosen = torch.zeros_like(keep)
    count = min(room, n_candidates)
    if count > 0:
        score = torch.where(candidates, mean_grad, torch.full_like(mean_grad, -1.0))
        chosen[torch.topk(score, count).indices] = True
    angular = g.log_scales.max(dim=-1).values.exp() / unit
    large = angular > SPLIT_PIXELS * knobs.pixel_angle
    split, clone = chosen & large, chosen & ~large
    rows = torch.arange(len(g), device=g.device)
    survivors = keep & ~split  # a cloned Gaussian stays, with its moments
    parts, units, sources = [g[survivors]], [unit[survivors]], [rows[survivors]]
    children = [torch.zeros(int(survivors.sum()), dtype=torch.bool, device=g.device)]
    if split.any():
        parent = g[split]
        # Children are drawn from the parent's own ellipsoid (its axes rotated into the
        # world): a disc's children stay on its surface and spread along its wide axes.
        axes = quat_to_rotation(parent.quats) * parent.log_scales.exp()[:, None, :]
        for _ in range(2):
            jitter = torch.randn(parent.means.shape, generator=generator).to(g.device)
            parts.append(
                Gaussians(
                    parent.means + 0.5 * (axes @ jitter[:, :, None])[:, :, 0],
                    parent.log_scales - math.log(SPLIT_FACTOR),
                    parent.quats,
                    parent.opacity_logits,
                    parent.sh,
                )
            )
            units.append(unit[split])
            sources.append(rows[split])
            children.append(torch.ones(int(split.sum()), dtype=torch.bool, device=g.device))
    if clone.any():
        parts.append(g[clone])
        units.append(unit[clone])
        sources.append(rows[clone])
        children.append(torch.ones(int(clone.sum()), dtype=torch.bool, device=g.device))
    merged = Gaussians.cat(parts)
    merged_units, source, child = torch.cat(units), torch.cat(sources), torch.cat(children)
    grown = len(merged)
    if len(merged) > knobs.max_gaussians:
        top = torch.topk(merged.opacity_logits, knobs.max_gaussians).indices
        merged, merged_units = merged[top], merged_units[top]
        source, child = source[top], child[top]
    stats = DensifyStats(
        step=step, before=len(g), pruned=int((~keep).sum()), split=int(split.sum()),
        cloned=int(clone.sum()), clipped=grown - len(merged), after=len(merged),
        budget=knobs.max_gaussians, candidates=n_candidates,
        seen=int((keep & (grad_count > 0)).sum()),
        threshold=float(mean_grad[chosen].min()) if chosen.any() else None,
        limit="budget" if count < n_candidates else "gradient",
    )  # fmt: skip
    return Densified(merged, merged_units, source, child, stats)
