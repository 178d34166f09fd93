"""Spacetime sets (pano4d.spacetime) in the trainers: one dynamic set whose Gaussians have
time parameters, trained on views at several times (a camera once per frame).

The torch trainer is the reference: its evaluation (``SpacetimeGaussians.at``) passes
torch's gradcheck, it trains every time parameter, holds the width floor, densifies with
the time parameters moving with their Gaussians and resumes bit for bit."""

from __future__ import annotations

import math
from typing import Any

import pytest
import torch
from sphere_problem import sphere_problem

from pano4d.gaussians import Gaussians
from pano4d.lift.densify import split_and_prune
from pano4d.lift.pipeline import make_trainer
from pano4d.lift.torch_trainer import MIN_LOG_WIDTH, GaussianTrainer
from pano4d.lift.trainer import Knobs, TrainViews
from pano4d.renderer import RenderOutput, render
from pano4d.spacetime import MIN_WIDTH_FRAMES, SpacetimeGaussians, TimeModel

pytestmark = pytest.mark.usefixtures("one_torch_thread")

MODEL = TimeModel(period=6, colour_harmonics=2, position_harmonics=1)
TIME_PARAMETERS = ("time_centre", "time_log_width", "colour_terms", "position_terms")


def _render_torch(g: Gaussians, camera: Any, background: Any = None) -> RenderOutput:
    return render(g, camera, background=background, backend="torch")


def _with_time(g: Gaussians, seed: int, model: TimeModel = MODEL) -> SpacetimeGaussians:
    """``g`` with random time parameters: centres anywhere in the loop, widths of 1.5 to 6
    frames (each Gaussian fades within the loop), colour waves of a tenth of the DC and
    position waves of a percent of the distance."""
    gen = torch.Generator().manual_seed(seed)
    n = len(g)
    rand = lambda *shape: torch.rand(*shape, generator=gen)  # noqa: E731
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
    """A step draws the set at its view's time and moves every parameter, the time ones
    included (each by about its learning rate: Adam's first step); the result is a
    spacetime set of the same model. A width below the floor is lifted to it, one above
    it is left free."""
    s, views = _problem()
    s.time_log_width[:4] = math.log(0.5 * MIN_WIDTH_FRAMES)
    s.time_centre[:4] = 0.0  # narrow, and at the times of the views at 0.5 and 5.25
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
    """Adam's moments of the time parameters, by moment and parameter."""
    state = trainer.optimiser.state
    return {key: {name: state[trainer.params[name]][key] for name in TIME_PARAMETERS}
            for key in ("exp_avg", "exp_avg_sq")}  # fmt: skip


@pytest.mark.parametrize("kind", ["torch"])
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
    decision = split_and_prune(before.canonical, trainer.unit, trainer.grad_accum,
                               trainer.grad_count, knobs, generator, trainer.step)  # fmt: skip
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


@pytest.mark.parametrize("kind", ["torch"])
def test_extreme_times_and_widths_give_finite_gradients(kind: str) -> None:
    """Centres at the loop's seam seen from both sides of it, widths from a thousandth of a
    frame to a million frames, a view exactly at a Gaussian's centre: every step's loss and
    every parameter stay finite."""
    s, views = _problem(times=(0.0, 0.25, MODEL.period - 0.5))
    n = len(s)
    s.time_centre[: n // 2] = 0.0
    s.time_centre[n // 2 :] = MODEL.period - 0.25
    widths = torch.tensor([1e-3, 0.5, 1.5, 40.0, 1e6])
    s.time_log_width.copy_(widths[torch.arange(n) % len(widths)].log())
    trainer = make_trainer(kind, s, views, Knobs(iterations=12), _render_torch, seed=2)
    for _ in range(12):
        assert math.isfinite(trainer.train_step())
    after = trainer.result()
    for name in TIME_PARAMETERS:
        assert torch.isfinite(getattr(after, name)).all(), name
    for name, t in after.canonical.tensors().items():
        assert torch.isfinite(t).all(), name
    assert bool((after.time_log_width >= MIN_LOG_WIDTH).all())
