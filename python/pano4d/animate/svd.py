"""Backend ``svd``: Stable Video Diffusion (or Animate-Anything's SVD) through diffusers.

Loads UNetSpatioTemporalConditionModel, AutoencoderKLTemporalDecoder,
CLIPVisionModelWithProjection and EulerDiscreteScheduler from a local folder in diffusers
format, by path. A UNet with 2c + 1 input channels is Animate-Anything's: its input is
(mask, noisy latent, image latent); one with 2c is plain SVD's (noisy latent, image
latent). Conditioning follows diffusers' StableVideoDiffusionPipeline: CLIP embedding of
the view (antialiased resize to the encoder's size), the view's VAE latent after noise
augmentation, added time ids (fps − 1, motion bucket, noise augmentation), classifier-free
guidance ramping linearly over the frames from ``guidance_min`` to ``guidance_max``.

``animate_svd`` runs the whole phase on a panorama: views that see the moving region,
the Panoramic Denoiser on the sphere, tiled decoding, and the composite that keeps
everything outside the region bit-identical to the input.
"""

from __future__ import annotations

import importlib.util
import json
import math
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn.functional as F

from pano4d.animate.decode import tiled_equirect
from pano4d.animate.denoiser import PanoramicDenoiser, latent_cameras
from pano4d.animate.noise import footprints_for_views
from pano4d.animate.unet_attention import CUDA_GRID_LIMIT, max_unet_rows
from pano4d.camera import Camera
from pano4d.config import AnimateConfig, SceneConfig
from pano4d.device import resolve_device
from pano4d.regions import active_views, blend_weight
from pano4d.resample import equirect_sampler, equirect_to_perspective, sphere_sampler
from pano4d.sphere import (
    Icosphere,
    equirect_directions,
    matched_view_size,
    view_layout,
    views_seeing,
)

# Files a diffusers SVD folder must hold; each network folder also needs its weights.
REQUIRED_FILES = (
    "model_index.json",
    "unet/config.json",
    "vae/config.json",
    "image_encoder/config.json",
    "scheduler/scheduler_config.json",
)
WEIGHT_FOLDERS = ("unet", "vae", "image_encoder")
_WEIGHT_SUFFIXES = (".safetensors", ".bin", ".safetensors.index.json", ".bin.index.json")
# OpenAI CLIP normalisation, used when the folder has no feature_extractor config.
_CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
_CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
# Rough activation memory of one view in one UNet call, in units of
# frames × latent pixels × first-block channels × bytes per value (CFG doubles it).
_UNET_ACTIVATION_FACTOR = 40
# Views per CLIP + VAE encoder call when building the conditions.
CONDITION_BATCH = 4
# Tiles of the VAE, in latent cells (8 image pixels each for SVD).
DECODE_TILE = 64
DECODE_OVERLAP = 8


class WeightsError(FileNotFoundError):
    """A weights folder that is missing or lacks files the backend needs."""


class AttentionLimitError(ValueError):
    """Views so large that one view's attention calls exceed the CUDA kernels' limits."""


def attention_limit_message(latent_height: int, latent_width: int, frames: int) -> str:
    return (
        f"svd: a view of {latent_height}x{latent_width} latent cells and {frames} frames "
        f"gives the UNet's attention more than {CUDA_GRID_LIMIT:,} sequences in one call, the "
        "most the CUDA attention kernels take; lower animate.fov_deg (smaller views) and "
        "raise animate.views to keep the sphere covered"
    )


def _weight_files(folder: Path) -> list[str]:
    if not folder.is_dir():
        return []
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(_WEIGHT_SUFFIXES))


def check_weights_folder(folder: Path) -> None:
    """Raise WeightsError naming the folder and every expected file that is missing."""
    folder = Path(folder)
    expected = [*REQUIRED_FILES, *(f"{name}/*.safetensors (or *.bin)" for name in WEIGHT_FOLDERS)]
    if not folder.is_dir():
        raise WeightsError(
            f"svd weights folder not found: {folder}; expected a diffusers folder with "
            + ", ".join(expected)
        )
    missing = [name for name in REQUIRED_FILES if not (folder / name).is_file()]
    missing += [
        f"{name}/*.safetensors (or *.bin)"
        for name in WEIGHT_FOLDERS
        if not _weight_files(folder / name)
    ]
    if missing:
        raise WeightsError(
            f"svd weights folder {folder} is incomplete: missing {', '.join(missing)} "
            f"(a diffusers folder needs {', '.join(expected)})"
        )


def _variant(folder: Path) -> str | None:
    """'fp16' when a network folder only holds fp16-variant weights (as SVD's hub repo)."""
    names = _weight_files(folder)
    return "fp16" if names and all(".fp16." in name for name in names) else None


def resolve_dtype(name: str, device: torch.device) -> torch.dtype:
    """'auto' is float16 on a GPU and float32 on the CPU."""
    if name == "auto":
        return torch.float16 if device.type == "cuda" else torch.float32
    return {"float32": torch.float32, "float16": torch.float16, "bfloat16": torch.bfloat16}[name]


@dataclass
class SVDCondition:
    """Per-view SVD conditioning, views first."""

    embeddings: torch.Tensor  # (B, 1, d) CLIP image embeddings
    image_latents: torch.Tensor  # (B, c, h, w), unscaled, as SVD concatenates them
    masks: torch.Tensor | None  # (B, 1, h, w) 1 = may move (Animate-Anything's input)

    def select(self, views: slice) -> SVDCondition:
        return SVDCondition(
            self.embeddings[views],
            self.image_latents[views],
            None if self.masks is None else self.masks[views],
        )


class SVDDenoiser:
    """Φ for the Panoramic Denoiser: SVD's UNet, VAE and CLIP encoder (protocol.py)."""

    def __init__(
        self,
        unet: torch.nn.Module,
        vae: torch.nn.Module,
        image_encoder: torch.nn.Module,
        scheduler: object,
        settings: AnimateConfig,
        device: torch.device,
        dtype: torch.dtype,
        clip_mean: tuple[float, ...] = _CLIP_MEAN,
        clip_std: tuple[float, ...] = _CLIP_STD,
    ) -> None:
        self.unet, self.vae, self.image_encoder = unet, vae, image_encoder
        self.scheduler = scheduler
        self.settings = settings
        self.device, self.dtype = device, dtype
        self.latent_channels = int(vae.config.latent_channels)
        self.scale_factor = 2 ** (len(vae.config.block_out_channels) - 1)
        self.size_multiple = self.scale_factor * 2 ** (len(unet.config.block_out_channels) - 1)
        in_channels = int(unet.config.in_channels)
        if in_channels not in (2 * self.latent_channels, 2 * self.latent_channels + 1):
            raise ValueError(
                f"UNet takes {in_channels} input channels; expected {2 * self.latent_channels} "
                f"(SVD) or {2 * self.latent_channels + 1} (Animate-Anything: mask first)"
            )
        self.takes_mask = in_channels == 2 * self.latent_channels + 1
        # SVD's VAE asks to encode in float32 (force_upcast), as diffusers' pipeline does.
        if dtype == torch.float16 and getattr(vae.config, "force_upcast", False):
            vae.encoder.float()
            vae.quant_conv.float()
        self.encoder_dtype = next(vae.encoder.parameters()).dtype
        self.clip_size = int(image_encoder.config.image_size)
        self.clip_mean = torch.tensor(clip_mean, device=device).view(1, 3, 1, 1)
        self.clip_std = torch.tensor(clip_std, device=device).view(1, 3, 1, 1)
        self._timesteps: dict[float, float] = {}
        # Rows of every UNet call so far (the animate metrics report the batch used).
        self.unet_call_rows: list[int] = []

    @property
    def guidance_branches(self) -> int:
        """UNet rows per view: the unguided and the guided prediction with guidance."""
        return 2 if self.do_guidance else 1

    def unet_rows(self, frames: int, height: int, width: int) -> int:
        """The most rows (views × guidance branches) one UNet call on ``frames`` latent frames
        of ``height`` × ``width`` may take with every attention call inside the CUDA kernels'
        limits (unet_attention.py); 0 when one row alone exceeds them."""
        return max_unet_rows(self.unet.config, height, width, frames)

    # --- sampler schedule ---------------------------------------------------------------
    def schedule(self, steps: int) -> tuple[torch.Tensor, float]:
        self.scheduler.set_timesteps(steps, device="cpu")
        sigmas = self.scheduler.sigmas.to(torch.float64)
        timesteps = self.scheduler.timesteps.to(torch.float64)
        self._timesteps = dict(zip(sigmas[:-1].tolist(), timesteps.tolist(), strict=True))
        return sigmas, float(self.scheduler.init_noise_sigma)

    @property
    def do_guidance(self) -> bool:
        return self.settings.guidance_max > 1.0

    # --- conditioning -------------------------------------------------------------------
    @torch.no_grad()
    def encode_condition(
        self, images: torch.Tensor, frames: int, masks: torch.Tensor | None, seed: int
    ) -> SVDCondition:
        """CLIP embeddings and noise-augmented VAE latents, ``CONDITION_BATCH`` views at a
        time (a VAE encoder at view size is the memory peak of this stage)."""
        from diffusers.pipelines.stable_video_diffusion.pipeline_stable_video_diffusion import (
            _resize_with_antialiasing,
        )

        if self.takes_mask and masks is None:
            raise ValueError("this UNet takes a motion mask (9 input channels); pass masks")
        generator = torch.Generator().manual_seed(seed)
        noise = torch.randn(images.shape, generator=generator)
        embeddings, image_latents = [], []
        for start in range(0, images.shape[0], CONDITION_BATCH):
            part = slice(start, start + CONDITION_BATCH)
            signed = images[part].to(self.device, torch.float32) * 2.0 - 1.0
            size = (self.clip_size, self.clip_size)
            clip_in = (_resize_with_antialiasing(signed, size) + 1.0) / 2.0
            clip_in = (clip_in - self.clip_mean) / self.clip_std
            embeds = self.image_encoder(clip_in.to(self.dtype)).image_embeds
            embeddings.append(embeds.unsqueeze(1).to(self.dtype))
            augmented = signed + self.settings.noise_aug * noise[part].to(self.device)
            latents = self.vae.encode(augmented.to(self.encoder_dtype)).latent_dist.mode()
            image_latents.append(latents.to(self.dtype))
        mask_channel = None
        if self.takes_mask:
            mask_channel = masks.to(self.device, self.dtype)[:, None]
        return SVDCondition(torch.cat(embeddings), torch.cat(image_latents), mask_channel)

    # --- one prediction -----------------------------------------------------------------
    @torch.no_grad()
    def predict_x0(
        self, latents: torch.Tensor, sigma: float, condition: SVDCondition
    ) -> torch.Tensor:
        """x̂₀ from the UNet's output with EDM preconditioning, as EulerDiscreteScheduler
        computes it (c_in = 1/√(σ² + 1); v- or ε-prediction per the scheduler config)."""
        if sigma not in self._timesteps:
            raise ValueError(f"σ = {sigma} is not on the schedule; call schedule() first")
        batch, frames = latents.shape[:2]
        latents = latents.to(self.device, torch.float32)
        model_in = (latents / math.sqrt(sigma**2 + 1)).to(self.dtype)
        image_latents = condition.image_latents[:, None].expand(-1, frames, -1, -1, -1)
        parts = [model_in, image_latents]
        if condition.masks is not None:
            parts.insert(0, condition.masks[:, None].expand(-1, frames, -1, -1, -1))
        cond_in = torch.cat(parts, dim=2)
        embeddings = condition.embeddings
        time_ids = torch.tensor(
            [[self.settings.fps - 1, self.settings.motion_bucket, self.settings.noise_aug]],
            device=self.device,
            dtype=self.dtype,
        ).expand(batch, -1)
        if self.do_guidance:
            uncond_parts = [model_in, torch.zeros_like(image_latents)]
            if condition.masks is not None:
                uncond_parts.insert(0, parts[0])
            cond_in = torch.cat([torch.cat(uncond_parts, dim=2), cond_in])
            embeddings = torch.cat([torch.zeros_like(embeddings), embeddings])
            time_ids = torch.cat([time_ids, time_ids])
        timestep = torch.tensor(self._timesteps[sigma], device=self.device)
        out = self._unet_in_parts(cond_in, timestep, embeddings, time_ids)
        if self.do_guidance:
            uncond, cond = out.chunk(2)
            scale = torch.linspace(
                self.settings.guidance_min, self.settings.guidance_max, frames, device=self.device
            ).view(1, frames, 1, 1, 1)
            out = uncond + scale * (cond - uncond)
        prediction = self.scheduler.config.prediction_type
        if prediction == "v_prediction":
            return out * (-sigma / math.sqrt(sigma**2 + 1)) + latents / (sigma**2 + 1)
        if prediction == "epsilon":
            return latents - sigma * out
        raise ValueError(f"unsupported scheduler prediction_type {prediction!r}")

    def _unet_in_parts(
        self,
        model_in: torch.Tensor,
        timestep: torch.Tensor,
        embeddings: torch.Tensor,
        time_ids: torch.Tensor,
    ) -> torch.Tensor:
        """The UNet on ``model_in`` (rows, L, C, h, w), in calls of at most ``unet_rows`` rows
        (rows are independent: the result equals one call's)."""
        rows, frames = model_in.shape[:2]
        limit = self.unet_rows(frames, *model_in.shape[-2:])
        if limit < 1:
            raise AttentionLimitError(attention_limit_message(*model_in.shape[-2:], frames))
        parts = []
        for start in range(0, rows, limit):
            part = slice(start, start + limit)
            out = self.unet(
                model_in[part],
                timestep,
                encoder_hidden_states=embeddings[part],
                added_time_ids=time_ids[part],
            ).sample
            parts.append(out.float())
            self.unet_call_rows.append(out.shape[0])
        return torch.cat(parts)

    # --- VAE ----------------------------------------------------------------------------
    @torch.no_grad()
    def encode(self, images: torch.Tensor) -> torch.Tensor:
        signed = images.to(self.device, self.encoder_dtype) * 2.0 - 1.0
        latents = self.vae.encode(signed).latent_dist.mode().float()
        return latents * float(self.vae.config.scaling_factor)

    @torch.no_grad()
    def decode(self, latents: torch.Tensor) -> torch.Tensor:
        batch, frames = latents.shape[:2]
        z = latents.flatten(0, 1).to(self.device) / float(self.vae.config.scaling_factor)
        images = self.vae.decode(z.to(self.dtype), num_frames=frames).sample.float()
        images = ((images + 1.0) / 2.0).clamp(0.0, 1.0)
        return images.reshape(batch, frames, *images.shape[1:])


def load_svd(
    folder: Path, settings: AnimateConfig, device: torch.device, dtype: torch.dtype
) -> SVDDenoiser:
    """Load the networks from a local diffusers folder (see ``check_weights_folder``)."""
    from diffusers import (
        AutoencoderKLTemporalDecoder,
        EulerDiscreteScheduler,
        UNetSpatioTemporalConditionModel,
    )
    from transformers import CLIPVisionModelWithProjection

    folder = Path(folder)
    check_weights_folder(folder)

    # The dtype goes to from_pretrained (a cast afterwards would skip the modules diffusers
    # keeps in float32). Loading straight into empty modules needs accelerate; without it,
    # say so rather than have diffusers fall back with a warning.
    low_memory = importlib.util.find_spec("accelerate") is not None

    def network(cls: type, name: str) -> torch.nn.Module:
        kwargs: dict[str, object] = {"subfolder": name, "low_cpu_mem_usage": low_memory}
        kwargs["dtype" if cls is CLIPVisionModelWithProjection else "torch_dtype"] = dtype
        variant = _variant(folder / name)
        if variant is not None:
            kwargs["variant"] = variant
        return cls.from_pretrained(folder, **kwargs).to(device).eval()

    unet = network(UNetSpatioTemporalConditionModel, "unet")
    vae = network(AutoencoderKLTemporalDecoder, "vae")
    image_encoder = network(CLIPVisionModelWithProjection, "image_encoder")
    scheduler = EulerDiscreteScheduler.from_pretrained(folder, subfolder="scheduler")
    mean, std = _CLIP_MEAN, _CLIP_STD
    processor = folder / "feature_extractor" / "preprocessor_config.json"
    if processor.is_file():
        config = json.loads(processor.read_text(encoding="utf-8"))
        mean = tuple(config.get("image_mean", mean))
        std = tuple(config.get("image_std", std))
    return SVDDenoiser(unet, vae, image_encoder, scheduler, settings, device, dtype, mean, std)


# --- the whole phase ----------------------------------------------------------------------
def view_batch(model: SVDDenoiser, frames: int, cam: Camera, budget_bytes: int) -> int:
    """Views per step batch: as many as ``budget_bytes`` of UNet activations hold, and no
    more than one UNet call takes within the attention kernels' limits. At least 1: a view
    whose guidance branches exceed the limits together gets one call per branch."""
    height, width = cam.height // model.scale_factor, cam.width // model.scale_factor
    per_view = (
        frames
        * height
        * width
        * int(model.unet.config.block_out_channels[0])
        * torch.finfo(model.dtype).bits
        // 8
        * _UNET_ACTIVATION_FACTOR
        * model.guidance_branches
    )
    by_kernels = model.unet_rows(frames, height, width) // model.guidance_branches
    return max(1, min(budget_bytes // per_view, by_kernels))


def memory_budget(device: torch.device) -> int:
    """Bytes the UNet's activations may use: half the free GPU memory, or 4 GiB on the CPU."""
    if device.type == "cuda":
        free, _ = torch.cuda.mem_get_info(device)
        return free // 2
    return 4 << 30


@dataclass
class PanoramaSetup:
    """Everything the sampler needs for one panorama, built once before the first step."""

    side: int  # view size in pixels
    n_views: int  # views in the layout
    active: list[int]  # the views that see the (grown) region
    ico: Icosphere  # the points the latent video lives on
    latent_views: list[Camera]  # the active views at latent resolution
    denoiser: PanoramicDenoiser
    condition: SVDCondition
    static_grid: torch.Tensor  # (c, H/s, W/s) the input's own latent
    static: torch.Tensor  # (c, N) the same on the sphere


def prepare_panorama(
    model: SVDDenoiser, settings: AnimateConfig, panorama: torch.Tensor, moving: torch.Tensor,
    seed: int, memory_bytes: int | None = None,
) -> PanoramaSetup:  # fmt: skip
    """Choose the active views, build their footprints, encode conditions and the input."""
    _, height, width = panorama.shape
    if moving.shape != (height, width):
        raise ValueError(f"moving mask is {tuple(moving.shape)}, panorama is {height}x{width}")
    s = model.scale_factor
    if height % s or width % s:
        raise ValueError(f"panorama {width}x{height} must have sides divisible by {s}")
    side = matched_view_size(width, settings.fov_deg, model.size_multiple)
    if model.unet_rows(settings.frames, side // s, side // s) < 1:
        raise AttentionLimitError(attention_limit_message(side // s, side // s, settings.frames))
    cameras = view_layout(settings.views, settings.fov_deg, side)
    active = active_views(cameras, moving)
    if not active:
        raise ValueError(
            f"no view of the {settings.views}-view layout at {settings.fov_deg}° sees the "
            "moving region; raise animate.views or animate.fov_deg"
        )
    chosen = [cameras[k] for k in active]
    latent_views = latent_cameras(chosen, s)
    ico, footprints = footprints_for_views(latent_views)

    # Conditions: each active view's crop of the panorama and of the moving mask.
    crops = torch.stack([equirect_to_perspective(panorama, cam) for cam in chosen])
    masks = None
    if model.takes_mask:
        grown = torch.stack([equirect_to_perspective(moving[None].float(), c) for c in chosen])
        masks = F.max_pool2d(grown, s)[:, 0] > 0
    condition = model.encode_condition(crops, settings.frames, masks, seed)

    # The input's own latent, everywhere, and on the sphere.
    static_grid = tiled_equirect(
        model.encode, panorama[None], down=s, tile=DECODE_TILE * s, overlap=DECODE_OVERLAP * s
    )[0]
    static = equirect_sampler(ico.points, width // s, height // s).apply(static_grid)
    budget = memory_budget(model.device) if memory_bytes is None else memory_bytes
    batch = min(len(active), view_batch(model, settings.frames, chosen[0], budget))
    denoiser = PanoramicDenoiser(model, footprints, batch)
    return PanoramaSetup(
        side, len(cameras), active, ico, latent_views, denoiser, condition, static_grid, static
    )


def decode_panorama(
    model: SVDDenoiser, setup: PanoramaSetup, signal: torch.Tensor, size: tuple[int, int]
) -> torch.Tensor:
    """The sphere latent video (L, c, N) → equirect video (L, 3, h, w) of ``size`` (w, h) on
    the host, decoded in tiles from a latent grid of the size's cells (so a smaller size
    decodes fewer tiles); where no active view sees, the decoder gets the input's own
    latent."""
    width, height = size
    s = model.scale_factor
    grid_h, grid_w = -(-height // s), -(-width // s)
    grid_w += grid_w % 2  # an equirect grid has an even width
    dirs = equirect_directions(grid_w, grid_h, torch.float64)
    latent = sphere_sampler(dirs, setup.ico).to(signal.device).apply(signal).cpu()
    seen = views_seeing(setup.latent_views, dirs).any(dim=0)
    static = setup.static_grid
    if static.shape[-2:] != (grid_h, grid_w):
        static = F.interpolate(static[None], size=(grid_h, grid_w), mode="area")[0]
    latent = torch.where(seen, latent, static)
    video = tiled_equirect(
        lambda z: model.decode(z[None])[0], latent, up=s, tile=DECODE_TILE, overlap=DECODE_OVERLAP
    )
    if video.shape[-2:] != (height, width):
        video = F.interpolate(video, size=(height, width), mode="area")
    return video


@dataclass
class OutputFrames:
    """The size a video is written at: the panorama there (3, h, w) and the regions' soft
    blend weight there (h, w)."""

    panorama: torch.Tensor
    blend: torch.Tensor


@dataclass
class SVDVideo:
    """What ``animate_svd`` made, and how it batched the UNet."""

    video: torch.Tensor  # (L, 3, h, w) float32
    batching: dict[str, int]  # for the animate metrics (svd_* keys)


def animate_svd(
    cfg: SceneConfig,
    panorama: torch.Tensor,
    moving: torch.Tensor,
    progress: bool = True,
    model: SVDDenoiser | None = None,
    output: OutputFrames | None = None,
) -> SVDVideo:
    """Animate ``panorama`` (3, H, W) float32 inside ``moving`` (H, W) bool with SVD.

    The video is (L, 3, h, w) float32 at ``output``'s size (default: the input's own): the
    decoded video blended into ``output.panorama`` with ``output.blend``, so every pixel
    outside the blend equals that panorama exactly. The UNet's views are cut from the
    input at its own resolution whatever the output's size. ``model`` skips loading (tests
    pass one already loaded).
    """
    settings = cfg.animate
    if model is None:
        if settings.weights is None:
            raise WeightsError("backend 'svd' needs animate.weights: a local diffusers folder")
        device = resolve_device(cfg.device)
        model = load_svd(settings.weights, settings, device, resolve_dtype(settings.dtype, device))
    log = print if progress else (lambda *_: None)
    setup = prepare_panorama(model, settings, panorama, moving, cfg.seed)
    latent = setup.side // model.scale_factor
    rows_limit = model.unet_rows(settings.frames, latent, latent)
    log(f"svd: {len(setup.active)}/{setup.n_views} views of {setup.side}px see the region; "
        f"{setup.denoiser.footprints.n_points} sphere points, "
        f"{setup.denoiser.view_batch} views per step batch, at most {rows_limit} UNet rows "
        "(views × guidance branches) per call")  # fmt: skip
    calls_before = len(model.unet_call_rows)
    signal = setup.denoiser.sample(
        setup.condition, setup.static, settings.frames, settings.steps, cfg.seed
    )
    for i, report in enumerate(setup.denoiser.reports):
        times = ", ".join(f"{k} {v:.2f}s" for k, v in report.seconds.items())
        log(f"svd step {i + 1}/{settings.steps}: {times}; views disagree by "
            f"{report.disagreement:.4f} before fusion")  # fmt: skip
    if output is None:
        output = OutputFrames(panorama, blend_weight(moving, settings.border_px))
    target, blend = output.panorama, output.blend
    video = decode_panorama(model, setup, signal, (target.shape[2], target.shape[1]))
    calls = model.unet_call_rows[calls_before:]
    batching = {
        "svd_active_views": len(setup.active),
        "svd_view_size": setup.side,
        "svd_views_per_batch": setup.denoiser.view_batch,
        "svd_unet_rows_limit": rows_limit,
        "svd_unet_batch": max(calls),
        "svd_unet_calls": len(calls),
    }
    blended = torch.where(blend > 0, torch.lerp(target[None], video, blend), target[None])
    return SVDVideo(blended, batching)
