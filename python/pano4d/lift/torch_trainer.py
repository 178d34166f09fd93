"""The torch trainer: the lifting optimisation with its losses and Adam in torch, rendering
with any differentiable rasteriser (``render_fn``). It is the reference the resident trainer
(``lift.resident``, the default) is checked against step for step, and the only trainer
with the torch rasteriser (``pano4d train --trainer torch``).

One step draws a view (``Trainer.next_view``), renders the trained Gaussians over the frozen
static set if there is one, sums the terms of ``lift.losses`` into L, back-propagates,
accumulates each Gaussian's screen-space position gradient for the densification statistic
(``lift.densify``) and takes an Adam step (β, ε and the learning rates of
``lift.trainer``).

A spacetime set (``pano4d.spacetime``) is drawn at the step's view time
(``SpacetimeGaussians.at``) and autograd carries the gradient through that evaluation to
its time parameters: its own Adam groups, its position terms as offsets in each Gaussian's
unit like the means; after each step its log-widths are held at ≥ log(MIN_WIDTH_FRAMES).
"""

from __future__ import annotations

import math
from typing import Any, cast

import torch
import torch.nn.functional as F

from pano4d.gaussians import Gaussians
from pano4d.lift.densify import densify_due, screen_gradient, split_and_prune
from pano4d.lift.losses import moved_camera, pearson_loss, sem_alpha, ssim_loss
from pano4d.lift.trainer import (
    ADAM_BETAS,
    ADAM_EPS,
    FeatureModel,
    Knobs,
    RenderFn,
    TrainedSet,
    Trainer,
    TrainViews,
    learning_rates,
)
from pano4d.spacetime import MIN_WIDTH_FRAMES, SpacetimeGaussians, TimeModel

# The floor of a spacetime set's log-widths, applied after each Adam step.
MIN_LOG_WIDTH = math.log(MIN_WIDTH_FRAMES)


class GaussianTrainer(Trainer[TrainedSet]):
    """Optimises one set of Gaussians or one spacetime set (optionally over the frozen
    static set) in torch, rendering with ``render_fn`` (any differentiable rasteriser)."""

    def __init__(
        self,
        gaussians: TrainedSet,
        views: TrainViews,
        knobs: Knobs,
        render_fn: RenderFn,
        static: Gaussians | None = None,
        features: FeatureModel | None = None,
        seed: int = 0,
        background: torch.Tensor | None = None,
    ) -> None:
        self.render_fn = render_fn
        super().__init__(gaussians, views, knobs, static, features, seed, background)

    def _start(self, gaussians: TrainedSet) -> None:
        self._set_parameters(gaussians)

    # --- parameters ------------------------------------------------------------------------
    def _set_parameters(
        self, trained: Gaussians | SpacetimeGaussians, unit: torch.Tensor | None = None
    ) -> None:
        """Optimise ``trained`` from here with a fresh Adam: its positions (the means, and
        a spacetime set's position terms) as offsets from where they are now (their
        anchors), in units of ``unit`` (by default each Gaussian's distance from the
        centre)."""
        trained = trained.detach()
        g = trained.canonical if isinstance(trained, SpacetimeGaussians) else trained
        self.anchors = g.means.clone()
        self.unit = (
            torch.linalg.norm(g.means, dim=-1).clamp(min=1e-3) if unit is None else unit
        )  # one offset unit per Gaussian: its initial distance from the centre
        self.params = {
            "offsets": torch.zeros_like(g.means),
            "log_scales": g.log_scales.clone(),
            "quats": g.quats.clone(),
            "opacity_logits": g.opacity_logits.clone(),
            "sh_dc": g.sh[:, :1].clone(),
            "sh_rest": g.sh[:, 1:].clone(),
        }
        # A spacetime set's time model and its position terms' anchors (None: Gaussians).
        self.model: TimeModel | None = None
        self.term_anchors: torch.Tensor | None = None
        if isinstance(trained, SpacetimeGaussians):
            self.model = trained.model
            self.term_anchors = trained.position_terms.clone()
            self.params |= {
                "colour_terms": trained.colour_terms.clone(),
                "position_terms": torch.zeros_like(trained.position_terms),
                "time_centre": trained.time_centre.clone(),
                "time_log_width": trained.time_log_width.clone(),
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

    def _trained(self) -> Gaussians | SpacetimeGaussians:
        """The set being trained, differentiable in the parameters."""
        return self._set_of(self.params, self.anchors, self.unit, self.term_anchors)

    def _set_of(
        self,
        p: dict[str, torch.Tensor],
        anchors: torch.Tensor,
        unit: torch.Tensor,
        term_anchors: torch.Tensor | None,
    ) -> Gaussians | SpacetimeGaussians:
        """The set that parameter groups ``p`` stand for: positions as offsets from
        ``anchors`` (and ``term_anchors``) in units of ``unit``."""
        g = Gaussians(
            anchors + p["offsets"] * unit[:, None],
            p["log_scales"],
            p["quats"],
            p["opacity_logits"],
            torch.cat([p["sh_dc"], p["sh_rest"]], dim=1),
        )
        if self.model is None or term_anchors is None:
            return g
        return SpacetimeGaussians(
            self.model,
            g,
            p["time_centre"],
            p["time_log_width"],
            p["colour_terms"],
            term_anchors + p["position_terms"] * unit[:, None, None],
        )

    def gaussians(self, time: float = 0.0) -> Gaussians:
        """The trained Gaussians as drawn at ``time`` (frames; a set of Gaussians is the same
        at every time), differentiable in the parameters."""
        trained = self._trained()
        return trained.at(time) if isinstance(trained, SpacetimeGaussians) else trained

    def result(self) -> TrainedSet:
        return cast(TrainedSet, self._trained().detach())

    def _scene(self, time: float) -> Gaussians:
        g = self.gaussians(time)
        return g if self.static is None else Gaussians.cat([self.static, g])

    # --- one step --------------------------------------------------------------------------
    def loss_at(self, index: int) -> torch.Tensor:
        v, k = self.views, self.knobs
        camera, time = v.cameras[index], v.time(index)
        out = self.render_fn(self._scene(time), camera, self.background)
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
            moved_rgb = self.render_fn(self._scene(time), moved, self.background).rgb
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
            # The offsets' gradient is the drawn mean's times the unit (a spacetime set's
            # mean at t moves with its offset one for one); its part across the ray to where
            # the step drew the Gaussian is what moves it on that view's screen.
            with torch.no_grad():
                norm = screen_gradient(grad, self.gaussians(self.last_time).means)
            self.grad_accum += norm
            self.grad_count += (norm > 0).to(norm.dtype)
        self.optimiser.step()
        if self.model is not None:
            with torch.no_grad():
                self.params["time_log_width"].clamp_(min=MIN_LOG_WIDTH)
        self.step += 1
        self.last_loss = float(loss.detach())
        if densify_due(self.knobs, self.step):
            self.densify_and_prune()
        return self.last_loss

    # --- densify and prune ------------------------------------------------------------------
    def densify_and_prune(self) -> None:
        with torch.no_grad():
            trained = self._trained().detach()
            spacetime = isinstance(trained, SpacetimeGaussians)
            d = split_and_prune(
                trained.canonical if spacetime else trained,
                self.unit,
                self.grad_accum,
                self.grad_count,
                self.knobs,
                self.generator,
                self.step,
            )
            self.last_densify = d.stats
            before = {name: self.optimiser.state.get(p) for name, p in self.params.items()}
            # Offsets restart from zero at the new positions (and position terms); Adam's
            # moments (kept in offset units, and each Gaussian keeps its unit) move with
            # their Gaussians, a spacetime set's time parameters too (children take their
            # parent's).
            self._set_parameters(d.with_time(trained) if spacetime else d.gaussians, d.unit)
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
        state = {
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
        if self.model is not None and self.term_anchors is not None:
            m = self.model
            state["time_model"] = [m.period, m.colour_harmonics, m.position_harmonics]
            state["term_anchors"] = self.term_anchors.cpu()
        return state

    def trained_in(self, state: dict[str, Any]) -> TrainedSet:
        # On a CPU run the state's tensors are the parameters themselves (``.cpu()`` copies
        # nothing), which the next steps change in place: the set is built from copies.
        p = {name: value.clone() for name, value in state["params"].items()}
        trained = self._set_of(p, state["anchors"], state["unit"], state.get("term_anchors"))
        return cast(TrainedSet, trained)

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if ("time_model" in state) != (self.model is not None):
            kinds = ("a set of Gaussians", "a spacetime set")
            raise ValueError(
                f"this checkpoint holds {kinds['time_model' in state]} and this trainer "
                f"trains {kinds[self.model is not None]}"
            )
        p = {k: v.to(self.device) for k, v in state["params"].items()}
        unit = state["unit"].to(self.device)
        # Anchored where the checkpoint's were; every parameter (offsets included) is then
        # copied as saved, not recomputed.
        g = Gaussians(
            state["anchors"].to(self.device),
            p["log_scales"],
            p["quats"],
            p["opacity_logits"],
            torch.cat([p["sh_dc"], p["sh_rest"]], dim=1),
        )
        trained: Gaussians | SpacetimeGaussians = g
        if "time_model" in state:
            trained = SpacetimeGaussians(
                TimeModel(*state["time_model"]),
                g,
                p["time_centre"],
                p["time_log_width"],
                p["colour_terms"],
                state["term_anchors"].to(self.device),
            )
        self._set_parameters(trained, unit)
        with torch.no_grad():
            for name, value in p.items():
                self.params[name].copy_(value)
        self.optimiser.load_state_dict(state["optimiser"])
        self.generator.set_state(state["generator"])
        self.step = int(state["step"])
        self.grad_accum = state["grad_accum"].to(self.device)
        self.grad_count = state["grad_count"].to(self.device)
        self.last_loss = float(state["last_loss"])
