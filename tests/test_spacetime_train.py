"""Spacetime sets (pano4d.spacetime) in the trainers: one dynamic set whose Gaussians have
time parameters, trained on views at several times (a camera once per frame).

The torch trainer is the reference: its evaluation (``SpacetimeGaussians.at``) passes
torch's gradcheck, it trains every time parameter, holds the width floor, densifies with
the time parameters moving with their Gaussians and resumes bit for bit. The resident
trainer (splat-core's evaluate pass, its adjoint and Adam's time groups) follows it: the
adjoint against torch's autograd through ``.at`` on given gradients, one whole step against
the torch trainer's (loss, every parameter's gradient, Adam's update), resume, densification
and the extremes in both. On the wgpu backend (lavapipe in CI)."""

from __future__ import annotations

import math
from typing import Any

import pytest
import torch
from sphere_problem import sphere_problem

from pano4d.extension import gaussian_arrays, spacetime_from
from pano4d.gaussians import Gaussians
from pano4d.lift.densify import split_and_prune
from pano4d.lift.pipeline import make_trainer
from pano4d.lift.resident import ResidentTrainer
from pano4d.lift.torch_trainer import MIN_LOG_WIDTH, GaussianTrainer
from pano4d.lift.trainer import Knobs, TrainViews, learning_rates
from pano4d.renderer import RenderOutput, render
from pano4d.spacetime import MIN_WIDTH_FRAMES, SpacetimeGaussians, TimeModel

pytestmark = pytest.mark.usefixtures("one_torch_thread")

MODEL = TimeModel(period=6, colour_harmonics=2, position_harmonics=1)
TIME_PARAMETERS = ("time_centre", "time_log_width", "colour_terms", "position_terms")


def _render_torch(g: Gaussians, camera: Any, background: Any = None) -> RenderOutput:
    return render(g, camera, background=background, backend="torch")


def _render_wgpu(g: Gaussians, camera: Any, background: Any = None) -> RenderOutput:
    """The resident trainer's rasteriser (the knobs' default mode), for the torch one."""
    return render(g, camera, background=background, backend="wgpu", antialiased=True)


def _with_time(g: Gaussians, seed: int, model: TimeModel = MODEL) -> SpacetimeGaussians:
    """``g`` with random time parameters: centres anywhere in the loop, widths of 1.5 to 6
    frames (each Gaussian fades within the loop), colour waves of up to a tenth of the DC's
    unit and position waves of up to 0.04 (a percent of the sphere problem's radius)."""
    gen = torch.Generator().manual_seed(seed)
    n = len(g)

    def rand(*shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=gen)

    return SpacetimeGaussians(
        model,
        g,
        rand(n) * model.period,
        (1.5 + 4.5 * rand(n)).log(),
        0.1 * (2 * rand(n, 2 * model.colour_harmonics, 3) - 1),
        0.04 * (2 * rand(n, 2 * model.position_harmonics, 3) - 1),
    )


def _problem(
    view_size: int = 12, sh_degree: int = 1, times: tuple[float, ...] = (0.5, 2.0, 3.5, 5.25)
) -> tuple[SpacetimeGaussians, TrainViews]:
    """The sphere problem (tests/sphere_problem.py) as a loop: each of its four cameras once
    per time, its targets tinted by a colour wave of the time, and the Gaussians on it with
    random time parameters."""
    g, views = sphere_problem(view_size, sh_degree)
    cameras, targets = [], []
    for t in times:
        u = 2 * math.pi * t / MODEL.period
        tint = torch.tensor([0.8 + 0.2 * math.cos(u), 0.8 + 0.2 * math.sin(u), 0.9])
        cameras += views.cameras
        targets.append(views.targets * tint)
    k = len(times)
    per_time = [t for t in times for _ in views.cameras]
    return _with_time(g, seed=1), TrainViews(
        cameras,
        torch.cat(targets),
        views.weights.repeat(k, 1, 1),
        views.depth.repeat(k, 1, 1),
        times=per_time,
    )


# --- the evaluation --------------------------------------------------------------------------
def test_the_evaluation_is_differentiable_in_every_parameter() -> None:
    """torch.autograd.gradcheck of SpacetimeGaussians.at in float64 against finite
    differences, in every parameter, at times inside the loop and across its seam (a centre
    at 0 seen at period − 0.5, one at period − 0.25 seen at 0.25)."""
    n = 5
    gen = torch.Generator().manual_seed(0)
    g = Gaussians(
        torch.randn(n, 3, generator=gen, dtype=torch.float64),
        torch.randn(n, 3, generator=gen, dtype=torch.float64),
        torch.randn(n, 4, generator=gen, dtype=torch.float64),
        torch.randn(n, generator=gen, dtype=torch.float64),
        torch.randn(n, 4, 3, generator=gen, dtype=torch.float64),
    )
    s = _with_time(g, seed=2).to(torch.float64)
    s.time_centre[0], s.time_centre[1] = 0.0, MODEL.period - 0.25
    inputs = [*g.tensors().values(), s.time_centre, s.time_log_width, s.colour_terms,
              s.position_terms]  # fmt: skip
    inputs = [t.clone().requires_grad_(True) for t in inputs]

    def evaluate(t: float) -> Any:
        def at(*tensors: torch.Tensor) -> tuple[torch.Tensor, ...]:
            canonical = Gaussians(*tensors[:5])
            drawn = SpacetimeGaussians(MODEL, canonical, *tensors[5:]).at(t)
            return tuple(drawn.tensors().values())

        return at

    for t in (0.0, 1.3, MODEL.period - 0.5, 0.25, 7.9):
        assert torch.autograd.gradcheck(evaluate(t), inputs, eps=1e-6, atol=1e-7), t


# --- the torch trainer -----------------------------------------------------------------------
def test_views_and_times_must_pair_up() -> None:
    s, views = _problem()
    views.times = [0.0]
    with pytest.raises(ValueError, match="16 views with 1 times"):
        GaussianTrainer(s, views, Knobs(iterations=1), _render_torch)


def test_the_torch_trainer_trains_every_time_parameter_and_holds_the_width_floor() -> None:
    """A step draws the set at its view's time and moves every time parameter (finite
    gradients); the result is a spacetime set of the same model. A width below the floor
    is lifted to it, one above it is left free."""
    s, views = _problem()
    s.time_log_width[:4] = math.log(0.5 * MIN_WIDTH_FRAMES)
    s.time_centre[:4] = 0.0  # narrow, centred between the views at 5.25 and 0.5 (the seam)
    knobs = Knobs(iterations=1)
    trainer = GaussianTrainer(s, views, knobs, _render_torch, seed=0)
    trainer.train_step()
    assert trainer.last_time == views.times[trainer.last_view]  # type: ignore[index]
    after = trainer.result()
    assert isinstance(after, SpacetimeGaussians) and after.model == MODEL
    for name in TIME_PARAMETERS:
        moved = (getattr(after, name) - getattr(s, name)).abs()
        assert float(moved.max()) > 0, name
        assert torch.isfinite(trainer.params[name].grad).all(), name  # type: ignore[arg-type]
    assert torch.equal(after.time_log_width[:4], torch.full((4,), MIN_LOG_WIDTH))
    assert bool((after.time_log_width >= MIN_LOG_WIDTH).all())
    free = s.time_log_width > MIN_LOG_WIDTH + 0.1
    assert bool((after.time_log_width[free] != s.time_log_width[free]).any())


def _densify_knobs(n: int, iterations: int = 12) -> Knobs:
    # gradient_scale: every Gaussian a view moves is over the threshold; the budget binds.
    return Knobs(iterations=iterations, lambda_geo=0.05, densify=True, densify_every=4,
                 max_gaussians=n + 10, gradient_scale=1e6)  # fmt: skip


def test_the_torch_trainer_resumes_a_spacetime_set_bit_for_bit() -> None:
    """state_dict after 7 of 12 steps (a densification at step 4 in between), a new trainer,
    load_state_dict, the rest: bit for bit the set of 12 steps in one go, every time
    parameter included. A checkpoint of the other kind of set is refused."""
    s, views = _problem()
    knobs = _densify_knobs(len(s))
    expected = GaussianTrainer(s, views, knobs, _render_torch, seed=3).run()
    first = GaussianTrainer(s, views, knobs, _render_torch, seed=3)
    for _ in range(7):
        first.train_step()
    state = first.state_dict()
    resumed = GaussianTrainer(s, views, knobs, _render_torch, seed=3)
    resumed.load_state_dict(state)
    got = resumed.run()
    assert len(got) == len(expected) > len(s)
    for name in TIME_PARAMETERS:
        assert torch.equal(getattr(got, name), getattr(expected, name)), name
    for name, t in got.canonical.tensors().items():
        assert torch.equal(t, expected.canonical.tensors()[name]), name
    plain = GaussianTrainer(s.canonical, views, knobs, _render_torch, seed=3)
    with pytest.raises(ValueError, match="holds a spacetime set"):
        plain.load_state_dict(state)


def _time_moments(trainer: Any) -> dict[str, dict[str, torch.Tensor]]:
    """Adam's moments of the time parameters in either trainer, by moment and parameter."""
    keys = ("exp_avg", "exp_avg_sq")
    if isinstance(trainer, ResidentTrainer):
        state = trainer._state()
        return {key: {name: getattr(state[key], name) for name in TIME_PARAMETERS}
                for key in keys}  # fmt: skip
    held = trainer.optimiser.state
    return {key: {name: held[trainer.params[name]][key] for name in TIME_PARAMETERS}
            for key in keys}  # fmt: skip


def _statistics(trainer: Any) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Either trainer's offset units and densification statistics."""
    if isinstance(trainer, ResidentTrainer):
        state = trainer._state()
        return state["unit"], state["grad_accum"], state["grad_count"]
    return trainer.unit, trainer.grad_accum, trainer.grad_count


@pytest.mark.parametrize("kind", ["torch", "resident"])
def test_densification_moves_the_time_parameters_with_their_gaussians(kind: str) -> None:
    """One densify-and-prune after 3 steps: decided on the canonical Gaussians (the shared
    split_and_prune, applied exactly); survivors keep their time parameters, split children
    and clones take their parent's; Adam's moments of the time parameters move as the
    others (survivors keep theirs, children start at zero)."""
    s, views = _problem()
    s.canonical.opacity_logits[:3] = -20.0  # transparent: pruned
    knobs = _densify_knobs(len(s), iterations=10).model_copy(update={"densify": False})
    trainer = make_trainer(kind, s, views, knobs, _render_torch, seed=0)
    for _ in range(3):
        trainer.train_step()
    before, moments = trainer.result(), _time_moments(trainer)
    generator = torch.Generator()
    generator.set_state(trainer.generator.get_state())
    decision = split_and_prune(before.canonical, *_statistics(trainer), knobs, generator,
                               trainer.step)  # fmt: skip
    trainer.densify_and_prune()
    after = trainer.result()
    assert bool(decision.child.any()) and len(after) <= knobs.max_gaussians
    for name, t in after.canonical.tensors().items():
        assert torch.equal(t, decision.gaussians.tensors()[name]), name
    for name in TIME_PARAMETERS:
        assert torch.equal(getattr(after, name), getattr(before, name)[decision.source]), name
    carried = _time_moments(trainer)
    for key, by_name in carried.items():
        for name, t in by_name.items():
            old = moments[key][name]
            survivors = ~decision.child
            assert torch.equal(t[survivors], old[decision.source[survivors]]), (key, name)
            assert bool((t[decision.child] == 0).all()), (key, name)
            assert float(old.abs().max()) > 0, (key, name)  # the carried moments are real


def _gradient(trainer: Any) -> dict[str, torch.Tensor]:
    """The last step's gradient of every parameter, in either trainer (the resident one's
    through its adjoint at the parameters after the step)."""
    if isinstance(trainer, ResidentTrainer):
        g = spacetime_from(trainer._session.parameter_gradient())
        return {**g.canonical.tensors(), **{n: getattr(g, n) for n in TIME_PARAMETERS}}
    return {name: p.grad for name, p in trainer.params.items() if p.grad is not None}


@pytest.mark.parametrize("kind", ["torch", "resident"])
def test_extreme_times_and_widths_give_finite_gradients(kind: str) -> None:
    """Centres at the loop's seam seen from both sides of it, widths from a thousandth of a
    frame to a million frames, a view exactly at a Gaussian's centre: every step's loss,
    gradient and parameter stay finite."""
    s, views = _problem(times=(0.0, 0.25, MODEL.period - 0.5))
    n = len(s)
    s.time_centre[: n // 2] = 0.0
    s.time_centre[n // 2 :] = MODEL.period - 0.25
    widths = torch.tensor([1e-3, 0.5, 1.5, 40.0, 1e6])
    s.time_log_width.copy_(widths[torch.arange(n) % len(widths)].log())
    trainer = make_trainer(kind, s, views, Knobs(iterations=12), _render_torch, seed=2)
    for _ in range(12):
        trainer.train_step()
        for name, gradient in _gradient(trainer).items():
            assert torch.isfinite(gradient).all(), name
    assert math.isfinite(trainer.last_loss)  # the resident one's is read at the last step
    after = trainer.result()
    for name in TIME_PARAMETERS:
        assert torch.isfinite(getattr(after, name)).all(), name
    for name, t in after.canonical.tensors().items():
        assert torch.isfinite(t).all(), name
    assert bool((after.time_log_width >= MIN_LOG_WIDTH).all())


# --- the resident trainer against the torch one -------------------------------------------------
def _static_set(g: Gaussians) -> Gaussians:
    """A frozen static set the trained Gaussians interleave with in depth: a copy of ``g``,
    every other one 2 % nearer the views' centre and the rest 2 % farther, half as opaque
    and in other colours (as tests/test_resident_train.py's)."""
    radial = torch.where(torch.arange(len(g)) % 2 == 0, 0.98, 1.02)[:, None]
    return Gaussians(g.means * radial, g.log_scales, g.quats, g.opacity_logits - 1.0,
                     g.sh.flip(-1))  # fmt: skip


def _assert_close(got: torch.Tensor, want: torch.Tensor, tolerance: float, what: str) -> None:
    """Agreement to ``tolerance`` of the reference's largest value (float32 summation
    order: the two sides add the same terms in other orders)."""
    scale = float(want.abs().max())
    assert scale > 0, f"{what}: the reference is zero, the case tests nothing"
    torch.testing.assert_close(got, want, rtol=0, atol=tolerance * scale, msg=what)


def test_the_device_adjoint_is_torchs_autograd_through_the_evaluation() -> None:
    """The resident session's gradient of every trained parameter, for a given gradient of
    the scene it drew (the static set's, then the spacetime set's snapshot's), is torch's
    autograd through SpacetimeGaussians.at at the view's time (which passes gradcheck
    above): inside the loop and across its seam (a third of the centres at 0, seen at
    period − 0.5), widths from the floor to 4 frames. The canonical parameters take the
    snapshot's gradient and the terms a product with the same float32 basis, exactly;
    the centre times and log-widths agree to 2e-6 of their largest value (measured:
    2.5e-7, exp and the order of the products)."""
    s, views = _problem(times=(0.0, 2.2, MODEL.period - 0.5))
    s.time_centre[: len(s) // 3] = 0.0
    static = _static_set(s.canonical)
    session = ResidentTrainer(s, views, Knobs(iterations=1), static=static)._session
    gen = torch.Generator().manual_seed(4)
    for index in (0, 4, 8):  # one view per time
        session.forward_backward(index)  # draws the set at the view's time
        n_all = len(static) + len(s)
        k = s.canonical.sh.shape[1]
        upstream = Gaussians(*(torch.randn(*shape, generator=gen) for shape in (
            (n_all, 3), (n_all, 3), (n_all, 4), (n_all,), (n_all, k, 3))))  # fmt: skip
        got = spacetime_from(session.parameter_gradient(gaussian_arrays(upstream)))
        values = [*s.canonical.tensors().values(), *(getattr(s, n) for n in TIME_PARAMETERS)]
        leaves = [t.clone().requires_grad_(True) for t in values]
        differentiable = SpacetimeGaussians(MODEL, Gaussians(*leaves[:5]), *leaves[5:])
        drawn = differentiable.at(views.time(index))
        snapshot = upstream[len(static) :].tensors()
        total = sum((t * snapshot[name]).sum() for name, t in drawn.tensors().items())
        want = torch.autograd.grad(total, leaves)
        names = [*s.canonical.tensors(), *TIME_PARAMETERS]
        got_by_name = {**got.canonical.tensors(), **{n: getattr(got, n) for n in TIME_PARAMETERS}}
        for name, reference in zip(names, want, strict=True):
            _assert_close(got_by_name[name], reference, 2e-6, f"{name} at {views.time(index)}")


def test_one_step_of_the_resident_trainer_is_the_torch_trainers() -> None:
    """The first step of both trainers on a spacetime set over a frozen static set, views at
    four times (the same view drawn, the same seed), both rendering with the wgpu kernels:
    the loss, every parameter's gradient (the resident one's read back through its adjoint;
    the means' and position terms' as such, the torch trainer's are their offsets'), the
    densification statistic (across the ray to where the step drew each Gaussian) and
    Adam's update, with eight Gaussians starting below the width floor, which both lift to
    exactly ln(MIN_WIDTH_FRAMES) in float32 (the constant mirrored in splat-core agrees).
    Gradients agree to 1e-4 of each parameter's largest (measured: 1.4e-5, the float32
    summation order of the losses and the backward), Adam's moments to 2e-4 (2.8e-5).
    Adam's first step is ±lr per element (m/sqrt(v) after the bias corrections), so where
    a gradient is clearly signed (over 1e-3 of its parameter's largest) the two updates
    agree to 1e-5·lr (measured: 9e-7); where it is rounding noise they may step apart."""
    s, views = _problem(view_size=16)
    s.time_log_width[:8] = math.log(0.5 * MIN_WIDTH_FRAMES)
    static = _static_set(s.canonical)
    knobs = Knobs(iterations=10, lambda_geo=0.05)
    reference = GaussianTrainer(s, views, knobs, _render_wgpu, static=static, seed=3)
    resident = ResidentTrainer(s, views, knobs, static=static, seed=3)
    reference.train_step()
    index = resident.next_view()
    assert index == reference.last_view and resident.last_time == reference.last_time
    session = resident._session
    session.forward_backward(index)
    gradient = spacetime_from(session.parameter_gradient())
    session.apply_adam()
    assert session.loss().total == pytest.approx(reference.last_loss, rel=1e-5)

    p, unit = reference.params, reference.unit
    grads = {name: t.grad for name, t in p.items()}
    assert all(g is not None for g in grads.values())
    want = {
        "means": grads["offsets"] / unit[:, None],  # type: ignore[operator]
        "log_scales": grads["log_scales"],
        "quats": grads["quats"],
        "opacity_logits": grads["opacity_logits"],
        "sh": torch.cat([grads["sh_dc"], grads["sh_rest"]], dim=1),  # type: ignore[list-item]
        "time_centre": grads["time_centre"],
        "time_log_width": grads["time_log_width"],
        "colour_terms": grads["colour_terms"],
        "position_terms": grads["position_terms"] / unit[:, None, None],  # type: ignore[operator]
    }
    got = {**gradient.canonical.tensors(), **{n: getattr(gradient, n) for n in TIME_PARAMETERS}}
    for name, reference_gradient in want.items():
        _assert_close(got[name], reference_gradient, 1e-4, f"gradient of {name}")  # type: ignore[arg-type]
    _, accum, count = _statistics(resident)
    _assert_close(accum, reference.grad_accum, 1e-4, "densification statistic")
    assert torch.equal(count, reference.grad_count)

    before, expected, after = s, reference.result(), resident.result()
    rates = learning_rates(knobs)
    lr = {"means": rates["offsets"] * unit[:, None], "log_scales": rates["log_scales"],
          "quats": rates["quats"], "opacity_logits": rates["opacity_logits"],
          "sh": rates["sh_dc"], "time_centre": rates["time_centre"],
          "time_log_width": rates["time_log_width"], "colour_terms": rates["colour_terms"],
          "position_terms": rates["position_terms"] * unit[:, None, None]}  # fmt: skip

    def tensors(x: SpacetimeGaussians) -> dict[str, torch.Tensor]:
        return {**x.canonical.tensors(), **{n: getattr(x, n) for n in TIME_PARAMETERS}}

    start, moved_torch, moved_device = tensors(before), tensors(expected), tensors(after)
    for name, g in want.items():
        assert g is not None
        signed = g.abs() > 1e-3 * g.abs().max()
        if name == "sh":
            signed[:, 1:] = False  # the higher bands learn at lr / 20: compared below
        step_torch = (moved_torch[name] - start[name])[signed]
        step_device = (moved_device[name] - start[name])[signed]
        rate = torch.as_tensor(lr[name]).expand_as(g)[signed]
        assert bool(signed.any()), name
        torch.testing.assert_close(step_device, step_torch, rtol=0, atol=1e-5 * float(rate.max()),
                                   msg=name)  # fmt: skip
    floor = torch.full((8,), MIN_LOG_WIDTH, dtype=torch.float32)
    assert torch.equal(after.time_log_width[:8], floor)
    assert torch.equal(expected.time_log_width[:8], floor)
    moments = _time_moments(resident), _time_moments(reference)
    for key in ("exp_avg", "exp_avg_sq"):
        for name in TIME_PARAMETERS:
            _assert_close(moments[0][key][name], moments[1][key][name], 2e-4, f"{key} {name}")


def test_the_resident_trainer_resumes_a_spacetime_set() -> None:
    """state_dict after 7 of 12 steps (a densification at step 4 in between), a new trainer,
    load_state_dict, the rest: the set of 12 steps in one go, every time parameter
    included, up to the backward's float-atomic summation order (docs/rasterizer.md,
    "Determinism"; bound 1e-4 as tests/test_resident_train.py's, while a lost piece of
    state moves elements by learning-rate steps). A checkpoint of the other kind of set is
    refused."""
    s, views = _problem()
    knobs = _densify_knobs(len(s))
    expected = ResidentTrainer(s, views, knobs, seed=3).run()
    first = ResidentTrainer(s, views, knobs, seed=3)
    for _ in range(7):
        first.train_step()
    state = first.state_dict()
    resumed = ResidentTrainer(s, views, knobs, seed=3)
    resumed.load_state_dict(state)
    assert resumed.step == 7
    got = resumed.run()
    assert isinstance(got, SpacetimeGaussians) and len(got) == len(expected) > len(s)
    for name in TIME_PARAMETERS:
        assert float((getattr(got, name) - getattr(expected, name)).abs().max()) <= 1e-4, name
    for name, t in got.canonical.tensors().items():
        assert float((t - expected.canonical.tensors()[name]).abs().max()) <= 1e-4, name
    plain = ResidentTrainer(s.canonical, views, knobs, seed=3)
    with pytest.raises(ValueError, match="trains a set of Gaussians, not a spacetime set"):
        plain.load_state_dict(state)
