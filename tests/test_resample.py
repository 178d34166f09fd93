"""Resamplers between equirect images, icosphere points and perspective views."""

from __future__ import annotations

import math

import pytest
import torch

from pano4d import resample, sphere
from pano4d.camera import Camera

W, H = 256, 128


def smooth(d: torch.Tensor) -> torch.Tensor:
    """A smooth function on the sphere: no seam, no pole singularity."""
    return torch.sin(3 * d[..., 0]) * torch.cos(2 * d[..., 1]) + d[..., 2] ** 2 + 0.5 * d[..., 1]


def smooth_image(width: int = W, height: int = H) -> torch.Tensor:
    return smooth(sphere.equirect_directions(width, height, torch.float64))[None].float()


def test_equirect_sampler_reproduces_pixel_centres_exactly() -> None:
    img = torch.rand(3, H, W)
    s = resample.equirect_sampler(sphere.equirect_directions(W, H, torch.float64), W, H)
    assert torch.allclose(s.apply(img), img, atol=1e-6)


def test_equirect_sampler_wraps_the_seam_and_crosses_the_poles() -> None:
    img = torch.zeros(1, H, W)
    img[0, :, 0] = 1.0  # first column
    img[0, 0, W // 2 + 3] = 5.0  # top row, half a turn away from column 3
    # Exactly on the seam (u = 0): half of column 0 and half of column W-1.
    d = sphere.equirect_to_dir(
        torch.tensor(0.0, dtype=torch.float64), torch.tensor(H / 2 + 0.5, dtype=torch.float64), W, H
    )
    s = resample.equirect_sampler(d[None], W, H)
    assert float(s.apply(img)[0, 0]) == pytest.approx(0.5)
    # Above the first row's centre at column 3: half of it comes from across the pole.
    d = sphere.equirect_to_dir(
        torch.tensor(3.5, dtype=torch.float64), torch.tensor(0.25, dtype=torch.float64), W, H
    )
    s = resample.equirect_sampler(d[None], W, H)
    assert float(s.apply(img)[0, 0]) == pytest.approx(0.25 * 5.0)


def test_equirect_sphere_equirect_round_trip() -> None:
    img = smooth_image()
    ico = sphere.icosphere_for_equirect(W)
    values = resample.equirect_to_sphere(img, ico)
    assert float((values[0] - smooth(ico.points)).abs().max()) < 2e-3
    back = resample.sphere_to_equirect(values, ico, W, H)
    err = (back - img).abs()
    assert float(err.max()) < 4e-3
    assert float(err.mean()) < 1e-3


def test_sphere_sampler_is_exact_on_lattice_points_and_linear_inside() -> None:
    ico = sphere.icosphere(6)
    values = torch.randn(2, len(ico))
    s = resample.sphere_sampler(ico.points, ico)
    assert torch.allclose(s.apply(values), values, atol=1e-5)
    # Weights are a partition of unity and non-negative everywhere, poles and seam included.
    dirs = torch.cat(
        [
            sphere.equirect_directions(64, 32, torch.float64).reshape(-1, 3),
            torch.tensor([[0, 0, 1.0], [0, 0, -1.0], [-1.0, 0, 0]], dtype=torch.float64),
        ]
    )
    s = resample.sphere_sampler(dirs, ico)
    assert torch.allclose(s.weight.sum(-1), torch.ones(dirs.shape[0]))
    assert (s.weight >= 0).all()
    assert (s.index >= 0).all()


def test_equirect_perspective_equirect_round_trip() -> None:
    img = smooth_image(512, 256)
    cam = Camera.from_fov(80.0, 256, 256, (0.0, 0.0, 0.0), (0.3, -0.5, 0.4))
    view = resample.equirect_to_perspective(img, cam)
    truth = smooth(cam.world_directions(torch.float64))
    assert float((view[0] - truth).abs().max()) < 2e-3
    back, valid = resample.perspective_to_equirect(view, cam, 512, 256)
    assert 0.05 < float(valid.float().mean()) < 0.3
    assert float((back - img)[0][valid].abs().max()) < 5e-3
    assert float(back[0][~valid].abs().max()) == 0.0


@pytest.mark.parametrize("builder", ["equirect", "sphere", "perspective"])
def test_adjoint_is_the_transpose(builder: str) -> None:
    gen = torch.Generator().manual_seed(0)
    dirs = torch.nn.functional.normalize(
        torch.randn(500, 3, generator=gen, dtype=torch.float64), dim=-1
    )
    if builder == "equirect":
        s = resample.equirect_sampler(dirs, 32, 16)
    elif builder == "sphere":
        s = resample.sphere_sampler(dirs, sphere.icosphere(4))
    else:
        s = resample.perspective_sampler(dirs, Camera.from_fov(100.0, 24, 20))
    x = torch.randn(3, *s.source_shape, generator=gen, dtype=torch.float64)
    y = torch.randn(3, *s.target_shape, generator=gen, dtype=torch.float64)
    lhs = (s.apply(x.float()).double() * y).sum()
    rhs = (x * s.adjoint(y.float()).double()).sum()
    assert float(lhs) == pytest.approx(float(rhs), rel=1e-4)


def test_fusion_of_overlapping_views_recovers_the_signal() -> None:
    """adjoint(values) / adjoint(ones) over all views: the closed-form fusion."""
    ico = sphere.icosphere(12)
    truth = smooth(ico.points).float()
    num = torch.zeros(len(ico))
    den = torch.zeros(len(ico))
    for cam in sphere.view_layout(20, 80.0, 48):
        s = resample.sphere_sampler(cam.world_directions(torch.float64), ico)
        view = s.apply(truth)
        num += s.adjoint(view)
        den += s.coverage_weight()
    fused = num / den.clamp(min=1e-12)
    assert (den > 0).all()
    assert float((fused - truth).abs().max()) < 0.05


def test_float16_matches_float32() -> None:
    img = smooth_image()
    ico = sphere.icosphere(20)
    s = resample.equirect_sampler(ico.points, W, H)
    a = s.apply(img)
    b = s.apply(img.half())
    assert b.dtype == torch.float16
    assert torch.isfinite(b).all()
    assert float((a - b.float()).abs().max()) < 2e-3
    adj = s.adjoint(b)
    assert adj.dtype == torch.float16 and torch.isfinite(adj).all()


def test_wrong_source_shape_is_a_clear_error() -> None:
    s = resample.equirect_sampler(sphere.icosphere(2).points, W, H)
    with pytest.raises(ValueError, match="trailing shape"):
        s.apply(torch.zeros(3, H, W + 1))


def test_continuity_across_the_seam_and_at_the_poles() -> None:
    """Sampling a smooth image just either side of the seam or a pole gives nearby values."""
    img = smooth_image()
    eps = 1e-7
    pairs = torch.tensor([
        [eps, 40.0], [W - eps, 40.0],        # seam
        [10.0, eps], [10.0 + W / 2, eps],     # across the north pole
        [7.0, H - eps], [7.0 + W / 2, H - eps],  # across the south pole
    ], dtype=torch.float64)  # fmt: skip
    d = sphere.equirect_to_dir(pairs[:, 0], pairs[:, 1], W, H)
    vals = resample.equirect_sampler(d, W, H).apply(img)[0]
    for a, b in ((0, 1), (2, 3), (4, 5)):
        assert float(abs(vals[a] - vals[b])) < 1e-3 * (1 + math.pi)
