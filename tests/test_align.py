"""Spatial-temporal depth alignment: planted per-view scales and shifts come back (up to the
two numbers the data cannot fix), the TV term shapes β, extreme depths stay finite,
warm-started frames change only where the scene moves."""

from __future__ import annotations

import pytest
import torch

from pano4d.lift import align
from pano4d.lift.align import DepthAligner
from pano4d.lift.depth import layout_prior, sample_equirect_depth
from pano4d.sphere import view_layout

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def scene() -> tuple[list, torch.Tensor]:
    cameras = view_layout(20, 80.0, 24)
    truth = layout_prior(128, 64, camera_height=1.6, far=100.0).clamp(max=30.0)
    return cameras, sample_equirect_depth(truth, cameras)


def _near(views: torch.Tensor) -> torch.Tensor:
    """Each view's 10th-percentile depth (n,): the size a shift is measured against."""
    return torch.quantile(views.reshape(len(views), -1), 0.1, dim=1)


def _planted(views: torch.Tensor, shift_amplitude: float) -> tuple[torch.Tensor, ...]:
    """Θ_i = (D − shift_i) / scale_i, so D = scale_i · Θ_i + shift_i; shifts are up to
    ``shift_amplitude`` of each view's near depth (a constant shift of 30 % of the near
    depth changes a floor view's depth ratio, not only its level)."""
    g = torch.Generator().manual_seed(0)
    scales = 1 + 0.3 * (2 * torch.rand(20, generator=g) - 1)
    shifts = shift_amplitude * _near(views) * (2 * torch.rand(20, generator=g) - 1)
    return (views - shifts[:, None, None]) / scales[:, None, None], scales, shifts


def _relative_error(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(((a - b).abs() / b).mean())


def _informative(views: torch.Tensor) -> torch.Tensor:
    """Views whose depth varies by more than 3× across the image. A view that sees one depth
    (the sky at its far clamp) cannot tell a scale from a shift: s·Θ + β is one number there,
    and the scale prior, not the data, picks s. Only the other views' s and β are data."""
    return views.amax(dim=(1, 2)) / views.amin(dim=(1, 2)) > 3.0


def test_alignment_recovers_planted_view_scales(scene) -> None:  # type: ignore[no-untyped-def]
    cameras, views = scene
    planted, scales, _ = _planted(views, 0.0)
    aligner = DepthAligner(cameras, iterations=400)
    result = aligner.fit(planted)
    # Up to the one global scale the views cannot fix, every view's scale comes back.
    ratio = result.scales() / scales
    assert float((ratio / ratio.median() - 1).abs().max()) < 0.06
    seen = aligner.sphere_to_views(result.log_depth).exp()
    naive = aligner.sphere_to_views(aligner.views_to_sphere(planted.log())).exp()
    assert _relative_error(seen, views) < 0.03
    assert _relative_error(naive, views) > 3 * _relative_error(seen, views)


def test_alignment_recovers_planted_shifts_and_scales(scene) -> None:  # type: ignore[no-untyped-def]
    """β and the scales come back from planted per-view shifts and scales.

    Two numbers are beyond the data: a common factor g of every scale, shift and the depth,
    and a common shift μ of every view's β and the depth (D → g·D + μ, s → g·s, β → g·β + μ
    leave every term of L_depth unchanged). They are fitted once from the depths, by least
    squares, and every comparison is made up to them.
    """
    cameras, views = scene
    planted, scales, shifts = _planted(views, 0.3)
    aligner = DepthAligner(cameras, iterations=2000)
    result = aligner.fit(planted)
    seen = aligner.sphere_to_views(result.log_depth).exp()
    basis = torch.stack([views.flatten(), torch.ones(views.numel())], dim=1)
    g, mu = torch.linalg.lstsq(basis, seen.flatten()[:, None]).solution.flatten().tolist()
    assert 0.8 < g < 1.2 and abs(mu) < 0.2, (g, mu)  # the gauge stays near the identity
    assert _relative_error(seen, g * views + mu) < 0.01
    # The fitted per-view maps explain the planted depth: scale · Θ + β ≈ the sphere's depth.
    fitted_shift = aligner.shifts(result, planted)
    mapped = result.scales()[:, None, None] * planted + fitted_shift
    assert _relative_error(mapped, seen) < 0.01
    near = _near(views)
    informative = _informative(views)
    assert int(informative.sum()) >= 8
    # Every informative view's scale, to the one common factor (the max, not a median).
    ratio = (result.scales() / scales)[informative]
    assert float((ratio / g - 1).abs().max()) < 0.02
    # β recovered pixel by pixel: g·shift_i + μ everywhere in every informative view.
    expected = g * shifts + mu
    error = (fitted_shift - expected[:, None, None]).abs().mean(dim=(1, 2)) / near
    assert float(error[informative].max()) < 0.05, error
    # What recovery means here: the planted shifts are far from 0 in these units.
    assert float((expected.abs() / near)[informative].mean()) > 0.1


@pytest.mark.parametrize("tv", [True, False])
def test_tv_term_smooths_a_planted_step_in_beta_away(  # type: ignore[no-untyped-def]
    scene, tv: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One view's Θ carries a two-pixel-wide step up and back down that no other view sees.

    β alone could explain it (β = −s·step there), which is what it does without the TV
    term. With the TV term the step costs more in TV than it saves in L_depth, so β stays
    flat across it and the view's own residual takes the step (the other views hold D).
    """
    measure_tv = align.total_variation
    if not tv:
        monkeypatch.setattr(align, "total_variation", lambda x: x.sum() * 0.0)
    cameras, views = scene
    k = int(torch.nonzero(_informative(views))[0])
    height = float(0.3 * _near(views)[k])
    band = slice(11, 13)
    planted = views.clone()
    planted[k, :, band] += height
    aligner = DepthAligner(cameras, iterations=1000)
    result = aligner.fit(planted)
    shift = aligner.shifts(result, planted)[k]
    outside = torch.cat([shift[:, : band.start], shift[:, band.stop :]], dim=1)
    step = float(outside.mean() - shift[:, band].mean())
    absorbed = step / (float(result.scales()[k]) * height)
    roughness = float(measure_tv(outside)) / height
    if tv:
        assert absorbed < 0.3 and roughness < 0.05, (absorbed, roughness)
    else:
        assert absorbed > 0.5, absorbed


def test_depth_from_0_1_to_1e4_stays_finite() -> None:
    cameras = view_layout(20, 80.0, 12)
    truth = torch.full((32, 64), 50.0)
    truth[:6] = 1e4
    truth[-6:] = 0.1
    views = sample_equirect_depth(truth, cameras)
    aligner = DepthAligner(cameras, iterations=60)
    result = aligner.fit(views)
    assert torch.isfinite(result.log_depth).all()
    depth = aligner.equirect_depth(result, 64, 32)
    assert torch.isfinite(depth).all()
    assert float(depth[-2:].median()) == pytest.approx(0.1, rel=0.05)
    assert float(depth[:2].median()) == pytest.approx(1e4, rel=0.05)
    assert float(depth.min()) > 0.05 and float(depth.max()) < 2e4


def test_later_frames_start_from_the_previous_and_change_only_where_it_moves(scene) -> None:  # type: ignore[no-untyped-def]
    cameras, views = scene
    aligner = DepthAligner(cameras, iterations=40, warm_iterations=20)
    first = aligner.fit(views)
    moving = aligner.ico.points[:, 2] > 0.5  # the sky cap moves in this test
    changed = views * 1.2
    second = aligner.fit(changed, previous=first, moving=moving)
    assert torch.equal(second.log_depth[~moving], first.log_depth[~moving])
    assert not torch.equal(second.log_depth[moving], first.log_depth[moving])
    with pytest.raises(ValueError, match="moving"):
        aligner.fit(changed, previous=first)
    with pytest.raises(ValueError, match="finite and positive"):
        aligner.fit(torch.zeros_like(views))
