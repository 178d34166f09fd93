"""The attention calls of SVD's UNet, and how large a batch one UNet call may take.

diffusers' UNetSpatioTemporalConditionModel holds a TransformerSpatioTemporalModel in
every cross-attention block of its down and up paths and in its mid block. At resolution
level ℓ (the latent halved ℓ times: h_ℓ × w_ℓ cells) with H_ℓ heads, each of its transformer
layers makes four ``F.scaled_dot_product_attention`` calls on a UNet batch of R rows (views
× guidance branches) of F frames:

    spatial  self  (attn1)   SDPA batch R·F         queries h_ℓ·w_ℓ   keys h_ℓ·w_ℓ
    spatial  cross (attn2)   SDPA batch R·F         queries h_ℓ·w_ℓ   keys 1 (CLIP token)
    temporal self  (attn1)   SDPA batch R·h_ℓ·w_ℓ   queries F         keys F
    temporal cross (attn2)   SDPA batch R·h_ℓ·w_ℓ   queries F         keys 1

(``attention_calls`` lists them; tests compare the list with the calls a forward makes.)

The fused CUDA kernels behind SDPA launch one thread block per (query block, head, batch
entry) and put heads and batch on grid axes y and z, which CUDA caps at 65,535:
FLASH_ATTENTION (grid: query blocks, batch, heads) and EFFICIENT_ATTENTION (grid: query
blocks, heads, batch) fail with "invalid configuration argument" from a batch of 65,536
(pytorch/pytorch#146704, #142228); CUDNN_ATTENTION fails from the same batch (pytorch/pytorch
PR #181235, verified on an H100; torch routes such calls away from cuDNN only since 2026-04,
PR #180718); MATH runs batched matrix products and has no such limit. Fixes that fold the
axes together were proposed in 2026 (PRs #176096, #177985) and are not relied on here.

So every call must have batch ≤ 65,535 and heads ≤ 65,535. The temporal calls at the finest
level with a transformer set the bound: R ≤ 65,535 // (h_0·w_0). For SVD at a 4096-wide
panorama (896² views, 112² latent cells) that is 5 rows, 2 views with guidance; at 8192
(1792², 224²) it is 1 row, so the guided and unguided halves go in separate calls. The
H100 crash of 2026-11-22 was R = 2 × 10 views at 896²: 250,880 temporal sequences.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

# The largest grid y / z dimension of a CUDA kernel launch.
CUDA_GRID_LIMIT = 65_535


@dataclass(frozen=True)
class AttentionCall:
    """One shape of scaled_dot_product_attention call in a UNet forward."""

    block: str  # "down 0", "mid", "up 2", ...
    kind: str  # "spatial self", "spatial cross", "temporal self", "temporal cross"
    batch_per_row: int  # SDPA batch for one row of the UNet batch
    heads: int
    queries: int
    keys: int
    head_dim: int
    count: int  # calls of this shape in one forward

    def batch(self, rows: int) -> int:
        return rows * self.batch_per_row


def _per_block(value: int | Sequence[int], blocks: int) -> list[int]:
    return [int(value)] * blocks if isinstance(value, int) else [int(v) for v in value]


def attention_calls(
    config: Mapping[str, Any],
    latent_height: int,
    latent_width: int,
    frames: int,
    context_tokens: int = 1,
) -> list[AttentionCall]:
    """The SDPA calls one forward of a UNetSpatioTemporalConditionModel with ``config``
    makes on a ``latent_height`` × ``latent_width`` latent of ``frames`` frames, per row of
    its batch. ``context_tokens``: the encoder hidden states' length (SVD: one CLIP token)."""
    down = list(config["down_block_types"])
    up = list(config["up_block_types"])
    levels = len(down)
    channels = _per_block(config["block_out_channels"], levels)
    heads = _per_block(config["num_attention_heads"], levels)
    layers = _per_block(config["layers_per_block"], levels)
    depth = _per_block(config["transformer_layers_per_block"], levels)
    # Downsample2D (3×3 conv, stride 2, padding 1) gives ceil(h / 2) at each level.
    sizes = [(latent_height, latent_width)]
    for _ in range(levels - 1):
        h, w = sizes[-1]
        sizes.append(((h + 1) // 2, (w + 1) // 2))

    # (block name, level, transformers in the block, heads, transformer layers each)
    blocks = [
        (f"down {i}", i, layers[i], heads[i], depth[i])
        for i, kind in enumerate(down)
        if kind.startswith("CrossAttn")
    ]
    blocks.append(("mid", levels - 1, 1, heads[-1], depth[-1]))
    for i, kind in enumerate(up):
        level = levels - 1 - i
        if kind.startswith("CrossAttn"):
            # Up blocks have one layer more than their down twin, and reversed lists.
            blocks.append((f"up {i}", level, layers[level] + 1, heads[level], depth[level]))

    calls = []
    for name, level, transformers, n_heads, n_layers in blocks:
        h, w = sizes[level]
        cells = h * w
        head_dim = channels[level] // n_heads
        count = transformers * n_layers
        for kind, batch, queries, keys in (
            ("spatial self", frames, cells, cells),
            ("spatial cross", frames, cells, context_tokens),
            ("temporal self", cells, frames, frames),
            ("temporal cross", cells, frames, context_tokens),
        ):
            calls.append(AttentionCall(name, kind, batch, n_heads, queries, keys, head_dim, count))
    return calls


def max_unet_rows(
    config: Mapping[str, Any],
    latent_height: int,
    latent_width: int,
    frames: int,
    limit: int = CUDA_GRID_LIMIT,
) -> int:
    """The most rows one UNet call may take so that every attention call has an SDPA batch
    and a head count ≤ ``limit``; 0 when even one row exceeds it."""
    calls = attention_calls(config, latent_height, latent_width, frames)
    if any(call.heads > limit for call in calls):
        return 0
    return min(limit // call.batch_per_row for call in calls)
