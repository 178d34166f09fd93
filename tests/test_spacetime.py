"""Spacetime Gaussians: the evaluation's two forms agree, and cross the extension intact.

The reference evaluation is ``SpacetimeGaussians.at`` (torch); the Rust form
(``spacetime.rs``, what the ``.ply4d`` reader evaluates a version-2 file with; the GPU pass
that the trainer and the viewer run is tested against it in Rust, ``spacetime/gpu_set.rs``)
is reached by writing a version-2 file and reading its dynamic set at each integer
timestamp. Both must match the values worked out by hand for the opacity's sign, the wrap
around the loop and the order of the Fourier basis, and each other on random sets.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from pano4d import ply4d
from pano4d.extension import (
    core,
    gaussian_arrays,
    gaussians_from,
    spacetime_arrays,
    spacetime_from,
)
from pano4d.gaussians import Gaussians, sh_coeffs_for_degree
from pano4d.spacetime import SpacetimeGaussians, TimeModel

Evaluation = Callable[[int], Gaussians]


def random_spacetime(n: int, degree: int, model: TimeModel, seed: int) -> SpacetimeGaussians:
    """``n`` random spacetime Gaussians of ``model``: centres anywhere in the loop (and
    beyond it), widths from a tenth of a frame to many periods."""
    gen = torch.Generator().manual_seed(seed)

    def r(*shape: int) -> torch.Tensor:
        return torch.randn(*shape, generator=gen)

    k = sh_coeffs_for_degree(degree)
    canonical = Gaussians(r(n, 3) * 3, r(n, 3), r(n, 4), r(n) * 2, r(n, k, 3))
    return SpacetimeGaussians(
        model,
        canonical,
        time_centre=(torch.rand(n, generator=gen) * 3 - 1) * model.period,
        time_log_width=torch.empty(n).uniform_(-2.3, 6.0, generator=gen),
        colour_terms=r(n, 2 * model.colour_harmonics, 3) * 0.3,
        position_terms=r(n, 2 * model.position_harmonics, 3) * 0.2,
    )


TIME_FIELDS = ("time_centre", "time_log_width", "colour_terms", "position_terms")


def assert_bit_equal_spacetime(a: SpacetimeGaussians, b: SpacetimeGaussians) -> None:
    assert a.model == b.model
    pairs = [(name, a.canonical.tensors()[name], t) for name, t in b.canonical.tensors().items()]
    pairs += [(name, getattr(a, name), getattr(b, name)) for name in TIME_FIELDS]
    for name, ta, tb in pairs:
        assert ta.dtype == tb.dtype == torch.float32, name
        assert ta.shape == tb.shape, name
        assert torch.equal(ta.view(torch.int32), tb.view(torch.int32)), name


# --- the extension's form ------------------------------------------------------------


@pytest.fixture(scope="module")
def built_extension() -> None:
    pytest.importorskip("pano4d._core")


@pytest.mark.usefixtures("built_extension")
@pytest.mark.parametrize(("n", "harmonics"), [(0, (1, 1)), (1, (0, 0)), (57, (3, 2))])
def test_spacetime_arrays_round_trip_bit_exact(n: int, harmonics: tuple[int, int]) -> None:
    s = random_spacetime(n, 2, TimeModel(14, *harmonics), seed=n)
    if n:
        # Values a lossy path would change: subnormal, -0, inf, NaN.
        s.time_centre[0] = 1e-45
        s.time_log_width[0] = -0.0
        s.canonical.opacity_logits[0] = float("inf")
        s.canonical.means[0, 1] = float("nan")
    arrays = spacetime_arrays(s)
    assert len(arrays) == n
    assert (arrays.period, arrays.colour_harmonics, arrays.position_harmonics) == (14, *harmonics)
    assert arrays.colour_terms.shape == (n, 2 * harmonics[0], 3)
    assert_bit_equal_spacetime(spacetime_from(arrays), s)


@pytest.mark.usefixtures("built_extension")
def test_spacetime_arrays_name_what_is_wrong() -> None:
    good = spacetime_arrays(random_spacetime(4, 0, TimeModel(8, 1, 2), seed=0))
    fields = {
        "canonical": good.canonical,
        "period": 8,
        "colour_harmonics": 1,
        "position_harmonics": 2,
        "time_centre": good.time_centre,
        "time_log_width": good.time_log_width,
        "colour_terms": good.colour_terms,
        "position_terms": good.position_terms,
    }
    core.SpacetimeArrays(**fields)  # type: ignore[arg-type]
    wrong = {
        "time_centre": good.time_centre[:3],
        "time_log_width": good.time_log_width[:, None],
        "colour_terms": good.position_terms,
        "position_terms": good.colour_terms,
        "canonical": gaussian_arrays(Gaussians.empty()),
        "period": -1,
        "colour_harmonics": 9,
        "position_harmonics": 2**40,
    }
    for name, value in wrong.items():
        expected = "time_centre" if name == "canonical" else name
        with pytest.raises(ValueError, match=expected):
            core.SpacetimeArrays(**{**fields, name: value})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="period"):
        core.SpacetimeArrays(**{**fields, "period": 0})  # type: ignore[arg-type]


# --- the two forms of the evaluation ---------------------------------------------------


def rust_evaluation(s: SpacetimeGaussians, folder: Path) -> Evaluation:
    """``s`` evaluated by the Rust reader: written as a version-2 file (no static set), its
    dynamic set read back at integer timestamps."""
    pytest.importorskip("pano4d._core")
    path = folder / "twin.ply4d"
    times = [t / 8 for t in range(s.model.period)]
    ply4d.write(path, ply4d.Scene4D(Gaussians.empty(s.canonical.sh_degree), s, times, 8.0))
    reader = core.Ply4dReader(str(path))
    return lambda t: gaussians_from(reader.read_dynamic(t))


def evaluation(form: str, s: SpacetimeGaussians, folder: Path) -> Evaluation:
    return s.at if form == "torch" else rust_evaluation(s, folder)


def assert_close(got: Gaussians, want: Gaussians, what: str) -> None:
    for name, tensor in want.tensors().items():
        torch.testing.assert_close(
            got.tensors()[name], tensor, rtol=1e-5, atol=1e-5,
            msg=lambda m, name=name: f"{what}, {name}: {m}",
        )  # fmt: skip


@pytest.mark.parametrize("form", ["torch", "rust"])
def test_known_values_pin_the_opacity_sign_the_wrap_and_the_basis(
    form: str, tmp_path: Path
) -> None:
    """A loop of 8 frames. Gaussian 0: centre 0, width 1; Gaussian 1: centre 7.5, width 2.
    Both: red + 1·cos, green + 2·sin, z + 3·cos, x + 4·sin (u = 2π·t / 8)."""
    model = TimeModel(period=8, colour_harmonics=1, position_harmonics=1)
    zeros = torch.zeros
    canonical = Gaussians(zeros(2, 3), zeros(2, 3), torch.tensor([[1.0, 0, 0, 0]] * 2),
                          zeros(2), zeros(2, 1, 3))  # fmt: skip
    colour, position = zeros(2, 2, 3), zeros(2, 2, 3)
    colour[:, 0, 0], colour[:, 1, 1] = 1.0, 2.0  # cos₁ of red, sin₁ of green
    position[:, 0, 2], position[:, 1, 0] = 3.0, 4.0  # cos₁ of z, sin₁ of x
    s = SpacetimeGaussians(
        model, canonical, torch.tensor([0.0, 7.5]), torch.tensor([0.0, math.log(2.0)]),
        colour, position,
    )  # fmt: skip
    at = evaluation(form, s, tmp_path)
    # Opacity falls away from the centre time: one frame off at width 1 is −½ (not +½).
    assert at(1).opacity_logits[0] == -0.5
    # Frame 7 is one frame before frame 0 around the loop, not seven after it.
    assert at(7).opacity_logits[0] == -0.5
    # Half a loop away is the farthest: −½·4².
    assert at(4).opacity_logits[0] == -8.0
    # Centre 7.5 is half a frame before frame 0 (the loop's seam): −½·(0.5 / 2)².
    assert at(0).opacity_logits[1] == -0.03125
    # Frame 3 is 3.5 frames after it around the loop, not 4.5 before: −½·(3.5 / 2)².
    assert at(3).opacity_logits[1] == -1.53125
    # cos₁ then sin₁: at frame 0 the cosine terms, a quarter loop on the sine terms.
    torch.testing.assert_close(at(0).sh[0, 0], torch.tensor([1.0, 0.0, 0.0]))
    torch.testing.assert_close(at(0).means[0], torch.tensor([0.0, 0.0, 3.0]))
    torch.testing.assert_close(at(2).sh[0, 0], torch.tensor([0.0, 2.0, 0.0]))
    torch.testing.assert_close(at(2).means[0], torch.tensor([4.0, 0.0, 0.0]))


def extreme_spacetime(model: TimeModel, seed: int) -> SpacetimeGaussians:
    """A random set whose first Gaussians sit at the extremes: centres on the loop's seam
    (half a period from frame 0, either side), on frames 0 and period − 1, a loop or many
    away; widths from e⁻²⁰ frames (present only at its centre) to e³⁰ (always)."""
    s = random_spacetime(200, 1, model, seed)
    p = float(model.period)
    centres = [p / 2, -p / 2, p / 2 + 1e-3, p / 2 - 1e-3, 0.0, p - 1, p, -p, 1e4, -3.5 * p]
    s.time_centre[: len(centres)] = torch.tensor(centres)
    widths = [-20.0, -5.0, -1.0, 0.0, 1.0, 5.0, 10.0, 30.0]
    s.time_log_width[20 : 20 + len(widths)] = torch.tensor(widths)
    s.time_centre[20 : 20 + len(widths)] = p / 2
    return s


MODELS = [TimeModel(1, 0, 0), TimeModel(2, 1, 0), TimeModel(7, 0, 3), TimeModel(14, 2, 1),
          TimeModel(5, 8, 8)]  # fmt: skip


@pytest.mark.parametrize("model", MODELS, ids=str)
def test_the_rust_evaluation_is_the_torch_reference(model: TimeModel, tmp_path: Path) -> None:
    s = extreme_spacetime(model, seed=model.period)
    rust = rust_evaluation(s, tmp_path)
    for t in range(model.period):
        assert_close(rust(t), s.at(t), f"frame {t} of {model}")
    with pytest.raises(ValueError, match="out of range"):
        rust(model.period)


@pytest.mark.parametrize("model", MODELS, ids=str)
def test_the_loop_closes(model: TimeModel) -> None:
    s = extreme_spacetime(model, seed=1)
    p = model.period
    for t in {0, p // 2, p - 1}:
        assert_close(s.at(t + p), s.at(t), f"frame {t} + one loop")
        assert_close(s.at(t - 3 * p), s.at(t), f"frame {t} − three loops")


# --- a tracked set's poses as one set --------------------------------------------------


def tracked_frames(n: int, degree: int, period: int, seed: int) -> list[Gaussians]:
    """``period`` poses of one set of ``n`` Gaussians, as the tracked stage leaves them:
    frame 0's scales, rotations and opacities throughout; means from 0.1 to 10⁴ (the depths
    a panorama holds) moving by up to a percent of their distance, colours by up to 0.3."""
    gen = torch.Generator().manual_seed(seed)

    def r(*shape: int) -> torch.Tensor:
        return torch.randn(*shape, generator=gen)

    k = sh_coeffs_for_degree(degree)
    depth = torch.logspace(-1, 4, n)[:, None]
    first = Gaussians(
        torch.nn.functional.normalize(r(n, 3), dim=-1) * depth, r(n, 3), r(n, 4), r(n), r(n, k, 3)
    )
    return [first] + [
        replace(first, means=first.means + r(n, 3) * 0.01 * depth, sh=first.sh + r(n, k, 3) * 0.3)
        for _ in range(1, period)
    ]


@pytest.mark.parametrize("period", [2, 3, 7, 14, 16])
def test_a_tracked_set_passes_through_every_frame(period: int) -> None:
    # With ⌊period / 2⌋ harmonics the Fourier terms hold any sequence of poses exactly.
    frames = tracked_frames(64, 1, period, seed=period)
    h = period // 2
    one = SpacetimeGaussians.through_frames(TimeModel(period, h, h), frames)
    for t, want in enumerate(frames):
        got = one.at(t)
        scale = want.means.abs().clamp(min=1.0)  # float32 at 10⁴: relative
        assert ((got.means - want.means).abs() / scale).max() < 1e-5, f"means at frame {t}"
        assert (got.sh[:, 0] - want.sh[:, 0]).abs().max() < 1e-5, f"colour at frame {t}"
        for name in ("log_scales", "quats"):
            assert torch.equal(got.tensors()[name], want.tensors()[name]), (name, t)
        # present throughout: the opacity is frame 0's to float32 rounding
        assert (got.opacity_logits - want.opacity_logits).abs().max() < 1e-4, t
    # the higher bands, held constant, are their mean over the frames
    rest = torch.stack([f.sh[:, 1:] for f in frames]).mean(dim=0)
    assert torch.allclose(one.canonical.sh[:, 1:], rest, atol=1e-6)


def test_fewer_harmonics_keep_the_slowest_waves() -> None:
    # A pose sequence of one slow wave and one fast: two harmonics of 14 frames keep the
    # slow one exactly and drop the fast one.
    period, n = 14, 8
    frames = tracked_frames(n, 0, period, seed=3)
    first = frames[0]
    u = [2 * math.pi * t / period for t in range(period)]
    slow = [math.cos(x) for x in u]
    fast = [math.sin(5 * x) for x in u]
    poses = [
        Gaussians(first.means + slow[t] + 0.5 * fast[t], first.log_scales, first.quats,
                  first.opacity_logits, first.sh)
        for t in range(period)
    ]  # fmt: skip
    one = SpacetimeGaussians.through_frames(TimeModel(period, 2, 2), poses)
    for t in range(period):
        want = first.means + slow[t]
        assert ((one.at(t).means - want).abs() / want.abs().clamp(min=1.0)).max() < 1e-5, t


def test_through_frames_names_what_is_wrong() -> None:
    frames = tracked_frames(5, 0, 4, seed=0)
    with pytest.raises(ValueError, match="4 frames make one loop, got 3"):
        SpacetimeGaussians.through_frames(TimeModel(4, 2, 2), frames[:3])
    with pytest.raises(ValueError, match="one set of Gaussians"):
        SpacetimeGaussians.through_frames(TimeModel(4, 2, 2), [*frames[:3], frames[3][:4]])


def test_an_empty_tracked_set_is_an_empty_spacetime_set() -> None:
    empty = tracked_frames(0, 0, 3, seed=0)
    one = SpacetimeGaussians.through_frames(TimeModel(3, 1, 1), empty)
    assert len(one) == 0 and len(one.at(1.5)) == 0
