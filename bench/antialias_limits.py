"""What limits an antialiased scene at ¼ of its training views' pixel density (issue #40):
the loss `bench/antialias.py` measures, taken apart on a scene it trained, and the same
question asked of a flat wall of Gaussians with no training at all.

For the trained scene (``--kind``, ``--preset``: `bench/antialias.py`'s output at its
default width, frames and seed), at its ground-truth cameras, drawn directly at ½ and ¼
density and drawn at full density and box-downsampled (the supersampled render), both
against the supersampled ground truth:

* ``coverage``: the loss again with the direct render's coverage set to the supersampled
  render's (colour / alpha × the box of the full render's alpha): what blending to a
  fainter or fuller pixel accounts for;
* ``filter shape``: the ground truth filtered by a Gaussian of the filter's variance and
  sampled at the small pixels' centres, against its box: what drawing a Gaussian filter
  instead of a box costs with no Gaussians involved;
* ``where``: the direct render's squared error beyond the supersampled render's, split
  between small pixels at a depth edge (log depth spans more than 0.5 inside the block) and
  the rest.

The wall: a flat textured wall of sub-pixel Gaussians (one layer; two layers stacked; one
layer spread 2 % in depth), drawn at ¼ and ½ density against its own supersampled render.

    .venv/bin/python bench/antialias_limits.py [--kind room] [--preset balanced]
        [--json bench/out/antialias_limits.json]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from antialias import OUT, box, full_density_size, mean, resized, scene_root

from pano4d import ply4d
from pano4d.camera import Camera
from pano4d.config import load_config
from pano4d.fsutil import write_json_atomic
from pano4d.gaussians import Gaussians, rgb_to_sh_dc
from pano4d.lift.export import read_gt_views
from pano4d.metrics import psnr
from pano4d.renderer import render
from pano4d.synth.scene import SCENE_KINDS
from pano4d.synth.views import render_view

FILTER_VARIANCE = 0.1  # the antialiased mode's 2D filter, px² (docs/rasterizer.md)
EDGE_LOG_DEPTH = 0.5  # a small pixel whose block spans more than this in log depth is an edge
FINER = 4  # the filter-shape check filters a truth drawn this much finer than full density


def gaussian_sampled(fine: torch.Tensor, step: int, variance: float) -> torch.Tensor:
    """(H, W, 3) ``fine`` blurred by a Gaussian of ``variance`` px² of the small image
    (``step`` fine pixels a small pixel) and sampled at the small pixels' centres."""
    sigma = math.sqrt(variance) * step
    radius = math.ceil(4 * sigma)
    x = torch.arange(-radius, radius + 1, dtype=torch.float64)
    w = torch.exp(-0.5 * (x / sigma) ** 2)
    w = (w / w.sum()).to(fine.dtype)
    c = fine.permute(2, 0, 1)[:, None]
    c = F.conv2d(F.pad(c, (radius, radius, 0, 0), mode="replicate"), w.view(1, 1, 1, -1))
    c = F.conv2d(F.pad(c, (0, 0, radius, radius), mode="replicate"), w.view(1, 1, -1, 1))[:, 0]
    centre = step // 2  # a small pixel's centre falls between two fine pixels
    c = 0.5 * (c[:, centre - 1 :: step] + c[:, centre::step])
    c = 0.5 * (c[:, :, centre - 1 :: step] + c[:, :, centre::step])
    return c.permute(1, 2, 0)


def trained_scene(kind: str, preset: str) -> dict[str, Any]:
    root = scene_root(kind, 1024, 2, 0)  # antialias.py's defaults
    output = root / f"out_{preset}_antialiased"
    if not (output / "scene.ply4d").is_file():
        print(f"error: {output}/scene.ply4d: no such scene; run bench/antialias.py --kinds "
              f"{kind} --presets {preset} first", file=sys.stderr)  # fmt: skip
        sys.exit(2)
    scene = ply4d.read(output / "scene.ply4d")
    world = SCENE_KINDS[kind](0, 2)
    views = read_gt_views(root / "panorama.png")
    knobs = json.loads((output / "metrics.json").read_text())["knobs"]
    fov = load_config(root / "scene.yaml").lift.fov_deg
    side = full_density_size(views[0]["camera"], knobs, fov)
    ks = (2, 4)
    direct: dict[int, list[float]] = {k: [] for k in ks}
    supersampled: dict[int, list[float]] = {k: [] for k in ks}
    coverage_set: dict[int, list[float]] = {k: [] for k in ks}
    shape: dict[int, list[float]] = {k: [] for k in ks}
    excess = {k: {"edge": 0.0, "rest": 0.0} for k in ks}
    pixels = {k: {"edge": 0, "rest": 0} for k in ks}
    for v in views:  # what does not depend on k, drawn and ray-cast once a view
        t = min(int(v["time"]), scene.num_times - 1)
        g = scene.at(t)
        full = resized(v["camera"], side, side)
        with torch.no_grad():
            drawn = render(g, full, antialiased=True)
        truth = render_view(world, full, t)[0]
        fine = render_view(world, resized(v["camera"], side * FINER, side * FINER), t)[0]
        drawn_rgb = drawn.rgb.clamp(0, 1).cpu()
        log_depth = drawn.depth.cpu().clamp(min=1e-3).log()
        for k in ks:
            with torch.no_grad():
                small = render(g, resized(v["camera"], side // k, side // k), antialiased=True)
            ideal = box(truth, k)
            rgb = small.rgb.clamp(0, 1).cpu()
            box_rgb = box(drawn_rgb, k)
            box_alpha = box(drawn.alpha.cpu()[..., None], k)
            covered = rgb / small.alpha.cpu().clamp(min=1e-6)[..., None] * box_alpha
            direct[k].append(psnr(rgb, ideal))
            supersampled[k].append(psnr(box_rgb, ideal))
            coverage_set[k].append(psnr(covered.clamp(0, 1), ideal))
            shape[k].append(psnr(gaussian_sampled(fine, k * FINER, FILTER_VARIANCE),
                                 box(fine, k * FINER)))  # fmt: skip
            blocks = log_depth.unfold(0, k, k).unfold(1, k, k)
            edge = (blocks.amax((-1, -2)) - blocks.amin((-1, -2))) > EDGE_LOG_DEPTH
            more = ((rgb - ideal) ** 2).mean(-1) - ((box_rgb - ideal) ** 2).mean(-1)
            for name, where in (("edge", edge), ("rest", ~edge)):
                excess[k][name] += float(more[where].sum())
                pixels[k][name] += int(where.sum())
    rows: dict[str, Any] = {}
    for k in ks:
        total = sum(excess[k].values())
        rows[f"1/{k}"] = {
            "loss_db": mean(supersampled[k]) - mean(direct[k]),
            "loss_with_coverage_set_db": mean(supersampled[k]) - mean(coverage_set[k]),
            "gaussian_filter_vs_box_db": mean(shape[k]),
            "edge_pixel_share": pixels[k]["edge"] / sum(pixels[k].values()),
            "edge_excess_share": excess[k]["edge"] / total if total else math.nan,
        }  # fmt: skip
        r = rows[f"1/{k}"]
        print(f"{kind} {preset} 1/{k}: loss {r['loss_db']:.2f} dB, "
              f"{r['loss_with_coverage_set_db']:.2f} with the coverage set; a Gaussian filter "
              f"against a box on the truth {r['gaussian_filter_vs_box_db']:.1f} dB; edges "
              f"{r['edge_pixel_share']:.0%} of the pixels, {r['edge_excess_share']:.0%} of "
              f"the excess error", flush=True)  # fmt: skip
    return rows


def wall(
    depth: float, spacing_px: float, focal: float, seed: int, spread: float = 0.0
) -> Gaussians:
    """A wall of Gaussians facing the camera at ``depth``, one every ``spacing_px`` pixels of
    a ``focal`` camera (jittered), σ 0.7 of the spacing, opacity 0.95, a texture of stripes
    and noise; ``spread``: the depths spread over that fraction of ``depth``."""
    rng = torch.Generator().manual_seed(seed)
    step = spacing_px * depth / focal
    xs = torch.arange(-1.05 * depth, 1.05 * depth, step)
    x, y = torch.meshgrid(xs, xs, indexing="ij")
    n = x.numel()
    jitter = (torch.rand(n, 2, generator=rng) - 0.5) * step
    z = depth + spread * depth * torch.rand(n, generator=rng)
    means = torch.stack([x.flatten() + jitter[:, 0], y.flatten() + jitter[:, 1], z], -1)
    s = math.log(0.7 * step)
    stripes = torch.sin(means[:, :1] * 3 / depth * torch.tensor([1.0, 1.7, 2.3]))
    colour = (0.5 + 0.3 * stripes + 0.15 * torch.rand(n, 3, generator=rng)).clamp(0, 1)
    return Gaussians(
        means,
        torch.tensor([s, s, s - 2.3]).expand(n, 3).clone(),  # thin discs, as trained ones are
        torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n, 4).clone(),
        torch.full((n,), math.log(0.95 / 0.05)),
        rgb_to_sh_dc(colour)[:, None],
    )


def walls() -> dict[str, Any]:
    side = 128
    focal = side / 2.0  # 90°
    K = torch.tensor([[focal, 0, side / 2], [0, focal, side / 2], [0, 0, 1]])
    camera = Camera(K, torch.eye(4), side, side)

    def self_consistency(g: Gaussians, k: int) -> float:
        with torch.no_grad():
            full = render(g, camera, antialiased=True).rgb.clamp(0, 1)
            small = render(g, resized(camera, side // k, side // k), antialiased=True)
        return psnr(small.rgb.clamp(0, 1), box(full, k))

    rows: dict[str, Any] = {}
    for spacing in (0.5, 1.0, 2.0):
        kinds = {
            "one layer": wall(5.0, spacing, focal, 0),
            "two layers": Gaussians.cat(
                [wall(5.0, spacing, focal, 0), wall(5.05, spacing, focal, 1)]
            ),
            "one layer 2 % deep": wall(5.0, spacing / math.sqrt(2), focal, 0, spread=0.02),
        }
        row = {name: {f"1/{k}": self_consistency(g, k) for k in (2, 4)}
               for name, g in kinds.items()}  # fmt: skip
        rows[f"{spacing:g} px"] = row
        print(f"wall, a Gaussian every {spacing:g} px: direct against its own supersampled "
              "render at ½ / ¼: " + "; ".join(f"{n} {r['1/2']:.1f} / {r['1/4']:.1f} dB"
                                              for n, r in row.items()), flush=True)  # fmt: skip
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", default="room")
    parser.add_argument("--preset", default="balanced")
    parser.add_argument("--json", type=Path, default=OUT / "antialias_limits.json")
    args = parser.parse_args()
    result = {
        "date": time.strftime("%Y-%m-%d %H:%M:%S"), "machine": platform.platform(),
        "args": {k: str(v) for k, v in vars(args).items()},
        "trained": trained_scene(args.kind, args.preset), "walls": walls(),
    }  # fmt: skip
    write_json_atomic(args.json, result)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
