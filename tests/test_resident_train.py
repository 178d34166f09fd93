"""The resident training loop (splat-core's TrainSession, pano4d.lift.resident) against the
torch trainer it replaces: each loss term's pixel gradient against torch autograd, Adam
against torch.optim.Adam, K steps of both trainers from the same start, resume,
densification's invariants, the semantic loss path and the host traffic of a step.

All on the wgpu backend (lavapipe in CI)."""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
import pytest
import torch
from sphere_problem import sphere_problem

from pano4d.camera import Camera
from pano4d.extension import core, flat, gaussian_arrays, gaussians_from, view
from pano4d.gaussians import Gaussians
from pano4d.lift.densify import screen_gradient, split_and_prune
from pano4d.lift.losses import OUTSIDE_SUMS, ssim_loss
from pano4d.lift.pipeline import make_trainer
from pano4d.lift.random_dinov2 import random_feature_model
from pano4d.lift.resident import ResidentTrainer, train_settings
from pano4d.lift.torch_trainer import GaussianTrainer
from pano4d.lift.trainer import Knobs, TrainViews, learning_rates
from pano4d.renderer import MIN_ALPHA_FOR_DEPTH, RenderOutput, render

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _render(
    g: Gaussians, camera: Camera, background: Any = None, antialiased: bool = True
) -> RenderOutput:
    """The torch trainer's rasteriser, in the knobs' default mode (antialiased) unless told."""
    return render(g, camera, background=background, backend="wgpu", antialiased=antialiased)


# The default knobs' L_rgb mix: (1 − λ_dssim) L1 + λ_dssim D-SSIM.
DSSIM = Knobs(iterations=1).lambda_dssim
L1 = 1 - DSSIM


# --- the loss kernels against torch autograd -------------------------------------------------
def _output(pixels: torch.Tensor) -> RenderOutput:
    """The forward's (h, w, 5) pixels as pano4d.render returns them (depth = D / alpha)."""
    rgb, alpha, accum = pixels[..., :3], pixels[..., 3], pixels[..., 4]
    drawn = alpha > MIN_ALPHA_FOR_DEPTH
    safe = torch.where(drawn, alpha, torch.ones_like(alpha))
    return RenderOutput(rgb, alpha, torch.where(drawn, accum / safe, torch.zeros_like(alpha)))


def _loss_case(h: int, w: int, seed: int, covered: float) -> tuple[TrainViews, torch.Tensor]:
    """One view with random targets, 0/1 and fractional weights (a third of them zero), and
    forward pixels whose alpha exceeds 0.5 on about a ``covered`` fraction."""
    gen = torch.Generator().manual_seed(seed)
    camera = Camera.from_fov(90.0, w, h, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    weight = torch.rand(1, h, w, generator=gen)
    weight[weight < 0.33] = 0.0
    weight[weight > 0.8] = 1.0
    views = TrainViews(
        [camera],
        torch.rand(1, h, w, 3, generator=gen),
        weight,
        torch.rand(1, h, w, generator=gen) * 5 + 1,
        torch.rand(1, h, w, 3, generator=gen),
    )
    pixels = torch.rand(h, w, 5, generator=gen)
    below = torch.rand(h, w, generator=gen) > covered
    pixels[..., 3] = torch.where(below, 0.5 * pixels[..., 3], 0.5 + 0.5 * pixels[..., 3])
    pixels[1, 2, 3] = 0.0  # nothing drawn: depth 0, no gradient through D / alpha
    pixels[..., 4] = pixels[..., 3] * (torch.rand(h, w, generator=gen) * 5 + 1)
    return views, pixels


def _session(views: TrainViews, lambdas: tuple[float, float, float, float]) -> Any:
    """A TrainSession of one dummy Gaussian on ``views`` (its render is never used), with
    the weights of L1, D-SSIM, L_temporal and L_geo set apart (no Knobs sets them so)."""
    g = Gaussians(
        torch.tensor([[0.0, 0.0, 5.0]]),
        torch.zeros(1, 3),
        torch.tensor([[1.0, 0.0, 0.0, 0.0]]),
        torch.zeros(1),
        torch.zeros(1, 1, 3),
    )
    targets = [
        core.ViewTarget(
            view=view(c),
            rgb=flat(views.targets[i]),
            weight=flat(views.weights[i]),
            depth=flat(views.depth[i]),
            previous=None if views.previous is None else flat(views.previous[i]),
            weight_sum=float(views.weights[i].sum().clamp(min=1e-6)),
            outside_sums=[0.0] * len(OUTSIDE_SUMS),
        )
        for i, c in enumerate(views.cameras)
    ]
    defaults = train_settings(Knobs(iterations=1))
    l1, ssim, temporal, geo = lambdas
    settings = core.TrainSettings(
        learning_rates=defaults.learning_rates, betas=defaults.betas, eps=defaults.eps,
        lambda_l1=l1, lambda_ssim=ssim, lambda_temporal=temporal, lambda_geo=geo,
        background=defaults.background, antialiased=defaults.antialiased,
    )  # fmt: skip
    return core.TrainSession(
        static_set=gaussian_arrays(Gaussians.empty(0)),
        trained=gaussian_arrays(g),
        unit=np.ones(1, np.float32),
        views=targets,
        settings=settings,
    )


def _torch_gradient(views: TrainViews, pixels: torch.Tensor, knobs: Knobs) -> torch.Tensor:
    """d loss_at / d pixels, through GaussianTrainer's own loss with ``pixels`` as the render."""
    p = pixels.clone().requires_grad_(True)
    trainer = GaussianTrainer(Gaussians.empty(0), views, knobs, lambda *_: _output(p))
    trainer.loss_at(0).backward()
    assert p.grad is not None
    return p.grad


def _device_gradient(
    views: TrainViews, pixels: torch.Tensor, lambdas: tuple[float, float, float, float]
) -> tuple[torch.Tensor, Any]:
    """The device's pixel gradient and its LossParts."""
    session = _session(views, lambdas)
    out = session.loss_gradient(0, flat(pixels))
    return torch.from_numpy(out.pixel_gradient).reshape(pixels.shape), out.parts


def _assert_close(device: torch.Tensor, reference: torch.Tensor, what: str) -> None:
    """Agreement to float32 summation order: 1e-5 of the largest value (measured: 1e-6)."""
    scale = float(reference.abs().max())
    assert scale > 0, f"{what}: the reference gradient is zero, the case tests nothing"
    torch.testing.assert_close(device, reference, rtol=0, atol=1e-5 * scale, msg=what)
    # The borders: the reflect padding's mirrored taps land on the outer 5 pixels.
    for region in (
        device[:5] - reference[:5],
        device[-5:] - reference[-5:],
        device[:, :5] - reference[:, :5],
        device[:, -5:] - reference[:, -5:],
    ):
        assert float(region.abs().max()) <= 1e-5 * scale, f"{what}: border"  # fmt: skip


@pytest.mark.parametrize("size", [(20, 24), (9, 7)])
def test_each_loss_terms_pixel_gradient_matches_torch_autograd(size: tuple[int, int]) -> None:
    """L1, D-SSIM (kornia, reflect padding; a 5-tap window for the 7-pixel side), L_temporal
    and L_geo (Pearson through depth = D / alpha), each alone, weights with zeros."""
    h, w = size
    views, pixels = _loss_case(h, w, seed=h, covered=0.7)
    rgb_only = Knobs(iterations=1)
    reference_rgb = _torch_gradient(views, pixels, rgb_only)
    p = pixels[..., :3].clone().requires_grad_(True)
    (DSSIM * ssim_loss(p, views.targets[0], views.weights[0])).backward()
    assert p.grad is not None
    reference_ssim = torch.zeros_like(pixels)
    reference_ssim[..., :3] = p.grad
    cases = {
        "ssim": ((0.0, DSSIM, 0.0, 0.0), reference_ssim),
        "l1": ((L1, 0.0, 0.0, 0.0), reference_rgb - reference_ssim),
        "temporal": (
            (0.0, 0.0, 0.1, 0.0),
            _torch_gradient(views, pixels, Knobs(iterations=1, lambda_temporal=0.1))
            - reference_rgb,
        ),
        "geo": (
            (0.0, 0.0, 0.0, 0.05),
            _torch_gradient(views, pixels, Knobs(iterations=1, lambda_geo=0.05)) - reference_rgb,
        ),
    }
    for name, (lambdas, reference) in cases.items():
        device, parts = _device_gradient(views, pixels, lambdas)
        _assert_close(device, reference, name)
    geo = cases["geo"][1]
    assert float(geo[..., 3:].abs().max()) > 0 and float(geo[..., :3].abs().max()) == 0
    # Every term together, with its loss value.
    knobs = Knobs(iterations=1, lambda_temporal=0.1, lambda_geo=0.05)
    device, parts = _device_gradient(views, pixels, (L1, DSSIM, 0.1, 0.05))
    _assert_close(device, _torch_gradient(views, pixels, knobs), "all terms")
    out = _output(pixels)
    trainer = GaussianTrainer(Gaussians.empty(0), views, knobs, lambda *_: out)
    assert parts.total == pytest.approx(float(trainer.loss_at(0)), rel=1e-5)
    assert parts.geo_applied


def test_geo_loss_follows_the_coverage_rule() -> None:
    """L_geo applies only where the covered weight (weight · [alpha > 0.5]) sums past 16:
    below that the device adds no depth gradient, as loss_at adds no term."""
    views, pixels = _loss_case(20, 24, seed=3, covered=0.03)
    covered = float((views.weights[0] * (pixels[..., 3] > 0.5)).sum())
    assert 0 < covered <= 16
    knobs = Knobs(iterations=1, lambda_geo=0.05)
    device, parts = _device_gradient(views, pixels, (L1, DSSIM, 0.0, 0.05))
    reference = _torch_gradient(views, pixels, knobs)
    assert not parts.geo_applied and parts.covered_weight == pytest.approx(covered)
    assert float(device[..., 3:].abs().max()) == 0.0 == float(reference[..., 3:].abs().max())
    _assert_close(device, reference, "rgb terms without L_geo")


# --- Adam ------------------------------------------------------------------------------------
def _gaussians(n: int, sh_degree: int, seed: int) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=gen) + torch.tensor([0.0, 0.0, 6.0])
    k = (sh_degree + 1) ** 2
    return Gaussians(
        means,
        torch.randn(n, 3, generator=gen) * 0.3 - 1.0,
        torch.randn(n, 4, generator=gen),
        torch.randn(n, generator=gen),
        torch.randn(n, k, 3, generator=gen) * 0.3,
    )


def test_adam_matches_torch_adam_with_the_trainers_groups() -> None:
    """Five Adam steps on the device against torch.optim.Adam as GaussianTrainer sets it up
    (per-group learning rates, eps 1e-15, means as offsets in units of the initial depth),
    on gradients spanning three decades and one exact zero. The first step is bit-exact;
    after it, moments and parameters agree to 4 float32 ulps of each group's scale (torch's
    own vector lanes fuse the multiply-adds and its scalar tail does not, so exact equality
    is not defined). The static set is not touched."""
    static, trained = _gaussians(5, 1, seed=0), _gaussians(7, 1, seed=1)
    cam = Camera.from_fov(60.0, 16, 16, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    ones = torch.ones(1, 16, 16)
    views = TrainViews([cam], torch.rand(1, 16, 16, 3), ones, ones)
    knobs = Knobs(iterations=5)
    reference = GaussianTrainer(trained, views, knobs, _render, static=static)
    resident = ResidentTrainer(trained, views, knobs, static=static)
    n_all = len(static) + len(trained)
    norms = torch.zeros(len(trained))
    for step in range(5):
        scale = 10.0 ** -(step % 3)
        grads = _gaussians(n_all, 1, seed=10 + step).map(lambda t, s=scale: t * s)
        grads.opacity_logits[len(static)] = 0.0  # a zero gradient: moments decay, no NaN
        resident._session.apply_gradients(gaussian_arrays(grads))
        g = grads[len(static) :]
        p = reference.params
        p["offsets"].grad = g.means * reference.unit[:, None]  # autograd's d/d offsets
        norms += screen_gradient(p["offsets"].grad, reference.result().means)
        for name in ("log_scales", "quats", "opacity_logits"):
            p[name].grad = getattr(g, name).clone()
        p["sh_dc"].grad, p["sh_rest"].grad = g.sh[:, :1].clone(), g.sh[:, 1:].clone()
        reference.optimiser.step()
    state = resident._state()
    expected = reference.result()
    ulp = torch.finfo(torch.float32).eps
    for name, got in state["params"].tensors().items():
        want = expected.tensors()[name]
        torch.testing.assert_close(got, want, rtol=4 * ulp, atol=4 * ulp * float(want.abs().max()))
    for key, torch_key in (("exp_avg", "exp_avg"), ("exp_avg_sq", "exp_avg_sq")):
        moments = state[key]
        for group in reference.params:
            want = reference.optimiser.state[reference.params[group]][torch_key]
            got = {
                "offsets": moments.means,
                "log_scales": moments.log_scales,
                "quats": moments.quats,
                "opacity_logits": moments.opacity_logits,
                "sh_dc": moments.sh[:, :1],
                "sh_rest": moments.sh[:, 1:],
            }[group]
            scale = float(want.abs().max())
            torch.testing.assert_close(got, want, rtol=4 * ulp, atol=4 * ulp * scale,
                                       msg=f"{key} {group}")  # fmt: skip
    assert state["adam_steps"] == 5
    # Densification's statistics: Σ ‖d/d offsets‖ across the ray and the steps where it was
    # non-zero.
    torch.testing.assert_close(state["grad_accum"], norms, rtol=4 * ulp, atol=0)
    assert torch.equal(state["grad_count"], torch.full((len(trained),), 5.0))
    scene = gaussians_from(resident._session.scene())
    for name, t in scene[: len(static)].tensors().items():
        assert torch.equal(t, static.tensors()[name]), name


# --- whole steps against the torch trainer -------------------------------------------------------
def _problem(sh_degree: int = 1, view_size: int = 24) -> tuple[Gaussians, TrainViews]:
    """Four 24×24 views (by default) of a gradient-coloured sphere and Gaussians on it with random
    orientations and anisotropic scales. (The initial facing discs have a symmetry, the
    rotation about their normal, whose gradient is pure rounding noise; Adam turns noise
    into ±lr steps in either trainer, so their trajectories are not comparable there.)"""
    g, views = sphere_problem(view_size, sh_degree)
    gen = torch.Generator().manual_seed(5)
    g = Gaussians(
        g.means,
        g.log_scales + 0.3 * torch.randn(g.log_scales.shape, generator=gen),
        torch.randn(g.quats.shape, generator=gen),
        g.opacity_logits,
        g.sh + 0.1 * torch.randn(g.sh.shape, generator=gen),
    )
    views.weights[:, :6] = 0.0  # a masked band, as the static stage masks the moving region
    views.previous = (views.targets * 0.9).clamp(0, 1)
    return g, views


STEPS = 20


def _with_static(g: Gaussians) -> tuple[Gaussians, Gaussians]:
    """The dynamic stage in miniature: a frozen static set covers the whole sphere (a copy of
    ``g``, every other one moved 2 % nearer the views' centre and the rest 2 % farther,
    half as opaque and in other colours) and the trained set is ``g``'s upper cap, its
    Gaussians shrunk to a fifth so that they interleave in depth with the static set there
    and reach no tile below: those hold the static set alone, which the device copies from
    its render of the static set."""
    radial = torch.where(torch.arange(len(g)) % 2 == 0, 0.98, 1.02)[:, None]
    static = Gaussians(g.means * radial, g.log_scales, g.quats, g.opacity_logits - 1.0,
                       g.sh.flip(-1))  # fmt: skip
    cap = g[g.means[:, 2] > 0.5 * g.means.norm(dim=-1)]
    return Gaussians(cap.means, cap.log_scales - 1.5, cap.quats, cap.opacity_logits,
                     cap.sh), static  # fmt: skip


@pytest.mark.parametrize("antialiased", [True, False], ids=["antialiased", "classic"])
@pytest.mark.parametrize("with_static", [False, True], ids=["alone", "frozen static set"])
def test_resident_trainer_follows_the_torch_trainer_for_k_steps(
    with_static: bool, antialiased: bool
) -> None:
    """K = 20 steps of both trainers from one start on the same views (same seed), every
    loss term on. Both render with the same wgpu kernels; what differs is float32 summation
    order in the losses (the device's separable tree sums against kornia's convolutions and
    torch's reductions, ~1e-7 relative per pixel gradient) and Adam's rounding (a few ulps).
    Adam normalises each step, so a step's difference is the rounding of the step itself,
    except where a gradient is near zero: there the two trainers' noise can give Adam steps
    of different size (one opacity logit here, by 1.3e-3 = 0.026 lr). Measured per group,
    ‖Δ‖ / ‖movement‖ is ≤ 2e-6 after 1 step, ≤ 5e-4 after 5, ≤ 1.3e-4 after 20 and
    ≤ 7e-5 after 40: the differences do not compound, they stay a small fraction of the
    movement. The tolerance is 1e-3 of the movement and, elementwise, 1e-2 of the largest
    K-step change (K·lr, times the largest unit for means): ≥ 7× the measured figures.
    With a frozen static set in front of and behind the trained Gaussians, the device copies
    the tiles of the static set alone from the static set's render, its backward skips the
    static set's gradients and stops each pixel's walk at its front-most trained Gaussian;
    torch's autograd through every Gaussian, blended everywhere, is the reference. L_temporal
    is off there: its L1 against the previous render changes sign where the two meet, and
    with the static set one Gaussian meets it so closely that the trainers' rounding sends
    its mean apart by 0.016 in 20 steps (with this extension or the one before the frozen
    static set was skipped alike); every other term agrees to 2e-5. Both rasteriser modes:
    the device's session draws in the knobs' mode, the torch trainer in the one given to its
    render function."""
    g, views = _problem(view_size=48 if with_static else 24)  # tiles of the static set alone
    g, static = _with_static(g) if with_static else (g, None)
    knobs = Knobs(iterations=STEPS, lambda_temporal=0.0 if with_static else 0.1,
                  lambda_geo=0.05, antialiased=antialiased)  # fmt: skip
    draw = functools.partial(_render, antialiased=antialiased)
    expected = GaussianTrainer(g, views, knobs, draw, static=static, seed=3).run()
    resident = ResidentTrainer(g, views, knobs, static=static, seed=3)
    got = resident.run()
    assert resident.step == STEPS and math.isfinite(resident.last_loss)
    unit = torch.linalg.norm(g.means, dim=-1).clamp(min=1e-3)
    rates = learning_rates(knobs)
    lr = {"means": rates["offsets"] * float(unit.max()), "log_scales": rates["log_scales"],
          "quats": rates["quats"], "opacity_logits": rates["opacity_logits"],
          "sh": rates["sh_dc"]}  # fmt: skip
    for name, start in g.tensors().items():
        a, b = got.tensors()[name], expected.tensors()[name]
        moved = float((b - start).norm())
        assert moved > 0, name
        assert float((a - b).norm()) <= 1e-3 * moved, name
        assert float((a - b).abs().max()) <= 1e-2 * STEPS * lr[name], name


def test_resident_trainer_resumes_across_a_densification() -> None:
    """state_dict after 7 of 12 steps, a new trainer, load_state_dict, the rest: the same
    Gaussians as 12 steps in one go (densification at step 4), up to the backward's
    float-atomic summation order (docs/rasterizer.md, "Determinism"): three uninterrupted
    runs differ by at most 8.6e-6 in any element on lavapipe, so the bound is 1e-4, while a
    lost piece of state (moments, step count, statistics, generator) moves elements by
    learning-rate steps (≥ 5e-4)."""
    g, views = _problem()
    # gradient_scale: every Gaussian a view moves is over the threshold; the budget binds.
    knobs = Knobs(iterations=12, lambda_geo=0.05, densify=True, densify_every=4,
                  max_gaussians=len(g) + 10, gradient_scale=1e6)  # fmt: skip
    expected = ResidentTrainer(g, views, knobs, seed=3).run()
    first = ResidentTrainer(g, views, knobs, seed=3)
    for _ in range(7):
        first.train_step()
    state = first.state_dict()
    resumed = ResidentTrainer(g, views, knobs, seed=3)
    resumed.load_state_dict(state)
    assert resumed.step == 7
    got = resumed.run()
    assert len(got) > len(g)
    assert len(got) == len(expected)
    for name, tensor in got.tensors().items():
        assert float((tensor - expected.tensors()[name]).abs().max()) <= 1e-4, name
    torch_state = GaussianTrainer(g, views, knobs, _render, seed=3).state_dict()
    with pytest.raises(ValueError, match="torch trainer"):
        resumed.load_state_dict(torch_state)


def _moments(trainer: Any) -> dict[str, Gaussians]:
    """Both trainers' Adam moments as Gaussians-shaped sets (means: the offsets')."""
    if isinstance(trainer, ResidentTrainer):
        s = trainer._state()
        return {"exp_avg": s["exp_avg"], "exp_avg_sq": s["exp_avg_sq"]}
    out = {}
    for key in ("exp_avg", "exp_avg_sq"):
        m = {name: trainer.optimiser.state[p][key] for name, p in trainer.params.items()}
        out[key] = Gaussians(m["offsets"], m["log_scales"], m["quats"], m["opacity_logits"],
                             torch.cat([m["sh_dc"], m["sh_rest"]], dim=1))  # fmt: skip
    return out


def _statistics(trainer: Any) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    if isinstance(trainer, ResidentTrainer):
        s = trainer._state()
        return s["unit"], s["grad_accum"], s["grad_count"]
    return trainer.unit, trainer.grad_accum, trainer.grad_count


@pytest.mark.parametrize("kind", ["resident", "torch"])
def test_densification_keeps_the_invariants_and_carries_the_moments(kind: str) -> None:
    """One densify-and-prune after 3 steps, in both trainers: the shared decision
    (split_and_prune) is applied exactly, transparent Gaussians go, the count stays within
    the budget, nothing is NaN, survivors keep their Adam moments and split children start
    at zero, the step count goes on, the statistics restart and the static set is untouched."""
    g, views = _problem()
    static, trainable = g[: len(g) // 2], g[len(g) // 2 :].map(torch.clone)
    trainable.opacity_logits[:3] = -20.0  # transparent: pruned
    # gradient_scale: every Gaussian a view moves is over the threshold; the budget binds.
    knobs = Knobs(
        iterations=10, lambda_geo=0.05, max_gaussians=len(trainable) + 4, gradient_scale=1e6
    )
    trainer = make_trainer(kind, trainable, views, knobs, _render, static=static, seed=0)
    for _ in range(3):
        trainer.train_step()
    before, moments = trainer.result(), _moments(trainer)
    unit, accum, count = _statistics(trainer)
    generator = torch.Generator()
    generator.set_state(trainer.generator.get_state())
    decision = split_and_prune(before, unit, accum, count, knobs, generator, trainer.step)
    trainer.densify_and_prune()
    assert trainer.last_densify == decision.stats  # what the run's diagnosis records
    after, carried = trainer.result(), _moments(trainer)
    assert bool(decision.child.any()) and bool((~decision.child).any())
    assert len(after) == len(decision.gaussians) <= knobs.max_gaussians
    assert bool((torch.sigmoid(after.opacity_logits) > 0.005).all())
    for name, t in after.tensors().items():
        assert torch.equal(t, decision.gaussians.tensors()[name]), name
    for key in ("exp_avg", "exp_avg_sq"):
        for name, t in carried[key].tensors().items():
            old = moments[key].tensors()[name]
            assert torch.isfinite(t).all(), (key, name)
            survivors = ~decision.child
            assert torch.equal(t[survivors], old[decision.source[survivors]]), (key, name)
            assert bool((t[decision.child] == 0).all()), (key, name)
        assert float(moments[key].means.abs().max()) > 0  # the carried moments are real
    new_unit, new_accum, new_count = _statistics(trainer)
    assert torch.equal(new_unit, decision.unit)
    assert not bool(new_accum.any()) and not bool(new_count.any())
    if isinstance(trainer, ResidentTrainer):
        assert trainer._state()["adam_steps"] == 3
        scene = gaussians_from(trainer._session.scene())
        kept = scene[: len(static)]
    else:
        assert all(float(s["step"]) == 3 for s in trainer.optimiser.state.values())
        assert trainer.static is not None
        kept = trainer.static
    for name, t in kept.tensors().items():
        assert torch.equal(t, static.tensors()[name]), name
    # And densification inside the loop (every 2 steps from 20 % to 50 %).
    knobs = knobs.model_copy(update={"densify": True, "densify_every": 2})
    trainer.knobs = knobs
    trainer.run()
    assert len(trainer.result()) <= knobs.max_gaussians and math.isfinite(trainer.last_loss)


def test_semantic_loss_on_the_resident_path_follows_the_torch_trainer(tmp_path: Any) -> None:
    """With a (tiny, random) DINOv2, L_sem from 54 % of the iterations: the resident trainer
    reads both renders back, runs the feature model in torch and back-propagates the moved
    render's pixel gradient on the device. Its result follows the torch trainer's as closely
    as without L_sem, and differs from a run without it by far more than that."""
    features = random_feature_model(tmp_path, patch_size=6, image_size=24)
    g, views = _problem()
    knobs = Knobs(iterations=8, lambda_sem=1.0, sem_scale=4.0)
    expected = GaussianTrainer(g, views, knobs, _render, features=features, seed=1).run()
    resident = ResidentTrainer(g, views, knobs, features=features, seed=1)
    got = resident.run()
    plain = ResidentTrainer(g, views, knobs, seed=1).run()
    assert math.isfinite(resident.last_loss)
    for name, start in g.tensors().items():
        a, b = got.tensors()[name], expected.tensors()[name]
        moved = float((b - start).norm())
        assert float((a - b).norm()) <= 1e-3 * moved, name
    assert float((got.means - plain.means).norm()) > 0.05 * float((got.means - g.means).norm())


def test_a_step_moves_no_gaussians_between_host_and_device() -> None:
    """Between checkpoints a step uploads only Adam's per-step constants, and the loss (7
    floats) and the renderer's frame check (4 words) are read back at most once every 10
    steps: the session's traffic counter says so."""
    g, views = _problem()
    trainer = ResidentTrainer(g, views, Knobs(iterations=100, lambda_geo=0.05))
    start = trainer._session.traffic()
    steps = 20
    for _ in range(steps):
        trainer.train_step()
    end = trainer._session.traffic()
    uploaded, read_back = end.uploaded - start.uploaded, end.read_back - start.read_back
    assert 0 < uploaded <= 128 * steps
    assert 0 < read_back <= 2 * (7 * 4 + 4 * 4)  # two loss reads, two frame checks
    assert math.isfinite(trainer.last_loss)


# --- the knobs' way to the device -------------------------------------------------------------
def test_scene_yaml_overrides_reach_the_device_session(tmp_path: Any) -> None:
    """A knob set in scene.yaml's ``overrides:`` goes scene.yaml → load_config →
    resolved_preset → trainer_knobs → make_trainer → TrainSettings → the Rust TrainConfig:
    the session's own settings, read back from it, carry the overridden λ_geo, λ_dssim and
    learning rates (f32 on the device), and the knobs left alone keep the preset's values."""
    from pano4d.config import PRESETS, load_config
    from pano4d.images import write_image
    from pano4d.lift.pipeline import trainer_knobs

    write_image(tmp_path / "pano.png", np.zeros((256, 512, 3), np.float32))
    (tmp_path / "scene.yaml").write_text(
        "panorama: pano.png\nregions:\n  - box: [10, 20, 110, 60]\npreset: draft\n"
        "overrides: {lambda_geo: 0.3, lambda_dssim: 0.25, lr_position: 0.004, lr_color: 0.02,"
        " antialiased: false}\n"
    )
    knobs = load_config(tmp_path / "scene.yaml").resolved_preset()
    g, views = _problem()
    stage = trainer_knobs(knobs, 3, 10_000, 2.0, views.cameras, 512)
    trainer = make_trainer("resident", g, views, stage, _render, seed=0)
    got = trainer._session.settings
    f32 = np.float32
    assert got.lambda_geo == f32(0.3) and got.lambda_ssim == f32(0.25)
    assert got.lambda_l1 == f32(1 - 0.25)
    assert got.lambda_temporal == f32(PRESETS["draft"]["lambda_temporal"])
    assert got.learning_rates["offsets"] == 0.004
    assert got.learning_rates["sh_dc"] == 0.02 and got.learning_rates["sh_rest"] == 0.02 / 20
    assert got.learning_rates["quats"] == Knobs(iterations=1).lr_rotation  # left alone
    assert got.betas == pytest.approx((0.9, 0.999)) and got.eps == 1e-15
    assert got.antialiased is False and train_settings(Knobs(iterations=1)).antialiased
    with pytest.raises(ValueError, match="missing"):
        core.TrainSettings(**{**_settings_kwargs(got), "learning_rates": {"offsets": 1.0}})


def _settings_kwargs(settings: Any) -> dict[str, Any]:
    names = ("learning_rates", "betas", "eps", "lambda_l1", "lambda_ssim", "lambda_temporal",
             "lambda_geo", "background", "antialiased")  # fmt: skip
    return {name: getattr(settings, name) for name in names}


# --- the pipeline's default --------------------------------------------------------------------
def test_pano4d_train_runs_the_resident_loop_by_default_and_resumes_only_its_own(
    tmp_path: Any,
) -> None:
    """run_train on wgpu trains with the resident loop (its checkpoints say so); after a kill
    it resumes to the same result as an uninterrupted run; the torch trainer refuses its
    checkpoint with what to do; the resident loop refuses the torch rasteriser."""
    import shutil

    from pano4d import ply4d, synth
    from pano4d.config import load_config
    from pano4d.lift.checkpoints import TrainError
    from pano4d.lift.trainers import trainer_for
    from pano4d.train import run_train

    root = tmp_path / "scene"
    synth.write_scene(root, synth.make_scene(0, 128, 64, 3, views=4, view_size=24))
    tiny = {"view_size": 16, "init_stride": 4, "align_iterations": 20,
            "gaussian_iterations": 12, "max_gaussians": 5000}  # fmt: skip

    def config(name: str) -> Any:
        out = tmp_path / name
        shutil.copytree(root / "gt" / "frames", out / "animate" / "frames")
        cfg = load_config(root / "scene.yaml")
        depth = cfg.depth.model_copy(update={"backend": "file", "path": root / "depth.exr"})
        return cfg.model_copy(update={"overrides": tiny, "output": out, "depth": depth})

    run_train(config("a"), progress=False, checkpoint_every=4)
    cfg = config("b")

    def interrupt(stage: str, step: int) -> None:
        if (stage, step) == ("static", 6):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_train(cfg, progress=False, checkpoint_every=4, on_step=interrupt)
    state = torch.load(cfg.output / "checkpoints" / "static.pt", weights_only=False)
    assert state["trainer_kind"] == "resident" and state["trainer"]["step"] == 4
    with pytest.raises(TrainError, match=r"static\.pt: written by the resident trainer.*--trainer"):
        run_train(cfg, progress=False, checkpoint_every=4, trainer="torch")
    run_train(cfg, progress=False, checkpoint_every=4)
    a, b = ply4d.read(tmp_path / "a" / "scene.ply4d"), ply4d.read(tmp_path / "b" / "scene.ply4d")
    for t in range(a.num_times):
        for name, tensor in a.at(t).tensors().items():
            assert torch.allclose(tensor, b.at(t).tensors()[name], atol=1e-5), (t, name)
    assert trainer_for("torch", None) == "torch" and trainer_for("wgpu", None) == "resident"
    with pytest.raises(ValueError, match="renders with wgpu"):
        trainer_for("torch", "resident")
