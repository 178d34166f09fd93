"""The torch trainer: the lifting optimisation with its losses and Adam in torch, rendering
with any differentiable rasteriser (``render_fn``). It is the reference the resident trainer
(``lift.resident``, the default) is checked against step for step, and the only trainer
with the torch rasteriser (``pano4d train --trainer torch``).

One step draws a view (``Trainer.next_view``), renders the trained Gaussians over the frozen
static set if there is one, sums the terms of ``lift.losses`` into L, back-propagates,
accumulates each Gaussian's screen-space position gradient for the densification statistic
(``lift.densify``) and takes an Adam step (β, ε and the learning rates of
``lift.trainer``).
"""

from __future__ import annotations

from typing import Any

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
    Trainer,
    TrainViews,
    learning_rates,
)


class GaussianTrainer(Trainer):
    """Optimises one set of Gaussians (optionally over the frozen static set) in torch,
    rendering with ``render_fn`` (any differentiable rasteriser)."""

    def __init__(
        self,
        gaussians: Gaussians,
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
        return g if self.static is None else Gaussians.cat([self.static, g])

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
