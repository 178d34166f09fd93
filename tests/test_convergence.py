"""The stop rule of the lifting optimisations (pano4d.lift.convergence): it stops a loss
curve that has flattened, not one that still falls, whatever view each record saw."""

from __future__ import annotations

import math
import random

import pytest

from pano4d.lift.convergence import Stop, StopRule
from pano4d.lift.diagnosis import LOSS_EVERY


def run(rule: StopRule, curve, views: int = 12, spread: float = 0.6, seed: int = 0) -> Stop:
    """Feed ``rule`` one record every LOSS_EVERY steps of ``curve(step)`` times the difficulty
    of a random view (each view's factor fixed, between 1 − spread/2 and 1 + spread/2), as a
    trainer's records are; where it stops."""
    rng = random.Random(seed)
    difficulty = [1 - spread / 2 + spread * rng.random() for _ in range(views)]
    losses: list[dict[str, float]] = []
    for step in range(LOSS_EVERY, rule.ceiling + LOSS_EVERY, LOSS_EVERY):
        view = rng.randrange(views)
        losses.append({"step": step, "view": view, "total": curve(step) * difficulty[view]})
        stop = rule.check(losses, step)
        if stop is not None:
            return stop
    raise AssertionError("the rule never stopped at its ceiling")


def decay(step: int) -> float:
    return 1.0 + 9.0 * math.exp(-step / 150.0)


def test_a_flat_curve_stops_at_the_floor_whatever_the_views() -> None:
    rule = StopRule.for_count(1000, 500)
    stops = [run(rule, lambda _s: 1.0, seed=seed).step for seed in range(10)]
    assert min(stops) >= rule.floor
    # Two windows of records, then the checks: a flat curve is done within a window more.
    assert max(stops) <= rule.floor + rule.window, stops


def test_a_falling_curve_runs_until_it_flattens() -> None:
    rule = StopRule.for_count(2000, 2000)
    for seed in range(8):
        stop = run(rule, decay, seed=seed).step
        # Where the true curve still falls by more than the tolerance per window, it goes on.
        fall = (decay(stop - rule.window) - decay(stop)) / decay(stop - rule.window)
        assert fall < 2 * rule.tolerance, (seed, stop, fall)
        # And it does not stop while the curve is far from its level (1.0).
        assert decay(stop) < 1.1, (seed, stop)
        assert stop < rule.ceiling, (seed, stop)


def test_a_steady_fall_never_stops_before_the_ceiling() -> None:
    rule = StopRule.for_count(1000, 1000)
    # 5 % per window all the way down: above the tolerance everywhere.
    per_step = math.log(1 - 2.5 * rule.tolerance) / rule.window
    assert run(rule, lambda s: math.exp(per_step * s), spread=0.2).step == rule.ceiling


def test_the_fixed_rule_runs_its_count() -> None:
    rule = StopRule.fixed(300)
    assert run(rule, lambda _s: 1.0) == Stop(300, "count", None)


@pytest.mark.parametrize("count", [1, 10, 100, 2000])
def test_floor_and_window_are_within_the_count(count: int) -> None:
    rule = StopRule.for_count(count, count)
    assert 0 < rule.floor <= count
    assert rule.window >= LOSS_EVERY


def reference_records(level: float, views: int = 12, spread: float = 0.6, seed: int = 0):
    """The earlier timestamp's records: every view once, at ``level`` times its difficulty
    (the same difficulties ``run`` draws for ``seed``)."""
    rng = random.Random(seed)
    difficulty = [1 - spread / 2 + spread * rng.random() for _ in range(views)]
    return [{"step": 10.0 * (v + 1), "view": v, "total": level * d}
            for v, d in enumerate(difficulty)]  # fmt: skip


def test_a_frame_that_barely_changed_costs_a_window() -> None:
    earlier = [reference_records(1.0, seed=seed) for seed in range(10)]
    for seed in range(10):
        rule = StopRule.for_count(1000, 500, [earlier[seed]])
        stop = run(rule, lambda _s: 1.005, seed=seed)
        assert stop.reason == "level" and stop.step <= rule.floor + LOSS_EVERY, (seed, stop)


def test_a_frame_that_changed_runs_until_it_is_back_at_its_level() -> None:
    # Warm-started 40 % above where the earlier timestamp ended, converging back to it.
    for seed in range(10):
        rule = StopRule.for_count(1000, 500, [reference_records(1.0, seed=seed)])
        stop = run(rule, lambda s: 1.0 + 0.4 * math.exp(-s / 60.0), seed=seed).step
        assert 1.0 + 0.4 * math.exp(-stop / 60.0) < 1.0 + 2 * rule.tolerance, (seed, stop)
        assert stop > 100, (seed, stop)


def test_a_frame_fitted_worse_than_the_earlier_ones_is_not_at_its_level() -> None:
    # 15 % above where the earlier timestamp ended and not improving: it stops because the
    # loss stopped falling, never because a window of easy views looked like the old level.
    for seed in range(10):
        rule = StopRule.for_count(1000, 500, [reference_records(1.0, seed=seed)])
        stop = run(rule, lambda _s: 1.15, seed=seed)
        assert stop.reason == "converged", (seed, stop)
