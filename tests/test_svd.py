"""The svd backend (pano4d.animate.svd) on tiny random models loaded by path, and the bound
on its UNet batch (unet_attention.py) checked on SVD's real configuration.

The full-size UNet is built on the meta device: shapes flow through the real diffusers
forward, with no weights and no arithmetic, so every attention call of SVD's UNet at a
4096- and 8192-wide panorama's view size can be checked here without a GPU.
"""

from __future__ import annotations

import json
import logging
import math
import warnings
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from pano4d.animate.denoiser import PanoramicDenoiser, latent_cameras
from pano4d.animate.noise import footprints_for_views, sphere_white_noise
from pano4d.animate.random_svd import SVD_SCHEDULER, random_svd_networks, save_random_svd
from pano4d.animate.unet_attention import CUDA_GRID_LIMIT, attention_calls, max_unet_rows
from pano4d.camera import Camera
from pano4d.config import AnimateConfig, validate_config
from pano4d.images import read_image
from pano4d.sphere import equirect_directions, matched_view_size

FRAMES, STEPS = 3, 2


@pytest.fixture(scope="module")
def tiny_svd(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny plain-SVD pipeline with random weights, saved in diffusers format."""
    return save_random_svd(tmp_path_factory.mktemp("svd") / "tiny")


@pytest.fixture(scope="module")
def tiny_svd_mask(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same with Animate-Anything's 9-channel UNet (mask, noisy latent, image latent)."""
    return save_random_svd(tmp_path_factory.mktemp("svd") / "tiny-mask", mask_channel=True)


@contextmanager
def sdpa_calls() -> Iterator[list[tuple[int, int, int, int, int]]]:
    """Records (batch, heads, queries, keys, head dim) of every scaled_dot_product_attention
    call (diffusers' AttnProcessor2_0 calls it through torch.nn.functional)."""
    calls: list[tuple[int, int, int, int, int]] = []
    original = F.scaled_dot_product_attention

    def spy(query: torch.Tensor, key: torch.Tensor, *args: object, **kwargs: object):  # type: ignore[no-untyped-def]
        calls.append((query.shape[0], query.shape[1], query.shape[2], key.shape[2], query.shape[3]))
        return original(query, key, *args, **kwargs)

    F.scaled_dot_product_attention = spy
    try:
        yield calls
    finally:
        F.scaled_dot_product_attention = original


def meta_svd(size: str, settings: AnimateConfig):  # type: ignore[no-untyped-def]
    """An SVDDenoiser of ``size``'s architecture on the meta device (shapes only)."""
    from diffusers import EulerDiscreteScheduler

    from pano4d.animate.svd import SVDDenoiser

    with torch.device("meta"):
        # Some modules make tensors with legacy constructors, which ignore the device
        # context: move them too.
        networks = [network.to("meta").half() for network in random_svd_networks(size)]
    scheduler = EulerDiscreteScheduler(**SVD_SCHEDULER)
    return SVDDenoiser(*networks, scheduler, settings, torch.device("meta"), torch.float16)


# --- the UNet batch bound -------------------------------------------------------------------
@pytest.mark.parametrize(
    ("size", "latent", "rows"),
    [("tiny", 12, 2), ("full", 112, 2), ("full", 224, 1), ("full", 90, 3)],
)
def test_attention_calls_are_the_ones_the_unet_makes(size: str, latent: int, rows: int) -> None:
    """The derived list of attention shapes equals what a forward of the real diffusers
    UNet calls, call for call (the full-size one on the meta device; 90 is not a multiple
    of 8, so the levels round up)."""
    from diffusers import UNetSpatioTemporalConditionModel

    from pano4d.animate.random_svd import unet_kwargs

    device = "meta" if size == "full" else "cpu"
    with torch.device(device):
        unet = UNetSpatioTemporalConditionModel(**unet_kwargs(size))
    unet = unet.to(device)
    frames, context = 5, unet.config.cross_attention_dim
    with torch.device(device), torch.no_grad(), sdpa_calls() as calls:
        unet(
            torch.randn(rows, frames, 8, latent, latent),
            torch.tensor(1.0),
            encoder_hidden_states=torch.randn(rows, 1, context),
            added_time_ids=torch.randn(rows, 3),
        )
    derived: Counter[tuple[int, int, int, int, int]] = Counter()
    for c in attention_calls(unet.config, latent, latent, frames):
        derived[(c.batch(rows), c.heads, c.queries, c.keys, c.head_dim)] += c.count
    assert Counter(calls) == derived


@pytest.mark.parametrize(
    ("width", "side", "rows", "views"), [(4096, 896, 5, 2), (8192, 1792, 1, 1)]
)
def test_full_svd_unet_batch_stays_within_the_cuda_attention_limits(
    width: int, side: int, rows: int, views: int
) -> None:
    """SVD's real configuration at the view size of a 4096- and 8192-wide panorama
    (default 80° views, L = 14, guidance): the bound on rows per UNet call, the views per
    step batch under an unlimited memory budget, and one guided prediction through
    SVDDenoiser.predict_x0 whose every attention call has batch and heads ≤ 65,535. One
    row more than the bound would exceed it (the bound is tight)."""
    from pano4d.animate.svd import view_batch

    settings = AnimateConfig(frames=14)
    model = meta_svd("full", settings)
    assert matched_view_size(width, settings.fov_deg, model.size_multiple) == side
    latent = side // model.scale_factor
    config = model.unet.config
    assert max_unet_rows(config, latent, latent, 14) == rows
    assert max(c.batch(rows + 1) for c in attention_calls(config, latent, latent, 14)) > (
        CUDA_GRID_LIMIT
    )
    camera = Camera.from_fov(settings.fov_deg, side, side)
    assert view_batch(model, 14, camera, budget_bytes=1 << 60) == views

    model.schedule(STEPS)
    sigma = next(iter(model._timesteps))
    condition = _meta_condition(model, views, latent)
    with sdpa_calls() as calls:
        x0 = model.predict_x0(torch.zeros(views, 14, 4, latent, latent), sigma, condition)
    assert x0.shape == (views, 14, 4, latent, latent)
    assert max(batch for batch, *_ in calls) <= CUDA_GRID_LIMIT
    assert max(heads for _, heads, *_ in calls) <= CUDA_GRID_LIMIT
    # Guidance doubles the rows: 2 views in one call at 4096; at 8192 one call per branch.
    assert model.unet_call_rows == ([2 * views] if rows >= 2 * views else [1, 1])


def _meta_condition(model, views: int, latent: int):  # type: ignore[no-untyped-def]
    from pano4d.animate.svd import SVDCondition

    with torch.device("meta"):
        embeddings = torch.zeros(views, 1, model.unet.config.cross_attention_dim)
        image_latents = torch.zeros(views, model.latent_channels, latent, latent)
        return SVDCondition(embeddings.half(), image_latents.half(), None)


def test_guidance_branches_in_separate_calls_give_the_same_prediction(
    tiny_svd: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Splitting a UNet batch into calls of fewer rows changes nothing but the calls."""
    from pano4d.animate.svd import SVDDenoiser, load_svd

    model = load_svd(tiny_svd, AnimateConfig(frames=2), torch.device("cpu"), torch.float32)
    image = torch.rand(3, 3, 32, 32, generator=torch.Generator().manual_seed(5))
    condition = model.encode_condition(image, 2, None, seed=0)
    latents = torch.randn(3, 2, 4, 4, 4, generator=torch.Generator().manual_seed(6))
    sigmas, init_scale = model.schedule(STEPS)
    whole = model.predict_x0(init_scale * latents, float(sigmas[0]), condition)
    assert model.unet_call_rows == [6]
    monkeypatch.setattr(SVDDenoiser, "unet_rows", lambda *_: 1)
    split = model.predict_x0(init_scale * latents, float(sigmas[0]), condition)
    assert model.unet_call_rows == [6, 1, 1, 1, 1, 1, 1]
    torch.testing.assert_close(split, whole, rtol=1e-5, atol=1e-5)


# --- loading --------------------------------------------------------------------------------
@contextmanager
def library_warnings() -> Iterator[list[str]]:
    """Warnings and WARNING-level log records of diffusers and transformers (their loggers
    do not propagate to the root logger, so pytest's caplog would not see them)."""
    records: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            records.append(record.getMessage())

    handler = Keep(level=logging.WARNING)
    loggers = [logging.getLogger(name) for name in ("diffusers", "transformers")]
    for logger in loggers:
        logger.addHandler(handler)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield records
        records.extend(str(w.message) for w in caught)
    finally:
        for logger in loggers:
            logger.removeHandler(handler)


@pytest.mark.parametrize("variant", [None, "fp16"])
def test_tiny_model_loads_in_half_precision_without_warnings(
    tmp_path: Path, variant: str | None
) -> None:
    """load_svd passes torch_dtype (and the fp16 variant where the folder has only those
    files) to from_pretrained: no cast after loading, which diffusers warns skips the
    modules it keeps in float32."""
    from pano4d.animate.svd import load_svd

    folder = save_random_svd(tmp_path / "tiny", variant=variant)  # type: ignore[arg-type]
    if variant == "fp16":
        assert all(".fp16." in p.name for p in (folder / "unet").glob("*.safetensors"))
    settings = AnimateConfig(frames=2)
    with library_warnings() as seen:
        model = load_svd(folder, settings, torch.device("cpu"), torch.float16)
    assert seen == []
    assert model.unet.dtype == torch.float16
    assert model.image_encoder.dtype == torch.float16


# --- the backend on a tiny random model -----------------------------------------------------
def _scene(tmp_path: Path, weights: Path, width: int = 128) -> tuple:
    from pano4d.images import write_image
    from pano4d.regions import moving_mask

    # A smooth panorama, written and read back through the config like a user's.
    dirs = equirect_directions(width, width // 2, torch.float64)
    x, y, z = dirs.unbind(-1)
    panorama = (0.5 + 0.4 * torch.stack([torch.sin(3 * x + z), y, torch.cos(2 * z)])).float()
    write_image(tmp_path / "panorama.png", panorama.permute(1, 2, 0).numpy(), bits=16)
    settings = {"backend": "svd", "weights": str(weights), "frames": FRAMES, "steps": STEPS,
                "views": 4, "fov_deg": 100.0, "border_px": 2}  # fmt: skip
    region = {"box": [v * width // 128 for v in (100, 4, 30, 44)]}  # across the 0°/360° seam
    cfg = validate_config(
        {"panorama": "panorama.png", "regions": [region], "animate": settings}, tmp_path
    )
    moving = moving_mask(cfg, width, width // 2)
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
    video = animate_svd(cfg, panorama, moving, progress=True).video
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


def test_animate_svd_writes_at_the_size_asked_for(tmp_path: Path, tiny_svd: Path) -> None:
    """The animating phase at a working size with svd: the UNet's views keep the size the
    input's resolution gives them (the same batching as at full size), the video is decoded
    at the working size, and outside the blend its frames are the input area-downsampled,
    bit for bit."""
    from pano4d.animate.frames import area_resize
    from pano4d.animate.pipeline import animation_input, run_animate

    cfg, _, _ = _scene(tmp_path, tiny_svd, width=512)
    size = (192, 96)  # not a multiple of the VAE's 8 in height: decoded larger, then resized
    small = run_animate(cfg, size, progress=False)
    full = run_animate(cfg, progress=False)
    assert small.store.size() == size
    assert small.metrics["svd_view_size"] == full.metrics["svd_view_size"]
    expected = area_resize(torch.from_numpy(read_image(cfg.panorama)[:, :, :3]), size)
    still = animation_input(cfg, size).regions.blend == 0
    frames = torch.stack([torch.from_numpy(f) for f in small.store.frames()])
    assert torch.equal(frames[:, still], expected[still][None].expand(FRAMES, -1, -1))
    assert float((frames[:, ~still] - expected[~still]).abs().mean()) > 1e-3


def test_animate_metrics_record_the_unet_batch(tmp_path: Path, tiny_svd: Path) -> None:
    """`pano4d animate` with the svd backend writes how it batched the UNet into
    metrics.json: the batch used is within the attention bound and the memory budget's
    views, and the calls add up to every step over every batch of views."""
    from pano4d.animate.pipeline import run_animate

    cfg, _, _ = _scene(tmp_path, tiny_svd, width=512)  # the smallest panorama accepted
    run_animate(cfg, progress=False)
    metrics = json.loads((Path(cfg.output) / "animate" / "metrics.json").read_text())
    views, per_batch = metrics["svd_active_views"], metrics["svd_views_per_batch"]
    assert views >= 2 and 1 <= per_batch <= views
    assert metrics["svd_unet_batch"] == 2 * min(per_batch, views)  # guidance: two rows a view
    assert metrics["svd_unet_batch"] <= metrics["svd_unet_rows_limit"]
    assert metrics["svd_unet_calls"] == STEPS * math.ceil(views / per_batch)


def test_views_too_large_for_the_attention_kernels_are_one_clear_error(
    tmp_path: Path, tiny_svd: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """When one view alone exceeds the kernels' limits, the phase stops before any work
    with a message that says what to change."""
    from pano4d.animate.pipeline import AnimateError, run_animate
    from pano4d.animate.svd import SVDDenoiser

    cfg, _, _ = _scene(tmp_path, tiny_svd, width=512)
    monkeypatch.setattr(SVDDenoiser, "unet_rows", lambda *_: 0)

    def not_before_the_check(*_: object) -> None:
        raise AssertionError("conditions encoded before the size was checked")

    monkeypatch.setattr(SVDDenoiser, "encode_condition", not_before_the_check)
    with pytest.raises(AnimateError, match=r"65,535 sequences .* lower animate\.fov_deg"):
        run_animate(cfg, progress=False)


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
