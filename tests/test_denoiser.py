"""The Panoramic Denoiser (pano4d.animate): noise on the sphere, project/fuse, the SVD
backend on a tiny random model loaded by path, tiled decoding, and the composite."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch

from pano4d.animate.decode import tiled_equirect
from pano4d.animate.denoiser import PanoramicDenoiser, SphereLatent, euler_step, latent_cameras
from pano4d.animate.noise import build_footprints, footprints_for_views, sphere_white_noise
from pano4d.camera import Camera
from pano4d.config import validate_config
from pano4d.images import read_image
from pano4d.resample import sphere_sampler
from pano4d.sphere import (
    equirect_directions,
    icosphere,
    icosphere_frequency_for_spacing,
    view_layout,
)

FRAMES, STEPS = 3, 2


# --- noise ---------------------------------------------------------------------------------
def _neighbour_correlation(x: torch.Tensor) -> tuple[float, float]:
    """Correlation of horizontally and vertically adjacent pixels of (..., h, w)."""
    x = x - x.mean()
    var = float(x.square().mean())
    horizontal = float((x[..., :, 1:] * x[..., :, :-1]).mean()) / var
    vertical = float((x[..., 1:, :] * x[..., :-1, :]).mean()) / var
    return horizontal, vertical


def test_noise_in_every_view_is_unit_variance_and_white() -> None:
    cameras = view_layout(20, 80.0, 24)
    ico, footprints = footprints_for_views(cameras)
    noise = sphere_white_noise(len(ico), (64,), torch.Generator().manual_seed(1))
    views = footprints.project_white(noise)  # (20, 64, 24, 24)
    n = views[0].numel()
    for k, view in enumerate(views):
        assert abs(float(view.mean())) < 4 / math.sqrt(n), k
        assert abs(float(view.var()) - 1.0) < 4 * math.sqrt(2 / n), k
        for corr in _neighbour_correlation(view):
            assert abs(corr) < 4 / math.sqrt(n), k
    # The test can fail: interpolating white noise from points as dense as the pixels
    # (barycentric, as a plain resampler would) gives neither.
    coarse = icosphere(icosphere_frequency_for_spacing(1.0 / cameras[0].fx))
    points = sphere_white_noise(len(coarse), (64,), torch.Generator().manual_seed(1))
    bilinear = sphere_sampler(cameras[0].world_directions(torch.float64), coarse).apply(points)
    assert float(bilinear.var()) < 0.8
    assert min(_neighbour_correlation(bilinear)) > 0.2


def test_overlapping_views_draw_the_same_noise() -> None:
    """Two views share sphere points, so their noise agrees where they overlap."""
    a = Camera.from_fov(60.0, 16, 16, forward=(1.0, 0.0, 0.0))
    b = Camera.from_fov(60.0, 16, 16, forward=(1.0, -0.3, 0.0))  # 17° to the right
    ico, footprints = footprints_for_views([a, b])
    noise = sphere_white_noise(len(ico), (32,), torch.Generator().manual_seed(2))
    views = footprints.project_white(noise)
    # Pixels of b whose centre falls in a's image: read a there by nearest pixel.
    uv, z = a.project(b.world_directions(torch.float64))
    inside = (z > 0) & (uv[..., 0] >= 0) & (uv[..., 0] < 16) & (uv[..., 1] >= 0) & (uv[..., 1] < 16)
    col, row = uv[..., 0].floor().long().clamp(0, 15), uv[..., 1].floor().long().clamp(0, 15)
    in_a = views[0][:, row[inside], col[inside]]
    in_b = views[1][:, inside]
    corr = float((in_a * in_b).mean() / (in_a.std() * in_b.std()))
    assert corr > 0.5
    far = views[1][:, ~inside]
    assert abs(float(views[0][:, :4, :4].mean() * far.mean())) < 0.2


# --- project and fuse ---------------------------------------------------------------------
def test_fuse_is_the_window_weighted_mean_and_exact_for_one_view() -> None:
    a = Camera.from_fov(70.0, 12, 12, forward=(1.0, 0.0, 0.0))
    b = Camera.from_fov(70.0, 12, 12, forward=(1.0, -0.5, 0.2))
    ico, footprints = footprints_for_views([a, b])
    images = torch.randn(2, 5, 12, 12, generator=torch.Generator().manual_seed(3))
    fused, seen = footprints.fuse(images)
    # Hand-computed at every point both views see.
    value = torch.zeros(2, 5, len(ico))
    weight = torch.zeros(2, len(ico))
    for k in range(2):
        entries = slice(footprints.offsets[k], footprints.offsets[k + 1])
        point = footprints.point[entries]
        pixel = footprints.pixel[entries] - k * 144
        value[k][:, point] = images[k].reshape(5, -1)[:, pixel]
        weight[k][point] = footprints.window[entries]
    both = (weight > 0).all(dim=0)
    assert int(both.sum()) > 50
    expected = (value * weight[:, None]).sum(0) / weight.sum(0).clamp(min=1e-12)
    torch.testing.assert_close(fused[:, both], expected[:, both])
    assert torch.equal(seen, (weight > 0).any(dim=0))
    # The two views disagree before fusion; after it, one value per point.
    assert float((value[0] - value[1])[:, both].abs().mean()) > 0.5
    # One view: project(fuse(x)) is x, so a lone view is denoised as if on its own grid.
    single = build_footprints([a], ico)
    fused_a, _ = single.fuse(images[:1])
    torch.testing.assert_close(single.project_mean(fused_a), images[:1], rtol=1e-6, atol=1e-6)


def test_euler_step_matches_diffusers_scheduler() -> None:
    from diffusers import EulerDiscreteScheduler

    from pano4d.animate.svd import SVD_SCHEDULER

    scheduler = EulerDiscreteScheduler(**SVD_SCHEDULER)
    scheduler.set_timesteps(5)
    gen = torch.Generator().manual_seed(4)
    noise, signal = torch.randn(2, 3, 50, generator=gen), torch.randn(2, 3, 50, generator=gen)
    state = SphereLatent(signal, noise, 3.0)
    x = signal + 3.0 * noise
    for i, t in enumerate(scheduler.timesteps):
        x0 = torch.randn(2, 3, 50, generator=gen)
        sigma = float(scheduler.sigmas[i])
        # The model output that makes the scheduler's v-prediction equal x0.
        v = (x / (sigma**2 + 1) - x0) * math.sqrt(sigma**2 + 1) / sigma
        x = scheduler.step(v, t, x).prev_sample
        state = euler_step(state, x0, sigma, float(scheduler.sigmas[i + 1]))
        torch.testing.assert_close(
            state.signal + state.noise_scale * state.noise, x, rtol=1e-4, atol=1e-4
        )


# --- a smooth fake Φ: seams, poles, agreement after fusion ----------------------------------
def _smooth_field(dirs: torch.Tensor) -> torch.Tensor:
    """A smooth function (2, ...) of direction."""
    x, y, z = dirs.unbind(-1)
    return torch.stack([x + 0.5 * y * z, torch.sin(2 * y) + z * z]).float()


@dataclass
class _TargetCondition:
    targets: torch.Tensor  # (B, c, h, w)

    def select(self, views: slice) -> _TargetCondition:
        return _TargetCondition(self.targets[views])


class _SmoothDenoiser:
    """Predicts a smooth field of direction plus a per-view offset, whatever the input."""

    latent_channels, scale_factor, size_multiple = 2, 1, 1
    device, dtype = torch.device("cpu"), torch.float32

    def schedule(self, steps: int) -> tuple[torch.Tensor, float]:
        return torch.tensor([10.0, 1.0, 0.0], dtype=torch.float64)[: steps + 1], 10.0

    def predict_x0(
        self, latents: torch.Tensor, sigma: float, cond: _TargetCondition
    ) -> torch.Tensor:
        return cond.targets[:, None].expand(-1, latents.shape[1], -1, -1, -1).clone()


def test_fused_latent_is_continuous_across_the_seam_and_at_the_poles() -> None:
    cameras = view_layout(20, 80.0, 16)
    ico, footprints = footprints_for_views(cameras)
    offsets = 0.05 * torch.randn(20, generator=torch.Generator().manual_seed(5))
    targets = torch.stack(
        [
            _smooth_field(c.world_directions(torch.float64)) + o
            for c, o in zip(cameras, offsets, strict=True)
        ]
    )
    seen_steps: list[tuple[torch.Tensor, list[torch.Tensor]]] = []
    denoiser = PanoramicDenoiser(_SmoothDenoiser(), footprints, view_batch=7)
    signal = denoiser.sample(
        _TargetCondition(targets),
        torch.zeros(2, len(ico)),
        frames=2,
        steps=2,
        seed=0,
        on_fuse=lambda fused, views: seen_steps.append((fused, views)),
    )
    assert [r.unet_calls for r in denoiser.reports] == [3, 3]
    assert all(r.disagreement > 0.01 for r in denoiser.reports)
    # Every point is seen, and the last step lands on the fused prediction.
    torch.testing.assert_close(signal, seen_steps[-1][0])
    grid = sphere_sampler(equirect_directions(128, 64, torch.float64), ico).apply(signal[0])
    steps_h = (grid[..., 1:] - grid[..., :-1]).abs().mean(dim=(0, 1))
    seam = (grid[..., 0] - grid[..., -1]).abs().mean()
    assert seam < 2 * steps_h.mean()
    # At the poles a row shrinks to a point: its values spread no more than between rows.
    rows_v = (grid[:, 1:] - grid[:, :-1]).abs().mean()
    for row in (0, -1):
        spread = (grid[:, row] - grid[:, row].mean(dim=-1, keepdim=True)).abs().mean()
        assert spread < 2 * rows_v
    # The reported disagreement is the window-weighted spread of the views, by hand.
    fused, views = seen_steps[0]
    stacked = torch.cat(views)
    mean_sq, _ = footprints.fuse(stacked.square())
    multi = torch.bincount(footprints.point, minlength=len(ico)) > 1
    spread = (mean_sq - fused.square())[..., multi].clamp(min=0).mean().sqrt()
    assert denoiser.reports[0].disagreement == pytest.approx(float(spread), rel=1e-4)


# --- tiled decoding -----------------------------------------------------------------------
def _blur(x: torch.Tensor) -> torch.Tensor:
    return torch.nn.functional.avg_pool2d(x, 5, stride=1, padding=2, count_include_pad=False)


@pytest.mark.parametrize("tile", [7, 16, 200])
def test_tiles_reproduce_a_local_operator_across_seam_and_poles(tile: int) -> None:
    grid = torch.randn(2, 3, 32, 64, generator=torch.Generator().manual_seed(6))
    # The whole-image reference: pad over the poles (half a turn round), wrap the seam.
    top = torch.roll(torch.flip(grid[..., :4, :], [-2]), 32, dims=-1)
    bottom = torch.roll(torch.flip(grid[..., -4:, :], [-2]), 32, dims=-1)
    padded = torch.cat([top, grid, bottom], dim=-2)
    padded = torch.cat([padded[..., -4:], padded, padded[..., :4]], dim=-1)
    whole = _blur(padded)[..., 4:-4, 4:-4]
    tiled = tiled_equirect(_blur, grid, tile=tile, overlap=4)
    torch.testing.assert_close(tiled, whole, rtol=1e-5, atol=1e-5)
    upsampled = tiled_equirect(
        lambda x: torch.nn.functional.interpolate(x, scale_factor=8),
        grid,
        up=8,
        tile=tile,
        overlap=2,
    )
    torch.testing.assert_close(upsampled, torch.nn.functional.interpolate(grid, scale_factor=8))


# --- the SVD backend on a tiny random model ------------------------------------------------
@pytest.fixture(scope="module")
def tiny_svd(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny plain-SVD pipeline with random weights, saved in diffusers format."""
    from pano4d.animate.svd import save_random_svd

    return save_random_svd(tmp_path_factory.mktemp("svd") / "tiny")


@pytest.fixture(scope="module")
def tiny_svd_mask(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same with Animate-Anything's 9-channel UNet (mask, noisy latent, image latent)."""
    from pano4d.animate.svd import save_random_svd

    return save_random_svd(tmp_path_factory.mktemp("svd") / "tiny-mask", mask_channel=True)


def _scene(tmp_path: Path, weights: Path) -> tuple:
    from pano4d.images import write_image
    from pano4d.regions import moving_mask

    # A smooth panorama, written and read back through the config like a user's.
    dirs = equirect_directions(128, 64, torch.float64)
    x, y, z = dirs.unbind(-1)
    panorama = (0.5 + 0.4 * torch.stack([torch.sin(3 * x + z), y, torch.cos(2 * z)])).float()
    write_image(tmp_path / "panorama.png", panorama.permute(1, 2, 0).numpy(), bits=16)
    settings = {"backend": "svd", "weights": str(weights), "frames": FRAMES, "steps": STEPS,
                "views": 4, "fov_deg": 100.0, "border_px": 2}  # fmt: skip
    region = {"box": [100, 4, 30, 44]}  # crosses the 0°/360° seam
    cfg = validate_config(
        {"panorama": "panorama.png", "regions": [region], "animate": settings}, tmp_path
    )
    moving = moving_mask(cfg, 128, 64)
    assert moving[:, 0].any() and moving[:, -1].any()
    return cfg, panorama, moving


def test_missing_or_incomplete_weights_folder_names_the_files(
    tmp_path: Path, tiny_svd: Path
) -> None:
    import shutil

    from pano4d.animate.svd import WeightsError, check_weights_folder

    pattern = r"not found: .*nowhere.*model_index\.json.*unet/config\.json"
    with pytest.raises(WeightsError, match=pattern):
        check_weights_folder(tmp_path / "nowhere")
    broken = tmp_path / "broken"
    shutil.copytree(tiny_svd, broken)
    (broken / "scheduler" / "scheduler_config.json").unlink()
    for weights in (broken / "unet").glob("*.safetensors"):
        weights.unlink()
    with pytest.raises(WeightsError) as error:
        check_weights_folder(broken)
    message = str(error.value)
    assert str(broken) in message
    assert "missing scheduler/scheduler_config.json, unet/*.safetensors (or *.bin) (" in message
    check_weights_folder(tiny_svd)  # the complete folder passes


def test_animate_svd_moves_only_the_region_and_keeps_the_rest_bit_identical(
    tmp_path: Path, tiny_svd_mask: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """End to end through the loading code, by path: several views, a region across the
    seam, Animate-Anything's mask input; outside the region the input, bit for bit."""
    from pano4d.animate.svd import animate_svd
    from pano4d.regions import blend_weight

    cfg, panorama, moving = _scene(tmp_path, tiny_svd_mask)
    panorama = torch.from_numpy(read_image(cfg.panorama)).permute(2, 0, 1).contiguous()
    video = animate_svd(cfg, panorama, moving, progress=True)
    log = capsys.readouterr().out
    active = int(log.split("svd: ")[1].split("/")[0])
    assert active >= 2, log  # the fusion is exercised
    assert "views disagree by" in log
    assert video.shape == (FRAMES, 3, 64, 128) and video.dtype == torch.float32
    assert torch.isfinite(video).all()
    outside = ~moving
    assert torch.equal(video[:, :, outside], panorama[:, outside][None].expand(FRAMES, -1, -1))
    inner = blend_weight(moving, cfg.animate.border_px) == 1
    assert float((video[:, :, inner] - panorama[:, inner]).abs().mean()) > 1e-3


def _plain_svd_loop(model, condition, latents: torch.Tensor, steps: int) -> torch.Tensor:
    """diffusers' StableVideoDiffusionPipeline loop on one view's latents, with its own
    scheduler stepping (scale_model_input, UNet, CFG, scheduler.step)."""
    from diffusers import EulerDiscreteScheduler

    scheduler = EulerDiscreteScheduler.from_config(model.scheduler.config)
    scheduler.set_timesteps(steps)
    frames = latents.shape[1]
    image_latents = condition.image_latents[:, None].expand(-1, frames, -1, -1, -1)
    embeddings = torch.cat([torch.zeros_like(condition.embeddings), condition.embeddings])
    time_ids = torch.tensor([[model.settings.fps - 1, model.settings.motion_bucket,
                              model.settings.noise_aug]] * 2)  # fmt: skip
    guidance = torch.linspace(model.settings.guidance_min, model.settings.guidance_max, frames)
    image_in = torch.cat([torch.zeros_like(image_latents), image_latents])
    for t in scheduler.timesteps:
        model_in = scheduler.scale_model_input(torch.cat([latents] * 2), t)
        with torch.no_grad():
            out = model.unet(
                torch.cat([model_in, image_in], dim=2),
                t,
                encoder_hidden_states=embeddings,
                added_time_ids=time_ids,
            ).sample
        uncond, cond = out.chunk(2)
        out = uncond + guidance.view(1, frames, 1, 1, 1) * (cond - uncond)
        latents = scheduler.step(out, t, latents).prev_sample
    return latents


def test_one_view_reproduces_plain_single_view_denoising(tiny_svd: Path) -> None:
    """The panoramic loop restricted to one view against diffusers' own loop on that view.

    Tolerance: diffusers forms x + (x − x̂₀)(σ' − σ)/σ in float32 with |x| ≈ σ_max = 700,
    which rounds at ulp(700) ≈ 6e-5; our loop keeps noise and signal apart and does not.
    """
    from pano4d.animate.svd import load_svd
    from pano4d.config import AnimateConfig

    settings = AnimateConfig(frames=FRAMES, steps=STEPS)
    model = load_svd(tiny_svd, settings, torch.device("cpu"), torch.float32)
    camera = Camera.from_fov(80.0, 32, 32, forward=(0.3, -1.0, 0.4))
    [lat] = latent_cameras([camera], model.scale_factor)
    ico, footprints = footprints_for_views([lat])
    image = torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(8))
    condition = model.encode_condition(image, FRAMES, None, seed=0)
    denoiser = PanoramicDenoiser(model, footprints, view_batch=1)
    signal = denoiser.sample(condition, torch.zeros(4, len(ico)), FRAMES, STEPS, seed=9)
    panoramic = footprints.project_mean(signal)
    # The same initial noise, as the view sees it, through the plain loop.
    noise = sphere_white_noise(len(ico), (FRAMES, 4), torch.Generator().manual_seed(9))
    _, init_scale = model.schedule(STEPS)
    plain = _plain_svd_loop(model, condition, init_scale * footprints.project_white(noise), STEPS)
    assert float(plain.abs().mean()) > 0.1
    torch.testing.assert_close(panoramic, plain, rtol=1e-3, atol=1e-3)
    assert float((panoramic - plain).abs().mean()) < 1e-4


def test_fp16_path_runs_without_nan(tiny_svd: Path) -> None:
    """float16 on the CPU (torch supports these ops there): conditioning, one prediction
    at the largest and smallest σ, decoding; all finite and close to float32."""
    from pano4d.animate.svd import load_svd
    from pano4d.config import AnimateConfig

    settings = AnimateConfig(frames=2, steps=STEPS)
    image = torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(11))
    latents = torch.randn(1, 2, 4, 4, 4, generator=torch.Generator().manual_seed(12))
    results = {}
    for dtype in (torch.float32, torch.float16):
        model = load_svd(tiny_svd, settings, torch.device("cpu"), dtype)
        assert model.unet.dtype == dtype
        condition = model.encode_condition(image, 2, None, seed=0)
        sigmas, init_scale = model.schedule(STEPS)
        first = model.predict_x0(init_scale * latents, float(sigmas[0]), condition)
        last = model.predict_x0(first, float(sigmas[-2]), condition)
        results[dtype] = (first, last, model.decode(last))
    for half, full in zip(results[torch.float16], results[torch.float32], strict=True):
        assert half.dtype == torch.float32 and torch.isfinite(half).all()
        assert float((half - full).abs().max()) < 0.05 * float(full.abs().max()) + 1e-3
