"""Tiled encoding and decoding of equirect images and latents, so memory stays bounded.

A VAE over a whole 4096×2048 frame needs tens of GB of activations; over a tile of a few
hundred pixels it needs a few hundred MB, whatever the panorama's size. ``tiled_equirect``
cuts the grid into tiles (cores of about ``tile`` cells), gives every tile ``overlap``
cells of context on each side — taken across the 0°/360° seam (columns wrap) and over the
poles (a row beyond a pole is the same row half a turn round) — runs the network on it, and
blends neighbours with linear ramps inside their shared 2·overlap band, giving no weight to
the outer overlap/2 of a tile (where a network sees its padding), so no seam shows; an
operator that reads at most overlap/2 cells around a cell is reproduced exactly. The
blended result is gathered on ``out_device`` (the host by default); the accelerator only
ever holds a tile.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import torch


def _pole_padded(grid: torch.Tensor, pad: int) -> torch.Tensor:
    """Pad rows by ``pad`` beyond each pole (rows continue half a turn round)."""
    if pad == 0:
        return grid
    width = grid.shape[-1]
    top = torch.roll(torch.flip(grid[..., :pad, :], [-2]), width // 2, dims=-1)
    bottom = torch.roll(torch.flip(grid[..., -pad:, :], [-2]), width // 2, dims=-1)
    return torch.cat([top, grid, bottom], dim=-2)


def _cores(size: int, tile: int, align: int) -> list[int]:
    """Edges of near-equal cores of at most ~``tile`` cells, on multiples of ``align``."""
    count = max(1, math.ceil(size / tile))
    edges = [round(k * size / count / align) * align for k in range(count + 1)]
    edges[-1] = size
    return sorted(set(edges))


def _ramp(length: int, overlap: int, device: torch.device) -> torch.Tensor:
    """Weights (length,) of a tile with ``overlap`` cells of context at each end: 0 over the
    outer overlap/2 (where a network sees the tile border), rising linearly over the next
    ``overlap`` cells to 1. Two neighbours share 2·overlap cells and their ramps sum to 1."""
    i = torch.arange(length, device=device, dtype=torch.float32) + 0.5
    distance = torch.minimum(i, length - i)
    if overlap == 0:
        return torch.ones_like(i)
    return ((distance - overlap / 2) / overlap).clamp(0.0, 1.0)


def tiled_equirect(
    fn: Callable[[torch.Tensor], torch.Tensor],
    grid: torch.Tensor,
    up: int = 1,
    down: int = 1,
    tile: int = 64,
    overlap: int = 8,
    out_device: torch.device | str = "cpu",
) -> torch.Tensor:
    """Apply ``fn`` to an equirect grid (..., C, h, w) tile by tile.

    ``fn`` maps (..., C, th, tw) to (..., C', th·up/down, tw·up/down) (a decoder: up = 8;
    an encoder: down = 8); tile cores and the overlap are in input cells and are rounded
    to multiples of ``down``. Returns (..., C', h·up/down, w·up/down) float32 on
    ``out_device``.
    """
    height, width = grid.shape[-2:]
    if height % down or width % down:
        raise ValueError(f"grid {width}x{height} is not divisible by the tile stride {down}")
    if width % 2:
        raise ValueError(f"an equirect grid has an even width, got {width}")
    overlap = min(math.ceil(overlap / down) * down, (height // down) * down)
    out_overlap = overlap * up // down
    padded = _pole_padded(grid, overlap)
    out_h, out_w = height * up // down, width * up // down
    out = None
    total = torch.zeros(out_h, out_w, device=out_device)
    row_edges, col_edges = _cores(height, tile, down), _cores(width, tile, down)
    for r0, r1 in itertools.pairwise(row_edges):
        rows = slice(r0, r1 + 2 * overlap)  # padded coordinates
        for c0, c1 in itertools.pairwise(col_edges):
            cols = torch.arange(c0 - overlap, c1 + overlap, device=grid.device) % width
            piece = fn(padded[..., rows, :][..., cols])
            th, tw = piece.shape[-2:]
            expected = ((r1 - r0 + 2 * overlap) * up // down, (c1 - c0 + 2 * overlap) * up // down)
            if (th, tw) != expected:
                raise ValueError(f"tile function returned {th}x{tw} cells, expected {expected}")
            weight = (
                _ramp(th, out_overlap, piece.device)[:, None]
                * _ramp(tw, out_overlap, piece.device)[None]
            )
            # Place the tile: its first row is (r0 − overlap)·up/down, wrapped columns.
            out_r0 = (r0 - overlap) * up // down
            keep_r = slice(max(0, -out_r0), min(th, out_h - out_r0))
            out_rows = slice(out_r0 + keep_r.start, out_r0 + keep_r.stop)
            out_cols = torch.arange(tw, device=out_device) + (c0 - overlap) * up // down
            out_cols = out_cols % out_w
            weighted = (piece.float() * weight)[..., keep_r, :].to(out_device)
            if out is None:
                out = torch.zeros(*piece.shape[:-2], out_h, out_w, device=out_device)
            out[..., out_rows, :].index_add_(-1, out_cols, weighted)
            total[out_rows].index_add_(-1, out_cols, weight[keep_r].to(out_device))
    assert out is not None
    return out / total
