"""The animating phase with the embedded ``flow`` animator: regions, frames, outputs, resume."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from pano4d import metrics
from pano4d.animate.flow import FlowAnimator
from pano4d.animate.pipeline import AnimateError, run_animate
from pano4d.config import ConfigError, Motion, Region, SceneConfig, validate_config
from pano4d.images import read_image, write_image
from pano4d.regions import (
    RegionError,
    active_views,
    angular_velocity_field,
    blend_weight,
    build_regions,
    dilate,
    region_mask,
    region_masks,
    regions_from_masks,
    sphere_distance_px,
)
from pano4d.sphere import dir_to_equirect, view_layout

WIDTH, HEIGHT = 256, 128


def texture(width: int = WIDTH, height: int = HEIGHT, seed: int = 0) -> torch.Tensor:
    """Smooth random colour texture (H, W, 3) in [0, 1], periodic in u (no seam of its own)."""
    gen = torch.Generator().manual_seed(seed)
    fy = torch.fft.fftfreq(height)[:, None]
    fx = torch.fft.rfftfreq(width)[None, :]
    amplitude = (torch.sqrt(fy * fy + fx * fx) * width).clamp(min=2.0) ** -1.6
    channels = []
    for _ in range(3):
        spectrum = torch.complex(
            torch.randn(height, width // 2 + 1, generator=gen),
            torch.randn(height, width // 2 + 1, generator=gen),
        )
        noise = torch.fft.irfft2(spectrum * amplitude, s=(height, width))
        channels.append((noise - noise.mean()) / noise.std())
    return (0.5 + 0.15 * torch.stack(channels, dim=-1)).clamp(0.0, 1.0)


def box_mask(
    u0: float, v0: float, u1: float, v1: float, width: int = WIDTH, height: int = HEIGHT
) -> torch.Tensor:
    region = Region(box=[u0, v0, u1, v1])
    return torch.from_numpy(region_mask(region, width, height))


def animate(
    mask: torch.Tensor,
    motion: Motion,
    frames: int = 6,
    border: int = 2,
    image: torch.Tensor | None = None,
    only: tuple[int, ...] | None = None,
) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """The texture and its frames (all, or the indices in ``only``)."""
    image = texture() if image is None else image
    regions = regions_from_masks([mask], [motion], border)
    animator = FlowAnimator(image, regions, frames, seed=0)
    return image, [animator.frame(t) for t in (only or range(frames))]


# --- regions -----------------------------------------------------------------------------
def test_box_crossing_the_seam_covers_both_ends() -> None:
    mask = box_mask(240, 40, 16, 80)
    assert mask[60, :16].all() and mask[60, 240:].all() and not mask[60, 16:240].any()


def test_distance_wraps_across_the_seam_and_over_the_pole() -> None:
    mask = torch.zeros(HEIGHT, WIDTH, dtype=torch.bool)
    mask[64, 0] = True
    distance = sphere_distance_px(mask, 20.0)
    assert distance[64, WIDTH - 1] == pytest.approx(1.0, abs=0.01)  # across the seam
    assert distance[70, 0] == pytest.approx(6.0)
    top = torch.zeros(HEIGHT, WIDTH, dtype=torch.bool)
    top[0, 10] = True
    distance = sphere_distance_px(top, 20.0)
    # Row 0 half a turn round is one pixel away over the pole; row 2 there is three.
    assert distance[0, 10 + WIDTH // 2] == pytest.approx(1.0, abs=0.05)
    assert distance[2, 10 + WIDTH // 2] == pytest.approx(3.0, abs=0.05)
    assert distance[40, 10] == 20.0  # capped


def test_distance_is_the_exact_separable_transform_away_from_the_poles() -> None:
    # Within 60° of the horizon no row is pooled, so each distance is exactly the least
    # rows² + (columns · cos latitude)² over the True pixels (columns wrapping round the
    # seam), capped.
    gen = torch.Generator().manual_seed(3)
    mask = torch.zeros(HEIGHT, WIDTH, dtype=torch.bool)
    mask[40:88] = torch.rand(48, WIDTH, generator=gen) < 0.01
    mask[60, 250:] = mask[60, :3] = True  # a run across the seam
    cap = 6.5
    distance = sphere_distance_px(mask, cap)[34:94].double()
    rows, cols = torch.nonzero(mask, as_tuple=True)
    j = torch.arange(34, 94)
    spacing = torch.cos(math.pi * (0.5 - (j.double() + 0.5) / HEIGHT))
    across = (torch.arange(WIDTH)[:, None] - cols).abs()
    across = torch.minimum(across, WIDTH - across)  # (W, P)
    squared = (j[:, None, None] - rows).square() + (across * spacing[:, None, None]).square()
    assert torch.allclose(distance, squared.amin(dim=-1).sqrt().clamp(max=cap), atol=1e-4)


def test_dilation_grows_through_seam_and_pole() -> None:
    mask = box_mask(250, 0, 4, 6)  # at the top, across the seam
    grown = dilate(mask, 4.0)
    assert grown[:, 250:].any() and grown[0, 128]  # over the pole to the far side
    assert grown[8, 0] and not grown[20, 0]
    assert (grown | ~mask).all()


def test_blend_weight_is_zero_outside_and_one_deep_inside() -> None:
    mask = box_mask(64, 32, 192, 96)
    weight = blend_weight(mask, 8)
    assert (weight[~mask] == 0).all()
    assert weight[64, 128] == 1.0
    assert 0 < weight[32, 128] < 0.2  # first row inside the box
    assert (weight[mask] > 0).all()
    hard = blend_weight(mask, 0)
    assert torch.equal(hard, mask.float())


def test_motion_hint_field_averages_overlapping_regions() -> None:
    left, right = box_mask(0, 40, 120, 80), box_mask(100, 40, 200, 80)
    east, north = Motion(direction_deg=0, speed=2.0), Motion(direction_deg=90, speed=2.0)
    regions = regions_from_masks([left, right], [east, north], 0)
    field = angular_velocity_field(regions)
    assert torch.allclose(field[:, 60, 10], regions.omegas[0])
    assert torch.allclose(field[:, 60, 150], regions.omegas[1])
    assert torch.allclose(field[:, 60, 110], regions.omegas.mean(dim=0))
    assert (field[:, 10, 10] == 0).all()
    assert float(torch.linalg.norm(regions.omegas[0])) == pytest.approx(math.radians(2.0))
    assert torch.allclose(regions.omegas[0], torch.tensor([0, 0, -math.radians(2.0)]).double())
    assert field.shape == (3, HEIGHT, WIDTH)
    assert angular_velocity_field(regions, 4).shape == (3, HEIGHT // 4, WIDTH // 4)


def test_no_region_is_an_error(tmp_path: Path) -> None:
    black = tmp_path / "black.png"
    write_image(black, np.zeros((HEIGHT, WIDTH, 1), np.float32))
    with pytest.raises(ConfigError, match="no white pixels"):
        region_mask(Region(mask=black), WIDTH, HEIGHT)
    with pytest.raises(RegionError, match="no moving region"):
        region_masks(SceneConfig.model_construct(regions=[]), WIDTH, HEIGHT)
    with pytest.raises(RegionError, match="covers no pixel"):
        sliver = Region(box=[0, 10.2, 9, 10.4])
        region_masks(SceneConfig.model_construct(regions=[sliver]), WIDTH, HEIGHT)
    with pytest.raises(RegionError, match="all black"):
        regions_from_masks([torch.zeros(HEIGHT, WIDTH, dtype=torch.bool)], [Motion()], 4)
    with pytest.raises(RegionError, match="all black"):
        active_views(view_layout(), torch.zeros(HEIGHT, WIDTH, dtype=torch.bool))


def test_active_views_are_the_views_that_see_the_region() -> None:
    cameras = view_layout(20, 80.0, 64)
    mask = box_mask(120, 60, 136, 68)  # around +x, on the horizon
    chosen = active_views(cameras, mask)
    facing = [i for i, c in enumerate(cameras) if float(c.forward[0]) > 0.9]
    assert facing and set(facing) <= set(chosen)
    assert all(float(cameras[i].forward[0]) > 0 for i in chosen)  # none faces away
    assert len(active_views(cameras, torch.ones(HEIGHT, WIDTH, dtype=torch.bool))) == 20


# --- the animator ------------------------------------------------------------------------
def test_static_pixels_are_bit_identical_and_inside_moves() -> None:
    mask = box_mask(40, 30, 140, 90)
    image, frames = animate(mask, Motion(direction_deg=30, speed=2.0))
    for frame in frames:
        assert torch.equal(frame[~mask], image[~mask])
        assert torch.isfinite(frame).all()
    assert (frames[3][mask] - image[mask]).abs().mean() > 0.01
    assert (frames[0] - image).abs().max() < 1e-4  # the loop starts at the input


def test_frames_loop_without_a_jump() -> None:
    mask = box_mask(40, 30, 140, 90)
    _, frames = animate(mask, Motion(direction_deg=0, speed=2.0), frames=8)
    steps = [metrics.mean_abs_difference(a, b, mask) for a, b in itertools.pairwise(frames)]
    loop = metrics.mean_abs_difference(frames[-1], frames[0], mask)
    assert 0.5 * np.mean(steps) < loop < 1.5 * np.mean(steps)


def test_mid_loop_frames_keep_the_texture_contrast() -> None:
    # Mid-loop the two ends are far apart, so their detail is uncorrelated: a plain
    # cross-fade would average it down to 1/√2 (0.6 of the input's here, with the
    # resampling's own blur); the variance-preserving one keeps it (0.8).
    mask = box_mask(16, 24, 240, 104)
    image, frames = animate(mask, Motion(direction_deg=0, speed=3.0), frames=8, only=(4,))
    inner = box_mask(40, 40, 216, 88)

    def detail(x: torch.Tensor) -> torch.Tensor:
        planes = x.permute(2, 0, 1)[None]
        blurred = torch.nn.functional.avg_pool2d(
            planes, 5, stride=1, padding=2, count_include_pad=False
        )
        return (planes - blurred)[0].permute(1, 2, 0)[inner]

    ratio = detail(frames[0]).std(dim=0).mean() / detail(image).std(dim=0).mean()
    assert 0.72 < float(ratio) < 1.0


def test_region_across_the_seam_animates_continuously() -> None:
    mask = box_mask(200, 30, 56, 100)
    image, frames = animate(mask, Motion(direction_deg=0, speed=3.0))
    own = metrics.seam_error(image)
    typical = float((image[30:100, 1:] - image[30:100, :-1]).abs().mean())
    for frame in frames:
        assert metrics.seam_error(frame) <= own + 0.5 * typical
    # The motion carries texture across the seam: columns on both sides change.
    assert (frames[3][30:100, :4] - image[30:100, :4]).abs().mean() > 0.01
    assert (frames[3][30:100, -4:] - image[30:100, -4:]).abs().mean() > 0.01


@pytest.mark.parametrize("direction", [0.0, 90.0])
def test_region_over_a_pole_animates_continuously(direction: float) -> None:
    mask = box_mask(0, 0, WIDTH, 30)  # the whole cap round the zenith
    image, frames = animate(mask, Motion(direction_deg=direction, speed=3.0))
    own = metrics.pole_error(image)
    typical = float((image[:30, 1:] - image[:30, :-1]).abs().mean())
    for frame in frames:
        assert torch.isfinite(frame).all()
        assert metrics.pole_error(frame) <= own + 0.5 * typical
        assert metrics.seam_error(frame) <= metrics.seam_error(image) + 0.5 * typical
    assert (frames[3][:30] - image[:30]).abs().mean() > 0.005


@pytest.mark.parametrize("direction", [0.0, 90.0, 180.0, 270.0, 45.0])
def test_motion_follows_the_hint_direction(direction: float) -> None:
    mask = box_mask(80, 35, 176, 85)
    _, frames = animate(mask, Motion(direction_deg=direction, speed=2.0), only=(1, 2))
    _, du, dv = metrics.region_flow(frames[0], frames[1], mask)
    measured = math.degrees(math.atan2(-dv, du))
    assert abs((measured - direction + 180) % 360 - 180) < 15


def test_speed_scales_the_measured_motion() -> None:
    mask = box_mask(80, 35, 176, 85)
    lengths = []
    for speed in (1.5, 3.0):
        _, frames = animate(mask, Motion(direction_deg=0, speed=speed), only=(1, 2))
        lengths.append(metrics.region_flow(frames[0], frames[1], mask)[0])
    assert lengths[1] / lengths[0] == pytest.approx(2.0, rel=0.2)
    # 1.5°/frame at the horizon is 256 / 240 px; the box spans ±~35° of latitude.
    assert lengths[0] == pytest.approx(WIDTH / 240, rel=0.25)


def test_east_hint_is_a_rotation_about_the_vertical() -> None:
    mask = box_mask(0, 40, WIDTH, 88)
    regions = regions_from_masks([mask], [Motion(direction_deg=0, speed=10.0)], 0)
    animator = FlowAnimator(texture(), regions, 2, seed=0)
    d = torch.tensor([[1.0, 0.0, 0.0]])
    u0, _ = dir_to_equirect(d, WIDTH, HEIGHT)
    u1, v1 = dir_to_equirect(d + animator.velocity(d), WIDTH, HEIGHT)
    assert float(u1 - u0) > 0 and float(v1) == pytest.approx(HEIGHT / 2, abs=0.5)


# --- the phase runner --------------------------------------------------------------------
def scene(tmp_path: Path, frames: int = 4, **animate: object) -> SceneConfig:
    write_image(tmp_path / "panorama.png", texture(512, 256, seed=1).numpy())
    data = {
        "panorama": "panorama.png",
        "regions": [
            {"box": [400, 20, 100, 90], "motion": {"direction_deg": 0.0, "speed": 2.0}},
            {"box": [0, 0, 512, 12], "motion": {"direction_deg": 90.0, "speed": 1.0}},
        ],
        "animate": {"frames": frames, "border_px": 4, **animate},
        "output": "out",
    }
    return validate_config(data, base_dir=tmp_path)


def test_run_animate_writes_frames_video_metrics_and_resumes(tmp_path: Path) -> None:
    cfg = scene(tmp_path)
    result = run_animate(cfg, progress=False)
    assert not result.skipped
    assert [p.name for p in result.store.paths] == ["0000.png", "0001.png", "0002.png", "0003.png"]
    assert result.video.stat().st_size > 0
    assert (result.folder / "done.json").is_file() and (result.folder / "metrics.json").is_file()
    assert result.metrics["static_error"] == 0.0
    assert result.metrics["flicker_static"] == 0.0
    assert result.metrics["nonfinite_frames"] == 0
    assert result.metrics["motion_px_per_frame"] > 0.5

    panorama = read_image(cfg.panorama)
    mask = build_regions(cfg, 512, 256).mask.numpy()
    first = next(result.store.frames())
    assert first.dtype == np.float32 and np.array_equal(first[~mask], panorama[~mask])
    again = metrics.evaluate_frames(result.store.folder, cfg.panorama, mask)
    assert again["static_error"] == 0.0

    written = [p.read_bytes() for p in result.store.paths]
    static = result.store.static_path.stat().st_mtime_ns
    assert run_animate(cfg, progress=False).skipped
    for path in result.store.paths[2:]:
        path.unlink()
    (result.folder / "done.json").unlink()
    resumed = run_animate(cfg, progress=False)
    assert not resumed.skipped and resumed.resumed_at == 2  # not from frame 0
    assert [p.read_bytes() for p in resumed.store.paths] == written
    assert result.store.static_path.stat().st_mtime_ns == static  # written once


def test_a_changed_config_starts_over(tmp_path: Path) -> None:
    run_animate(scene(tmp_path), progress=False)
    frames = tmp_path / "out" / "animate" / "moving"
    (frames / "0003.png").unlink()
    stale = frames / "0001.png"
    before = stale.read_bytes()
    result = run_animate(scene(tmp_path, border_px=6), progress=False)
    assert not result.skipped and stale.read_bytes() != before


def test_svd_backend_without_weights_is_a_clear_error(tmp_path: Path) -> None:
    cfg = scene(tmp_path)
    missing = tmp_path / "no-such-model"
    broken = cfg.model_copy(
        update={"animate": cfg.animate.model_copy(update={"backend": "svd", "weights": missing})}
    )
    with pytest.raises(AnimateError, match="no-such-model"):
        run_animate(broken, progress=False)
