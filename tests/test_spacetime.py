"""Spacetime Gaussians across the extension: ``_core.SpacetimeArrays`` round trips."""

from __future__ import annotations

import pytest
import torch

from pano4d.extension import core, gaussian_arrays, spacetime_arrays, spacetime_from
from pano4d.gaussians import Gaussians, sh_coeffs_for_degree
from pano4d.spacetime import SpacetimeGaussians, TimeModel


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
