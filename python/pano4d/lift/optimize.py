"""Per-timestamp Gaussian optimisation (4K4DGen, lifting phase).

    L = L_rgb + λ_temporal L_temporal + λ_sem L_sem + λ_geo L_geo
    L_rgb      = (1 − λ_dssim) L1 + λ_dssim (1 − SSIM)        (kornia SSIM, 11×11 window)
    L_temporal = L1 between the render of G_t and that of G_{t−1} in the same view
    L_geo      = 1 − Pearson(rendered depth, Θ's depth)
    L_sem      = 1 − cos(CLS(render at the view), CLS(render at the view moved by δ)),
                 δ ∈ [−α, α]³ × median scene depth, α = 0.05 / 0.1 / 0.2 from 54 / 66 / 90 %
                 of the iterations; only with a feature backend (DINOv2).

The λ, densification and the learning rates are knobs (``Knobs``, whose shared part
``config.OptimisationKnobs`` documents them); Adam's β and ε, the SSIM window, the L_sem
schedule and the densification's thresholds are constants here: numerical or the papers'
choices, not something a scene needs changed.

Each step renders one view drawn from a seeded generator. Gaussians can be trained against a
frozen context (the static set while a timestamp's dynamic set trains): the context is
rendered with them but gets no gradient. Positions are optimised as offsets in units of each
Gaussian's initial depth, so one learning rate fits a Gaussian at 2 m and one at 1000 m.

Densify and prune (when enabled) run every ``densify_every`` steps between 20 % and 50 % of
the iterations (the second half lets the last children settle, as in 3DGS's schedule): prune
near-transparent Gaussians, split (large) or clone (small) those whose mean screen-space
position gradient is over DENSIFY_GRADIENT, and keep the count within ``max_gaussians``
(``split_and_prune``, shared with the resident trainer). Adam's moments move with their
Gaussians: survivors keep theirs, split children and clones start at zero, the step count
goes on.
For the run's diagnosis (``lift.diagnosis``) a trainer keeps its last loss terms in
``last_terms`` and its last densify-and-prune's counts in ``last_densify``.
``state_dict`` / ``load_state_dict`` capture everything a resumed run needs (parameters,
Adam moments, the view generator, the step), so a resumed run continues bit-for-bit.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import torch
import torch.nn.functional as F

from pano4d.camera import Camera
from pano4d.config import OptimisationKnobs
from pano4d.gaussians import Gaussians
from pano4d.lift.diagnosis import DensifyStats
from pano4d.raster_torch import quat_to_rotation

SSIM_WINDOW = 11
SEM_SCHEDULE = ((0.54, 0.05), (0.66, 0.1), (0.90, 0.2))  # (fraction of iterations, α)
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
ADAM_EPS = 1e-15  # 3DGS's
ADAM_BETAS = (0.9, 0.999)  # torch.optim.Adam's defaults, what 3DGS trains with
SH_REST_LR_DIVISOR = 20  # the higher SH degrees learn 20× slower than degree 0 (3DGS)


class RenderFn(Protocol):
    def __call__(
        self, gaussians: Gaussians, camera: Camera, background: torch.Tensor | None
    ) -> Any: ...


class FeatureModel(Protocol):
    def cls(self, image: torch.Tensor) -> torch.Tensor:
        """CLS embedding (D,) of an image (h, w, 3) in [0, 1], differentiable."""
        ...


# The loss sums over the pixels of a view outside the window a step renders (``TrainViews.
# outside``; lift.windows computes them): Σ w·mean|x − t|, Σ w·SSIM, Σ w·mean|x − prev|,
# L_geo's covered weight Σ c, the means of the rendered and of Θ's depth over it, and the
# sums Σ c·da², Σ c·db², Σ c·da·db about those means. The device's LossParams has them in
# this order (crates/splat-core/src/train/losses.rs, OUTSIDE_SUMS).
OUTSIDE_SUMS = (
    "l1", "ssim", "temporal", "covered", "mean_depth", "mean_target_depth",
    "var_depth", "var_target_depth", "cov_depth",
)  # fmt: skip


@dataclass
class TrainViews:
    """What one optimisation sees: cameras and, per view, target (h, w, 3), loss weight
    (h, w) and Θ's z-depth (h, w); ``previous`` holds renders of G_{t−1} for L_temporal.

    The cameras may be windows of larger views (``Camera.window``: a dynamic step renders
    only the pixels the moving region reaches, lift.windows). Then ``weight_sums`` (V,)
    holds the whole views' loss normalisers and ``outside`` (V, len(OUTSIDE_SUMS)) the loss
    sums over the rest of each view, so that the loss and its gradient are the whole
    view's. Views may then differ in size: the tensors hold lists."""

    cameras: list[Camera]
    targets: torch.Tensor | list[torch.Tensor]
    weights: torch.Tensor | list[torch.Tensor]
    depth: torch.Tensor | list[torch.Tensor]
    previous: torch.Tensor | list[torch.Tensor] | None = None
    weight_sums: torch.Tensor | None = None
    outside: torch.Tensor | None = None

    def weight_sum(self, index: int) -> torch.Tensor:
        """The loss normaliser of view ``index``: max(Σ weight, 1e-6) over the whole view."""
        if self.weight_sums is not None:
            return self.weight_sums[index]
        return self.weights[index].sum().clamp(min=1e-6)

    def outside_sums(self, index: int) -> torch.Tensor:
        """OUTSIDE_SUMS of view ``index`` (zeros: the view is whole)."""
        if self.outside is not None:
            return self.outside[index]
        return torch.zeros(len(OUTSIDE_SUMS), device=self.weights[index].device)


class Knobs(OptimisationKnobs):
    """One optimisation's knobs: the preset's optimisation knobs (the λ, densify, the
    learning rates) and this run's own (``pipeline.trainer_knobs`` makes them per stage)."""

    iterations: int
    max_gaussians: int = 1_000_000  # this set's budget
    pixel_angle: float = 0.0  # radians per working-panorama pixel (0: every Gaussian splits)
    # The views' pixels × radians per pixel: the statistic's unit (DENSIFY_GRADIENT).
    gradient_scale: float = 1.0
    densify_every: int = 100
    sem_scale: float = 1.0  # world units of δ = 1 (median scene depth)


def learning_rates(knobs: OptimisationKnobs) -> dict[str, float]:
    """Adam's learning rate per parameter group (the groups of GaussianTrainer.params and of
    the resident trainer's TrainSettings)."""
    return {
        "offsets": knobs.lr_position,
        "log_scales": knobs.lr_scale,
        "quats": knobs.lr_rotation,
        "opacity_logits": knobs.lr_opacity,
        "sh_dc": knobs.lr_color,
        "sh_rest": knobs.lr_color / SH_REST_LR_DIVISOR,
    }


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


def moved_camera(camera: Camera, offset: torch.Tensor) -> Camera:
    """The same camera translated by ``offset`` (3,) in world space."""
    w2c = camera.world_to_cam.clone()
    w2c[:3, 3] = w2c[:3, 3] - camera.R @ offset.to(torch.float64)
    return Camera(camera.K, w2c, camera.width, camera.height, camera.view_half_fov_tan)


class Trainer(ABC):
    """What both trainers share (``GaussianTrainer`` here, ``ResidentTrainer`` in
    lift.resident): their inputs, the step count, the seeded generator that draws each
    step's view, and the loop; a lifting stage can use either (``pipeline.make_trainer``).
    Only the torch trainer takes a ``render_fn``: the resident one renders on the device."""

    def __init__(
        self,
        gaussians: Gaussians,
        views: TrainViews,
        knobs: Knobs,
        context: Gaussians | None = None,
        features: FeatureModel | None = None,
        seed: int = 0,
        background: torch.Tensor | None = None,
    ) -> None:
        if knobs.iterations < 0:
            raise ValueError(f"iterations must be ≥ 0, got {knobs.iterations}")
        if len(views.cameras) == 0:
            raise ValueError("no views to train on")
        self.views, self.knobs, self.features = views, knobs, features
        self.context = context.detach() if context is not None else None
        self.background = background
        self.device = gaussians.device
        self.step = 0
        self.last_view = -1  # the view of the last step (the records say which view they saw)
        self.generator = torch.Generator().manual_seed(seed)
        self.last_loss = math.nan
        # For the diagnosis: diagnosis.TERMS names → values (tensors, read when logged).
        self.last_terms: dict[str, float | torch.Tensor] = {}
        self.last_densify: DensifyStats | None = None
        self._start(gaussians)

    @abstractmethod
    def _start(self, gaussians: Gaussians) -> None:
        """Sets up the optimisation of ``gaussians`` (called once by __init__)."""

    def next_view(self) -> int:
        """The view of the next step, drawn from the seeded generator (``last_view``)."""
        self.last_view = int(torch.randint(len(self.views.cameras), (), generator=self.generator))
        return self.last_view

    @abstractmethod
    def train_step(self) -> float:
        """One step; returns the loss (the resident trainer's last one read back)."""

    @abstractmethod
    def result(self) -> Gaussians:
        """The trained Gaussians."""

    @abstractmethod
    def densify_and_prune(self) -> None: ...

    @abstractmethod
    def state_dict(self) -> dict[str, Any]:
        """Everything a resumed run needs."""

    @abstractmethod
    def load_state_dict(self, state: dict[str, Any]) -> None: ...

    def run(self, on_step: Callable[[Trainer], bool] | None = None) -> Gaussians:
        """Train up to ``knobs.iterations`` (continuing from ``self.step``), or until
        ``on_step`` returns True after a step; returns the result."""
        while self.step < self.knobs.iterations:
            self.train_step()
            if on_step is not None and on_step(self):
                break
        return self.result()


class GaussianTrainer(Trainer):
    """Optimises one set of Gaussians (optionally against a frozen context) in torch,
    rendering with ``render_fn`` (any differentiable rasteriser)."""

    def __init__(
        self,
        gaussians: Gaussians,
        views: TrainViews,
        knobs: Knobs,
        render_fn: RenderFn,
        context: Gaussians | None = None,
        features: FeatureModel | None = None,
        seed: int = 0,
        background: torch.Tensor | None = None,
    ) -> None:
        self.render_fn = render_fn
        super().__init__(gaussians, views, knobs, context, features, seed, background)

    def _start(self, gaussians: Gaussians) -> None:
        self._set_parameters(gaussians)

    # --- parameters ------------------------------------------------------------------------
    def _set_parameters(
        self, g: Gaussians, anchors: torch.Tensor | None = None, unit: torch.Tensor | None = None
    ) -> None:
        g = g.detach()
        self.anchors = g.means.clone() if anchors is None else anchors
        self.unit = (
            torch.linalg.norm(g.means, dim=-1).clamp(min=1e-3) if unit is None else unit
        )  # one offset unit per Gaussian: its initial distance from the centre
        self.params = {
            "offsets": ((g.means - self.anchors) / self.unit[:, None]).clone(),
            "log_scales": g.log_scales.clone(),
            "quats": g.quats.clone(),
            "opacity_logits": g.opacity_logits.clone(),
            "sh_dc": g.sh[:, :1].clone(),
            "sh_rest": g.sh[:, 1:].clone(),
        }
        for p in self.params.values():
            p.requires_grad_(True)
        rates = learning_rates(self.knobs)
        self.optimiser = torch.optim.Adam(
            [{"params": [p], "lr": rates[k], "name": k} for k, p in self.params.items()],
            betas=ADAM_BETAS,
            eps=ADAM_EPS,
        )
        self.grad_accum = torch.zeros(len(g), device=self.device)
        self.grad_count = torch.zeros(len(g), device=self.device)

    def gaussians(self) -> Gaussians:
        """The current Gaussians (differentiable in the parameters)."""
        p = self.params
        return Gaussians(
            self.anchors + p["offsets"] * self.unit[:, None],
            p["log_scales"],
            p["quats"],
            p["opacity_logits"],
            torch.cat([p["sh_dc"], p["sh_rest"]], dim=1),
        )

    def result(self) -> Gaussians:
        return self.gaussians().detach()

    def _scene(self) -> Gaussians:
        g = self.gaussians()
        return g if self.context is None else Gaussians.cat([self.context, g])

    # --- one step --------------------------------------------------------------------------
    def loss_at(self, index: int) -> torch.Tensor:
        v, k = self.views, self.knobs
        camera = v.cameras[index]
        out = self.render_fn(self._scene(), camera, self.background)
        rgb, depth = out.rgb, out.depth
        target, weight = v.targets[index], v.weights[index]
        wsum, outside = v.weight_sum(index), v.outside_sums(index)
        l1 = (((rgb - target).abs().mean(-1) * weight).sum() + outside[0]) / wsum
        d_ssim = ssim_loss(rgb, target, weight, wsum, outside[1])
        loss = (1 - k.lambda_dssim) * l1 + k.lambda_dssim * d_ssim
        terms = {"l1": l1, "d_ssim": d_ssim}
        if k.lambda_temporal > 0 and v.previous is not None:
            temporal = (
                ((rgb - v.previous[index]).abs().mean(-1) * weight).sum() + outside[2]
            ) / wsum
            loss = loss + k.lambda_temporal * temporal
            terms["temporal"] = temporal
        if k.lambda_geo > 0:
            covered = weight * (out.alpha.detach() > 0.5)
            if covered.sum() + outside[3] > 16:
                terms["geo"] = pearson_loss(depth, v.depth[index], covered, outside[3:])
                loss = loss + k.lambda_geo * terms["geo"]
        alpha = sem_alpha(self.step, k.iterations)
        if k.lambda_sem > 0 and self.features is not None and alpha > 0:
            delta = torch.rand(3, generator=self.generator, dtype=torch.float64) * 2 - 1
            moved = moved_camera(camera, delta * alpha * k.sem_scale)
            moved_rgb = self.render_fn(self._scene(), moved, self.background).rgb
            centre = self.features.cls(rgb.detach())
            shifted = self.features.cls(moved_rgb)
            terms["sem"] = 1 - F.cosine_similarity(centre, shifted, dim=0)
            loss = loss + k.lambda_sem * terms["sem"]
        self.last_terms = {"total": loss.detach(), **{n: t.detach() for n, t in terms.items()}}
        return loss

    def train_step(self) -> float:
        loss = self.loss_at(self.next_view())
        self.optimiser.zero_grad(set_to_none=True)
        loss.backward()
        grad = self.params["offsets"].grad
        if grad is not None:
            means = self.anchors + self.params["offsets"].detach() * self.unit[:, None]
            norm = screen_gradient(grad, means)
            self.grad_accum += norm
            self.grad_count += (norm > 0).to(norm.dtype)
        self.optimiser.step()
        self.step += 1
        self.last_loss = float(loss.detach())
        if densify_due(self.knobs, self.step):
            self.densify_and_prune()
        return self.last_loss

    # --- densify and prune ------------------------------------------------------------------
    def densify_and_prune(self) -> None:
        with torch.no_grad():
            d = split_and_prune(
                self.result(),
                self.unit,
                self.grad_accum,
                self.grad_count,
                self.knobs,
                self.generator,
                self.step,
            )
            self.last_densify = d.stats
            before = {name: self.optimiser.state.get(p) for name, p in self.params.items()}
            # Offsets restart from zero at the new positions; Adam's moments (kept in offset
            # units, and each Gaussian keeps its unit) move with their Gaussians.
            self._set_parameters(d.gaussians, d.gaussians.means.clone(), d.unit)
            for name, p in self.params.items():
                state = before[name]
                if state:
                    self.optimiser.state[p] = {
                        "step": state["step"].clone(),
                        "exp_avg": d.carry(state["exp_avg"]),
                        "exp_avg_sq": d.carry(state["exp_avg_sq"]),
                    }

    # --- checkpoints -------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {
            "params": {k: v.detach().cpu() for k, v in self.params.items()},
            "anchors": self.anchors.cpu(),
            "unit": self.unit.cpu(),
            "optimiser": self.optimiser.state_dict(),
            "generator": self.generator.get_state(),
            "step": self.step,
            "grad_accum": self.grad_accum.cpu(),
            "grad_count": self.grad_count.cpu(),
            "last_loss": self.last_loss,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        p = {k: v.to(self.device) for k, v in state["params"].items()}
        anchors, unit = state["anchors"].to(self.device), state["unit"].to(self.device)
        g = Gaussians(
            anchors + p["offsets"] * unit[:, None],
            p["log_scales"],
            p["quats"],
            p["opacity_logits"],
            torch.cat([p["sh_dc"], p["sh_rest"]], dim=1),
        )
        self._set_parameters(g, anchors, unit)
        with torch.no_grad():
            self.params["offsets"].copy_(p["offsets"])  # exact, not recomputed through means
        self.optimiser.load_state_dict(state["optimiser"])
        self.generator.set_state(state["generator"])
        self.step = int(state["step"])
        self.grad_accum = state["grad_accum"].to(self.device)
        self.grad_count = state["grad_count"].to(self.device)
        self.last_loss = float(state["last_loss"])
