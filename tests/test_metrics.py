"""pano4d.metrics on inputs whose answers are known."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from pano4d import metrics
from pano4d.images import write_image
from pano4d.resample import equirect_to_perspective
from pano4d.sphere import view_layout

WIDTH, HEIGHT = 256, 128


def smooth_noise(width: int = WIDTH, height: int = HEIGHT, seed: int = 0) -> torch.Tensor:
    """Grey smooth noise (H, W) in [0, 1], periodic in both axes."""
    gen = torch.Generator().manual_seed(seed)
    fy = torch.fft.fftfreq(height)[:, None]
    fx = torch.fft.rfftfreq(width)[None, :]
    amplitude = (torch.sqrt(fy * fy + fx * fx) * width).clamp(min=3.0) ** -1.5
    spectrum = torch.complex(
        torch.randn(height, width // 2 + 1, generator=gen),
        torch.randn(height, width // 2 + 1, generator=gen),
    )
    noise = torch.fft.irfft2(spectrum * amplitude, s=(height, width))
    return (0.5 + 0.15 * (noise - noise.mean()) / noise.std()).clamp(0.0, 1.0)


def colour(grey: torch.Tensor) -> torch.Tensor:
    return torch.stack([grey, 0.8 * grey + 0.1, 1.0 - grey], dim=-1)


@pytest.mark.parametrize(("du", "dv"), [(3, 0), (0, -2), (5, 4), (-9, 2)])
def test_optical_flow_of_a_translation_is_the_translation(du: int, dv: int) -> None:
    image = smooth_noise()
    moved = torch.roll(image, shifts=(dv, du), dims=(0, 1))  # moved(x + d) = image(x)
    flow = metrics.optical_flow(image, moved)[:, 16:-16, 16:-16]
    assert float(flow[0].mean()) == pytest.approx(du, abs=0.1)
    assert float(flow[1].mean()) == pytest.approx(dv, abs=0.1)
    assert float(flow[0].median()) == pytest.approx(du, abs=0.05)


def test_optical_flow_of_a_subpixel_shift() -> None:
    image = smooth_noise(seed=1)[None, None]
    shift = 0.4
    grid_x = (torch.arange(WIDTH) + 0.5 - shift) / WIDTH * 2 - 1
    grid_y = (torch.arange(HEIGHT) + 0.5) / HEIGHT * 2 - 1
    yy, xx = torch.meshgrid(grid_y, grid_x, indexing="ij")
    moved = torch.nn.functional.grid_sample(
        image, torch.stack([xx, yy], -1)[None], align_corners=False, padding_mode="border"
    )
    flow = metrics.optical_flow(image[0, 0], moved[0, 0])[:, 16:-16, 16:-16]
    assert float(flow[0].median()) == pytest.approx(shift, abs=0.05)


def test_region_flow_reports_full_resolution_pixels_and_direction() -> None:
    # 1024 wide is measured at 512: the flow must still come back in full-resolution pixels.
    image = colour(smooth_noise(1024, 512, seed=2))
    moved = torch.roll(image, shifts=(-6, 0), dims=(0, 1))  # 6 px towards the zenith
    mask = torch.zeros(512, 1024, dtype=torch.bool)
    mask[100:400, 200:800] = True
    length, du, dv = metrics.region_flow(image, moved, mask)
    assert length == pytest.approx(6.0, rel=0.1)
    assert dv == pytest.approx(-6.0, rel=0.1) and abs(du) < 0.3


def test_seam_and_pole_errors_on_known_images() -> None:
    periodic = colour(smooth_noise())
    neighbours = float((periodic[:, 1:] - periodic[:, :-1]).abs().mean())
    assert metrics.seam_error(periodic) < 1.5 * neighbours  # the seam is like any column
    cut = periodic.clone()
    cut[:, -1] += 0.25
    assert metrics.seam_error(cut) == pytest.approx(
        float((periodic[:, 0] - cut[:, -1]).abs().mean()), abs=1e-6
    )
    flat_poles = periodic.clone()
    flat_poles[0] = 0.3
    flat_poles[-1] = 0.6
    assert metrics.pole_error(flat_poles) == 0.0
    stripes = flat_poles.clone()
    stripes[0, : WIDTH // 2] = 0.5  # the top row differs by 0.2 from its far side
    assert metrics.pole_error(stripes) == pytest.approx(0.5 * 0.2, abs=1e-6)


def test_static_error_is_zero_only_for_identical_static_pixels() -> None:
    pano = colour(smooth_noise())
    mask = torch.zeros(HEIGHT, WIDTH, dtype=torch.bool)
    mask[40:80, 100:150] = True
    frame = pano.clone()
    frame[mask] = 0.0
    assert metrics.static_error(frame, pano, mask) == 0.0
    frame[5, 5, 1] = torch.nextafter(frame[5, 5, 1], torch.tensor(2.0))
    assert metrics.static_error(frame, pano, mask) > 0.0


def rolling_band(frames: int, step: int) -> tuple[torch.Tensor, torch.Tensor, list[torch.Tensor]]:
    """A panorama whose band of rows 40–88 turns by ``step`` px a frame and loops, since
    frames · step is the width."""
    pano = colour(smooth_noise(seed=3))
    mask = torch.zeros(HEIGHT, WIDTH, dtype=torch.bool)
    mask[40:88] = True
    video = []
    for t in range(frames):
        frame = pano.clone()
        frame[40:88] = torch.roll(pano[40:88], shifts=t * step, dims=1)
        video.append(frame)
    return pano, mask, video


def test_animate_metrics_of_a_known_loop() -> None:
    pano, mask, video = rolling_band(frames=64, step=4)
    result = metrics.animate_metrics(video[:8], pano, mask)
    assert result["frames"] == 8
    assert result["static_error"] == 0.0 and result["flicker_static"] == 0.0
    assert result["motion_px_per_frame"] == pytest.approx(4.0, rel=0.05)
    assert result["motion_deg_per_frame"] == pytest.approx(4.0 * 360 / WIDTH, rel=0.05)
    assert result["motion_direction_deg"] == pytest.approx(0.0, abs=3.0)
    assert result["seam_excess"] < 0.01 and result["nonfinite_frames"] == 0
    # 8 frames of a 64-frame loop: the jump back is 7 ordinary steps (28 px).
    assert result["loop_ratio"] > 1.5
    looped = metrics.animate_metrics(rolling_band(frames=8, step=32)[2], pano, mask)
    assert looped["loop_ratio"] == pytest.approx(1.0, abs=0.2)


def test_animate_metrics_counts_nonfinite_frames_and_needs_two() -> None:
    pano, mask, video = rolling_band(frames=4, step=2)
    video[2] = video[2].clone()
    video[2][50, 50, 0] = float("nan")
    assert metrics.animate_metrics(video, pano, mask)["nonfinite_frames"] == 1
    with pytest.raises(ValueError, match="at least 2 frames"):
        metrics.animate_metrics(video[:1], pano, mask)


def test_evaluate_frames_reads_a_folder(tmp_path: Path) -> None:
    pano, mask, video = rolling_band(frames=4, step=2)
    pano = (pano * 255).round() / 255  # 8-bit values survive a 16-bit PNG exactly
    video = [(f * 255).round() / 255 for f in video]
    for t, frame in enumerate(video):
        write_image(tmp_path / "frames" / f"{t:04d}.png", frame.numpy(), bits=16)
    write_image(tmp_path / "mask.png", mask.float().numpy())
    from_files = metrics.evaluate_frames(tmp_path / "frames", pano.numpy(), tmp_path / "mask.png")
    in_memory = metrics.animate_metrics(video, pano, mask)
    assert from_files["static_error"] == 0.0
    assert from_files == pytest.approx(in_memory, abs=1e-6)
    with pytest.raises(FileNotFoundError, match="no frames"):
        metrics.evaluate_frames(tmp_path, pano, mask)


def test_cross_view_disagreement() -> None:
    cameras = view_layout(20, 80.0, 32)
    flat = torch.full((3, HEIGHT, WIDTH), 0.4)
    views = torch.stack([equirect_to_perspective(flat, c) for c in cameras])
    assert metrics.cross_view_disagreement(views, cameras, width=128) < 1e-6
    pano = colour(smooth_noise()).permute(2, 0, 1)
    views = torch.stack([equirect_to_perspective(pano, c) for c in cameras])
    agreeing = metrics.cross_view_disagreement(views, cameras, width=128)
    views[3] += 0.3  # one view disagrees with its neighbours by 0.3
    disagreeing = metrics.cross_view_disagreement(views, cameras, width=128)
    assert agreeing < 0.02 and disagreeing > agreeing + 0.01
    # Two views that overlap and differ by d: each deviates from their mean by d/2.
    pair = [torch.zeros(1, 32, 32), torch.ones(1, 32, 32)]
    both = [cameras[0], cameras[1]]
    if math.isclose(metrics.cross_view_disagreement(pair, both, 128), 0.0):
        pytest.fail("views 0 and 1 of the layout should overlap")
    assert metrics.cross_view_disagreement(pair, both, 128) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="views for"):
        metrics.cross_view_disagreement(pair, cameras, 128)
