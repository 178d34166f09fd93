"""The resident training loop: ``GaussianTrainer``'s optimisation with the Gaussians, Adam's
moments and the stage's targets kept on the GPU (``pano4d._core.TrainSession``, Rust module
``splat_core::train``).

A step is forward → losses and their pixel gradient → backward → Adam, all on the device and
submitted without waiting for the host; the view is drawn from the same seeded generator as
``GaussianTrainer``'s, so the two trainers see the same views in the same order. The host
reads back the loss every ``LOSS_EVERY`` steps (and at the last), the whole trained state at
checkpoints (``state_dict``), densification and ``result()``. Densification reads the
parameters, moments and gradient statistics back once per interval, runs the torch trainer's
own decision (``split_and_prune``) and uploads the survivors and children (moments carried).

The semantic loss (only with a feature model) needs the render on the host: on its steps the
centre render and the moved render are read back, the feature model runs in torch, and the
moved render's pixel gradient is uploaded and back-propagated on the device. It runs on every
step (``sem_every = 1``, as the torch trainer) unless ``sem_every`` is raised.

A spacetime set (``pano4d.spacetime``) is drawn at each step's view time by the device's
evaluate pass, whose adjoint carries the gradient to its time parameters (splat-core's
``spacetime/evaluate.rs``); Adam updates every parameter there and holds the log-widths at the
torch trainer's floor. Its state comes back as a spacetime set too.

``ResidentTrainer`` has ``GaussianTrainer``'s constructor less ``render_fn`` (renders
happen on the device) and its public methods, so a lifting stage can use either. Its knobs
reach the device as one typed object, ``pano4d._core.TrainSettings`` (``train_settings``).
``train_step`` returns the last loss read back, which is up to ``LOSS_EVERY − 1`` steps old.

Everything crosses to the device as a typed object (``pano4d._core``'s stub lists them):
each view's targets as a ``ViewTarget``, the static set as ``GaussianArrays``, the trained
set and Adam's moments as ``GaussianArrays`` or ``SpacetimeArrays`` (``pano4d.extension``),
and the loss comes back as ``LossParts``, read by name.
"""

from __future__ import annotations

from typing import Any, cast

import torch
import torch.nn.functional as F

from pano4d.extension import (
    core,
    flat,
    gaussian_arrays,
    gaussians_from,
    spacetime_arrays,
    spacetime_from,
    view,
)
from pano4d.gaussians import Gaussians
from pano4d.lift.densify import densify_due, split_and_prune
from pano4d.lift.diagnosis import LOSS_EVERY
from pano4d.lift.losses import moved_camera, sem_alpha
from pano4d.lift.trainer import ADAM_BETAS, ADAM_EPS, Knobs, TrainedSet, Trainer, learning_rates
from pano4d.spacetime import SpacetimeGaussians


def _arrays(s: Gaussians | SpacetimeGaussians) -> core.GaussianArrays | core.SpacetimeArrays:
    """A set (or Adam moments of one) as the session takes it."""
    return spacetime_arrays(s) if isinstance(s, SpacetimeGaussians) else gaussian_arrays(s)


def _from_arrays(
    arrays: core.GaussianArrays | core.SpacetimeArrays, device: torch.device | str
) -> Gaussians | SpacetimeGaussians:
    """What the session gives back, as the set it is."""
    if isinstance(arrays, core.SpacetimeArrays):
        return spacetime_from(arrays, device)
    return gaussians_from(arrays, device)


def _checkpoint_form(s: Gaussians | SpacetimeGaussians) -> dict[str, Any]:
    """A set (or Adam moments of one) as a checkpoint holds it: a set of Gaussians as its
    tensors, a spacetime set as its numpy arrays (``SpacetimeGaussians.to_numpy``)."""
    return s.to_numpy() if isinstance(s, SpacetimeGaussians) else s.to("cpu").tensors()


def _from_checkpoint(held: dict[str, Any]) -> Gaussians | SpacetimeGaussians:
    return SpacetimeGaussians.from_numpy(held) if "model" in held else Gaussians(**held)


def train_settings(
    knobs: Knobs, background: tuple[float, ...] = (0.0, 0.0, 0.0)
) -> core.TrainSettings:
    """What the device's loop needs of ``knobs``, as ``pano4d._core.TrainSettings`` (the Rust
    ``TrainConfig``): learning rates per group, Adam's β and ε, the weights of L1, D-SSIM,
    L_temporal and L_geo (L_sem runs on the host), the background and the rasteriser's mode."""
    return core.TrainSettings(
        learning_rates=learning_rates(knobs),
        betas=ADAM_BETAS,
        eps=ADAM_EPS,
        lambda_l1=1 - knobs.lambda_dssim,
        lambda_ssim=knobs.lambda_dssim,
        lambda_temporal=knobs.lambda_temporal,
        lambda_geo=knobs.lambda_geo,
        background=background,
        antialiased=knobs.antialiased,
    )


class ResidentTrainer(Trainer[TrainedSet]):
    """Optimises one set of Gaussians or one spacetime set (optionally over the frozen
    static set) on the GPU."""

    sem_every = 1  # steps between semantic-loss evaluations (each reads two renders back)
    overflowed_frames = 0  # steps whose frame outgrew the intersection buffers (no gradient)

    def _start(self, gaussians: TrainedSet) -> None:
        trained = gaussians.detach()
        g = trained.canonical if isinstance(trained, SpacetimeGaussians) else trained
        static = Gaussians.empty(g.sh_degree) if self.static is None else self.static
        if static.sh_degree > g.sh_degree:
            raise ValueError(
                f"the static set's SH degree ({static.sh_degree}) is above the trained set's "
                f"({g.sh_degree}); give the trained set at least the static set's degree"
            )
        static = static.with_sh_degree(g.sh_degree)
        bg = torch.zeros(3) if self.background is None else torch.as_tensor(self.background)
        unit = torch.linalg.norm(g.means, dim=-1).clamp(min=1e-3)
        self._session = core.TrainSession(
            static_set=gaussian_arrays(static),
            trained=_arrays(trained),
            unit=flat(unit),
            views=self._view_targets(),
            settings=train_settings(self.knobs, tuple(float(v) for v in bg.reshape(-1))),
        )
        self._session.reserve_frames()

    def _view_targets(self) -> list[core.ViewTarget]:
        v, k = self.views, self.knobs
        temporal = k.lambda_temporal > 0 and v.previous is not None
        return [
            core.ViewTarget(
                view=view(camera),
                rgb=flat(v.targets[i]),
                weight=flat(v.weights[i]),
                depth=flat(v.depth[i]) if k.lambda_geo > 0 else None,
                previous=flat(v.previous[i]) if temporal and v.previous is not None else None,
                weight_sum=float(v.weight_sum(i)),
                outside_sums=[float(x) for x in v.outside_sums(i)],
                time=v.time(i),
            )
            for i, camera in enumerate(v.cameras)
        ]

    # --- one step --------------------------------------------------------------------------
    def train_step(self) -> float:
        index = self.next_view()
        k = self.knobs
        alpha = sem_alpha(self.step, k.iterations)
        sem = (
            k.lambda_sem > 0
            and self.features is not None
            and alpha > 0
            and self.step % self.sem_every == 0
        )
        sem_loss = self._semantic_step(index, alpha) if sem else 0.0
        if not sem:
            self._session.step(index)
        self.step += 1
        if sem or self.step % LOSS_EVERY == 0 or self.step >= k.iterations:
            loss = self._session.loss()
            self.last_loss = loss.total + sem_loss
            self.last_terms = self._terms(loss, sem_loss if sem else None)
            # Steps do not wait for their intersection counts: a frame that outgrew the
            # renderer's room drew only the background (no gradient that step). Counted
            # here, and the room grows before the next frames.
            self.overflowed_frames += self._session.check_frames().overflowed
        if densify_due(k, self.step):
            self.densify_and_prune()
        return self.last_loss

    def _terms(
        self, loss: core.LossParts, sem_loss: float | None
    ) -> dict[str, float | torch.Tensor]:
        """GaussianTrainer.last_terms from TrainSession.loss() and this step's λ_sem·L_sem."""
        k = self.knobs
        terms: dict[str, float | torch.Tensor] = {
            "total": loss.total + (sem_loss or 0.0), "l1": loss.l1, "d_ssim": loss.d_ssim
        }
        if k.lambda_temporal > 0 and self.views.previous is not None:
            terms["temporal"] = loss.temporal
        if loss.geo_applied:
            terms["geo"] = loss.one_minus_pearson
        if sem_loss is not None:
            terms["sem"] = sem_loss / k.lambda_sem
        return terms

    def _semantic_step(self, index: int, alpha: float) -> float:
        """A step with L_sem: the device's losses and backward, then L_sem on the host from
        the read-back renders, its pixel gradient back-propagated on the device, then Adam."""
        assert self.features is not None
        k, camera = self.knobs, self.views.cameras[index]
        h, w = camera.height, camera.width
        s = self._session
        s.forward_backward(index)
        centre = torch.from_numpy(s.read_render()).reshape(h, w, 5)[..., :3].to(self.device)
        delta = torch.rand(3, generator=self.generator, dtype=torch.float64) * 2 - 1
        moved = moved_camera(camera, delta * alpha * k.sem_scale)
        pixels = torch.from_numpy(s.render_at(view(moved))).reshape(h, w, 5)
        moved_rgb = pixels[..., :3].to(self.device).requires_grad_(True)
        loss = k.lambda_sem * (
            1 - F.cosine_similarity(self.features.cls(centre), self.features.cls(moved_rgb), dim=0)
        )
        loss.backward()
        assert moved_rgb.grad is not None
        v_pixels = torch.zeros(h, w, 5)
        v_pixels[..., :3] = moved_rgb.grad.cpu()
        s.backward_at(flat(v_pixels))
        s.apply_adam()
        return float(loss.detach())

    # --- state on the host ---------------------------------------------------------------------
    def _state(self) -> dict[str, Any]:
        """The trained set and its optimiser state, read back (one round trip)."""
        raw = self._session.state()
        out: dict[str, Any] = {"adam_steps": raw.adam_steps}
        for key, arrays in (
            ("params", raw.params), ("exp_avg", raw.exp_avg), ("exp_avg_sq", raw.exp_avg_sq)
        ):
            out[key] = _from_arrays(arrays, self.device)
        for key, values in (
            ("unit", raw.unit), ("grad_accum", raw.grad_accum), ("grad_count", raw.grad_count)
        ):
            out[key] = torch.from_numpy(values).to(self.device)
        return out

    def _upload(
        self,
        g: Gaussians | SpacetimeGaussians,
        unit: torch.Tensor,
        exp_avg: Gaussians | SpacetimeGaussians | None,
        exp_avg_sq: Gaussians | SpacetimeGaussians | None,
        grad_accum: torch.Tensor | None,
        grad_count: torch.Tensor | None,
        adam_steps: int,
    ) -> None:
        self._session.set_trained(
            trained=_arrays(g),
            unit=flat(unit),
            exp_avg=None if exp_avg is None else _arrays(exp_avg),
            exp_avg_sq=None if exp_avg_sq is None else _arrays(exp_avg_sq),
            grad_accum=None if grad_accum is None else flat(grad_accum),
            grad_count=None if grad_count is None else flat(grad_count),
            adam_steps=adam_steps,
        )
        self._session.reserve_frames()

    def result(self) -> TrainedSet:
        return cast(TrainedSet, _from_arrays(self._session.params(), self.device))

    # --- densify and prune ------------------------------------------------------------------
    def densify_and_prune(self) -> None:
        """GaussianTrainer's densify-and-prune on the read-back state; Adam's moments move
        with their Gaussians (survivors keep theirs, split children start at zero), and so
        do a spacetime set's time parameters (children take their parent's)."""
        with torch.no_grad():
            s = self._state()
            trained = s["params"]
            spacetime = isinstance(trained, SpacetimeGaussians)
            d = split_and_prune(
                trained.canonical if spacetime else trained,
                s["unit"],
                s["grad_accum"],
                s["grad_count"],
                self.knobs,
                self.generator,
                self.step,
            )
            self.last_densify = d.stats
            moments = [s[key].map(d.carry) for key in ("exp_avg", "exp_avg_sq")]
            densified = d.with_time(trained) if spacetime else d.gaussians
            self._upload(densified, d.unit, *moments, None, None, s["adam_steps"])

    # --- checkpoints -------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        s = self._state()
        return {
            "resident": True,
            "params": _checkpoint_form(s["params"]),
            "unit": s["unit"].cpu(),
            "exp_avg": _checkpoint_form(s["exp_avg"]),
            "exp_avg_sq": _checkpoint_form(s["exp_avg_sq"]),
            "adam_steps": s["adam_steps"],
            "generator": self.generator.get_state(),
            "step": self.step,
            "grad_accum": s["grad_accum"].cpu(),
            "grad_count": s["grad_count"].cpu(),
            "last_loss": self.last_loss,
        }

    def trained_in(self, state: dict[str, Any]) -> TrainedSet:
        # ``state_dict`` read the parameters back into fresh host tensors of their own.
        return cast(TrainedSet, _from_checkpoint(state["params"]))

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if not state.get("resident"):
            raise ValueError(
                "this checkpoint was written by the torch trainer (GaussianTrainer), not the "
                "resident one; resume it with the trainer that wrote it"
            )
        self._upload(
            _from_checkpoint(state["params"]),
            state["unit"],
            _from_checkpoint(state["exp_avg"]),
            _from_checkpoint(state["exp_avg_sq"]),
            state["grad_accum"],
            state["grad_count"],
            int(state["adam_steps"]),
        )
        self.generator.set_state(state["generator"])
        self.step = int(state["step"])
        self.last_loss = float(state["last_loss"])
