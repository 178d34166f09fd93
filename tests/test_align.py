"""Spatial-temporal depth alignment: planted per-view scales and shifts, extreme depths,
warm-started frames that change only where the scene moves."""

from __future__ import annotations

import pytest
import torch

from pano4d.lift.align import DepthAligner
from pano4d.lift.depth import layout_prior, sample_equirect_depth
from pano4d.sphere import view_layout

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def scene() -> tuple[list, torch.Tensor]:
    cameras = view_layout(20, 80.0, 24)
    truth = layout_prior(128, 64, camera_height=1.6, far=100.0).clamp(max=30.0)
    return cameras, sample_equirect_depth(truth, cameras)


def _planted(views: torch.Tensor, shift_amplitude: float) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(0)
    scales = 1 + 0.3 * (2 * torch.rand(20, generator=g) - 1)
    shifts = shift_amplitude * (2 * torch.rand(20, generator=g) - 1)
    return (views - shifts[:, None, None]) / scales[:, None, None], scales, shifts


def _relative_error(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(((a - b).abs() / b).mean())


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


def test_alignment_with_planted_shifts_still_finds_the_true_depth(scene) -> None:  # type: ignore[no-untyped-def]
    cameras, views = scene
    planted, scales, _ = _planted(views, 0.3)
    aligner = DepthAligner(cameras, iterations=400)
    result = aligner.fit(planted)
    seen = aligner.sphere_to_views(result.log_depth).exp()
    assert _relative_error(seen, views) < 0.03
    # The fitted per-view maps explain the planted depth: scale · Θ + β ≈ the sphere's depth.
    mapped = result.scales()[:, None, None] * planted + aligner.shifts(result, planted)
    assert _relative_error(mapped, seen) < 0.02
    ratio = result.scales() / scales
    assert float((ratio / ratio.median() - 1).abs().median()) < 0.03


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
