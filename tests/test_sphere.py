"""Sphere and camera geometry: docs/design.md's conventions, the shared vectors, the extremes."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from pano4d import sphere
from pano4d.camera import Camera

VECTORS = json.loads((Path(__file__).parent / "vectors" / "geometry.json").read_text())
W, H = 4096, 2048


def seam_distance(a: torch.Tensor, b: torch.Tensor, width: float) -> torch.Tensor:
    d = torch.remainder(a - b, width)
    return torch.minimum(d, width - d)


def test_image_centre_looks_along_x_and_right_is_minus_y() -> None:
    d = sphere.equirect_to_dir(
        torch.tensor(W / 2.0, dtype=torch.float64), torch.tensor(H / 2.0, dtype=torch.float64), W, H
    )
    assert torch.allclose(d, torch.tensor([1.0, 0.0, 0.0], dtype=d.dtype), atol=1e-12)
    right = sphere.equirect_to_dir(
        torch.tensor(3 * W / 4.0, dtype=torch.float64),
        torch.tensor(H / 2.0, dtype=torch.float64),
        W,
        H,
    )
    assert torch.allclose(right, torch.tensor([0.0, -1.0, 0.0], dtype=d.dtype), atol=1e-12)
    top = sphere.equirect_to_dir(torch.tensor(123.0), torch.tensor(0.0), W, H)
    assert top[2] == pytest.approx(1.0)


def test_shared_vectors_equirect() -> None:
    for case in VECTORS["equirect_to_dir"]:
        d = sphere.equirect_to_dir(
            torch.tensor(case["u"], dtype=torch.float64),
            torch.tensor(case["v"], dtype=torch.float64),
            case["width"],
            case["height"],
        )
        assert torch.allclose(d, torch.tensor(case["dir"], dtype=torch.float64), atol=1e-12)
    for case in VECTORS["dir_to_equirect"]:
        u, v = sphere.dir_to_equirect(torch.tensor(case["dir"], dtype=torch.float64), W, H)
        assert 0 <= float(u) < W
        assert float(seam_distance(u, torch.tensor(case["u"], dtype=torch.float64), W)) < 1e-6
        assert float(v) == pytest.approx(case["v"], abs=1e-6)


def test_shared_vectors_cameras() -> None:
    for case in VECTORS["cameras"]:
        cam = Camera.from_fov(
            case["fov_deg"], case["width"], case["height"], case["position"], case["forward"]
        )
        assert torch.allclose(cam.K, torch.tensor(case["K"], dtype=torch.float64))
        assert torch.allclose(
            cam.world_to_cam[:3], torch.tensor(case["world_to_cam"], dtype=torch.float64)
        )
        for p in case["project"]:
            uv, z = cam.project(torch.tensor(p["point"], dtype=torch.float64))
            assert torch.allclose(uv, torch.tensor(p["uv"], dtype=torch.float64), rtol=1e-9)
            assert float(z) == pytest.approx(p["z"])
        for p in case["unproject_ray"]:
            pt = cam.unproject(
                torch.tensor(p["uv"], dtype=torch.float64),
                torch.tensor(p["ray_length"], dtype=torch.float64),
                kind="ray",
            )
            assert float(torch.linalg.norm(pt - cam.position)) == pytest.approx(p["ray_length"])
        again = Camera.from_dict(json.loads(json.dumps(cam.to_dict())))
        assert torch.equal(again.world_to_cam, cam.world_to_cam)
    for layout in VECTORS["view_directions"]:
        got = sphere.view_directions(layout["n"])
        assert torch.allclose(got, torch.tensor(layout["directions"], dtype=torch.float64))


def test_known_point_projects_to_expected_pixel_and_back() -> None:
    cam = Camera.from_fov(90.0, 200, 100, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    uv, z = cam.project(torch.tensor([10.0, -1.0, 1.0], dtype=torch.float64))
    assert uv.tolist() == pytest.approx([110.0, 40.0])
    assert float(z) == pytest.approx(10.0)
    back = cam.unproject(uv, z)
    assert back.tolist() == pytest.approx([10.0, -1.0, 1.0])


def test_no_roll_view_up_is_world_up() -> None:
    for cam in sphere.view_layout():
        down = cam.R[1]
        # The image's down axis has no component along the image's right-world-horizontal.
        assert abs(float(cam.R[0, 2])) < 1e-12  # right axis is horizontal
        assert float(down[2]) <= 0  # image down points downwards in the world


@pytest.mark.parametrize("depth", [0.1, 1.0, 1e4])
@pytest.mark.parametrize("kind", ["z", "ray"])
def test_unproject_project_round_trip(depth: float, kind: str) -> None:
    cam = Camera.from_fov(70.0, 33, 21, (0.5, -1.0, 2.0), (0.3, 0.4, -0.2))
    uv = cam.pixel_grid(torch.float64).reshape(-1, 2)
    d = torch.full((uv.shape[0],), depth, dtype=torch.float64)
    pts = cam.unproject(uv, d, kind=kind)
    uv2, z = cam.project(pts)
    assert torch.allclose(uv2, uv, atol=1e-6)
    if kind == "z":
        assert torch.allclose(z, d, rtol=1e-12)
    else:
        assert torch.allclose(torch.linalg.norm(pts - cam.position, dim=-1), d, rtol=1e-12)


def test_default_layout_covers_the_sphere() -> None:
    cams = sphere.view_layout()
    assert len(cams) == 20
    cov = sphere.coverage(cams, 256, 128)
    assert cov.min_views >= 1
    assert cov.uncovered_fraction == 0.0
    assert cov.overlap.shape == (128, 256)
    # A narrow layout does not cover: the report says so.
    narrow = sphere.coverage(sphere.view_layout(6, 40.0, 64), 256, 128)
    assert narrow.min_views == 0
    assert narrow.uncovered_fraction > 0.3


@pytest.mark.parametrize("f", [1, 2, 3, 7])
def test_icosphere_counts_and_uniformity(f: int) -> None:
    ico = sphere.icosphere(f)
    assert len(ico) == 10 * f * f + 2
    assert torch.allclose(
        torch.linalg.norm(ico.points, dim=-1), torch.ones(len(ico), dtype=torch.float64)
    )
    assert int(ico.lattice.max()) == len(ico) - 1
    assert torch.unique(ico.points, dim=0).shape[0] == len(ico)
    if f >= 3:
        # Near-uniform: nearest-neighbour angles within a factor 1.6 of each other.
        cos = ico.points @ ico.points.T
        cos.fill_diagonal_(-2)
        nn = torch.acos(cos.max(dim=1).values.clamp(-1, 1))
        assert float(nn.max() / nn.min()) < 1.6


def test_icosphere_frequency_meets_target_spacing() -> None:
    f = sphere.icosphere_frequency_for_spacing(2 * math.pi / 4096)
    assert sphere.icosphere_spacing(f) <= 2 * math.pi / 4096
    assert sphere.icosphere_spacing(f - 1) > 2 * math.pi / 4096
    assert 10 * f * f + 2 > 4096 * 2048 / 2  # about one point per equatorial pixel


near_edges = st.sampled_from([0.0, 1e-7, 0.5, W / 2, W - 1e-7, float(W)])
us = st.one_of(near_edges, st.floats(0, W))
vs = st.one_of(st.sampled_from([0.0, 1e-7, H / 2, H - 1e-7, float(H)]), st.floats(0, H))


@settings(max_examples=300, deadline=None)
@given(us, vs)
def test_equirect_round_trip_is_finite_and_continuous(u: float, v: float) -> None:
    d = sphere.equirect_to_dir(
        torch.tensor(u, dtype=torch.float64), torch.tensor(v, dtype=torch.float64), W, H
    )
    assert torch.isfinite(d).all()
    assert float(torch.linalg.norm(d)) == pytest.approx(1.0)
    u2, v2 = sphere.dir_to_equirect(d, W, H)
    assert torch.isfinite(u2) and torch.isfinite(v2)
    assert 0 <= float(u2) < W
    assert float(v2) == pytest.approx(v, abs=1e-6)
    pole = min(v, H - v) < 1e-3
    if not pole:  # at a pole every u is the same point
        assert float(seam_distance(u2, torch.tensor(u, dtype=torch.float64), W)) < 1e-6
    # Continuity across the seam: a step of ε in u is a step of about ε·2π/W on the sphere.
    d2 = sphere.equirect_to_dir(
        torch.tensor(u + 1e-3, dtype=torch.float64), torch.tensor(v, dtype=torch.float64), W, H
    )
    assert float(torch.linalg.norm(d2 - d)) <= 1e-3 * 2 * math.pi / W * 1.0001


@settings(max_examples=200, deadline=None)
@given(
    st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(
        lambda t: sum(x * x for x in t) > 1e-12
    )
)
def test_dir_round_trip(t: tuple[float, float, float]) -> None:
    d = torch.tensor(t, dtype=torch.float64)
    d = d / torch.linalg.norm(d)
    u, v = sphere.dir_to_equirect(d, W, H)
    back = sphere.equirect_to_dir(u, v, W, H)
    assert torch.allclose(back, d, atol=1e-9)


def test_matched_view_size_matches_the_panorama_pixel_at_the_view_centre() -> None:
    # An 80° view spans 910 pixels of a 4096-wide panorama, 228 of a 1024-wide one.
    assert sphere.matched_view_size(4096, 80.0) == 912
    assert sphere.matched_view_size(1024, 80.0) == 224
    assert sphere.matched_view_size(64, 10.0) == 16  # never below one multiple
    # Averaged over the view, one view pixel spans one panorama pixel.
    side = sphere.matched_view_size(4096, 80.0, multiple=1)
    assert math.radians(80.0) / side == pytest.approx(2 * math.pi / 4096, rel=1e-3)
