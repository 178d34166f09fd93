"""Random-weight SVD models of the real architecture, for tests and benchmarks.

No SVD weights can be downloaded here, so the ``svd`` backend is exercised on pipelines
built from configs with random weights: ``"tiny"`` (the same block types at 32–64 channels,
for tests on a CPU) and ``"full"`` (SVD's own architecture: the real model's FLOPs, memory
and attention shapes, for ``bench/animate.py --full`` on a GPU). ``save_random_svd`` writes
one in diffusers format, so that it is loaded by path through ``svd.load_svd`` like real
weights.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import torch

Size = Literal["tiny", "full"]

# SVD's scheduler config (stabilityai/stable-video-diffusion-img2vid-xt).
SVD_SCHEDULER = {
    "beta_end": 0.012,
    "beta_schedule": "scaled_linear",
    "beta_start": 0.00085,
    "interpolation_type": "linear",
    "num_train_timesteps": 1000,
    "prediction_type": "v_prediction",
    "sigma_max": 700.0,
    "sigma_min": 0.002,
    "steps_offset": 1,
    "timestep_spacing": "leading",
    "timestep_type": "continuous",
    "use_karras_sigmas": True,
}


# SVD's temporal VAE and ViT-H/14 CLIP image encoder, and their tiny twins.
_VAE_KWARGS: dict[str, dict[str, Any]] = {
    "full": {"block_out_channels": (128, 256, 512, 512), "layers_per_block": 2, "sample_size": 768},
    "tiny": {"block_out_channels": (32, 32, 32, 32), "layers_per_block": 1, "sample_size": 64},
}
_CLIP_KWARGS: dict[str, dict[str, Any]] = {
    "full": {"hidden_size": 1280, "intermediate_size": 5120, "num_attention_heads": 16,
             "num_hidden_layers": 32, "patch_size": 14, "image_size": 224,
             "projection_dim": 1024, "hidden_act": "gelu"},
    "tiny": {"hidden_size": 32, "intermediate_size": 64, "num_attention_heads": 2,
             "num_hidden_layers": 2, "patch_size": 8, "image_size": 32, "projection_dim": 32},
}  # fmt: skip


def unet_kwargs(size: Size = "tiny", mask_channel: bool = False) -> dict[str, Any]:
    """UNetSpatioTemporalConditionModel arguments: ``"full"`` is SVD's UNet (diffusers'
    defaults are SVD's: 320–1280 channels, 5–20 heads of 64, three cross-attention levels);
    ``mask_channel`` adds Animate-Anything's mask input."""
    in_channels = 8 + (1 if mask_channel else 0)
    if size == "full":
        return {"in_channels": in_channels, "sample_size": 96}
    if size == "tiny":
        return {
            "in_channels": in_channels,
            "sample_size": 8,
            "down_block_types": ("CrossAttnDownBlockSpatioTemporal", "DownBlockSpatioTemporal"),
            "up_block_types": ("UpBlockSpatioTemporal", "CrossAttnUpBlockSpatioTemporal"),
            "block_out_channels": (32, 64),
            "addition_time_embed_dim": 8,
            "projection_class_embeddings_input_dim": 24,
            "layers_per_block": 1,
            "cross_attention_dim": 32,
            "num_attention_heads": (2, 4),
            "num_frames": 4,
        }
    raise ValueError(f"size must be 'tiny' or 'full', got {size!r}")


def random_svd_networks(
    size: Size = "tiny", mask_channel: bool = False, seed: int = 0
) -> tuple[Any, Any, Any]:
    """(UNet, VAE, CLIP image encoder) with random weights, in float32 on the current
    device: ``size="full"`` is SVD's own architecture (the UNet of ``unet_kwargs("full")``,
    the temporal VAE, a ViT-H/14 CLIP encoder), ``"tiny"`` the same block types at 32–64
    channels. ``mask_channel`` gives the UNet Animate-Anything's extra mask input."""
    from diffusers import AutoencoderKLTemporalDecoder, UNetSpatioTemporalConditionModel
    from transformers import CLIPVisionConfig, CLIPVisionModelWithProjection

    unet_config = unet_kwargs(size, mask_channel)  # refuses an unknown size
    torch.manual_seed(seed)
    unet = UNetSpatioTemporalConditionModel(**unet_config)
    vae = AutoencoderKLTemporalDecoder(
        down_block_types=("DownEncoderBlock2D",) * 4, **_VAE_KWARGS[size]
    )
    clip = CLIPVisionConfig(**_CLIP_KWARGS[size])
    return unet.eval(), vae.eval(), CLIPVisionModelWithProjection(clip).eval()


def random_svd_pipeline(size: Size = "tiny", mask_channel: bool = False, seed: int = 0) -> Any:
    """A StableVideoDiffusionPipeline of ``random_svd_networks(size, mask_channel, seed)``
    with SVD's scheduler, in float32 on the CPU."""
    from diffusers import EulerDiscreteScheduler, StableVideoDiffusionPipeline
    from transformers import CLIPImageProcessor

    unet, vae, image_encoder = random_svd_networks(size, mask_channel, seed)
    side = image_encoder.config.image_size
    return StableVideoDiffusionPipeline(
        vae=vae,
        image_encoder=image_encoder,
        unet=unet,
        scheduler=EulerDiscreteScheduler(**SVD_SCHEDULER),
        feature_extractor=CLIPImageProcessor(crop_size=side, size={"shortest_edge": side}),
    )


def save_random_svd(
    folder: Path,
    size: Size = "tiny",
    mask_channel: bool = False,
    seed: int = 0,
    variant: Literal["fp16"] | None = None,
) -> Path:
    """Write ``random_svd_pipeline(size, mask_channel, seed)`` in diffusers format.

    ``variant="fp16"`` stores float16 weights as ``*.fp16.safetensors``, as SVD's hub
    repository does (half the bytes to write and read for the full-size model).
    """
    pipeline = random_svd_pipeline(size, mask_channel, seed)
    if variant == "fp16":
        # Random weights have no modules to keep in float32: a plain cast is what the hub's
        # fp16 files are. Loading them goes through from_pretrained(torch_dtype=...).
        for network in (pipeline.unet, pipeline.vae, pipeline.image_encoder):
            network.half()
    pipeline.save_pretrained(folder, variant=variant)
    return Path(folder)
