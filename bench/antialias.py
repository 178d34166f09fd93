"""A scene at fewer pixels than it was trained at: the rasteriser's classic mode against the
antialiased one (issue #40), side by side in one run on synthetic scenes with exact ground truth.

For each kind and preset, one scene is trained twice from the same inputs, ``antialiased:
false`` (the classic mode: 3DGS's 0.3 px² dilation alone, what every scene before this mode
was trained in) and ``antialiased: true``, one right after the other. Then, at the scene's
ground-truth cameras (displaced 1 % and 5 % of the median depth):

* at ``1/k`` of the training views' pixel density (k = 1, 2, 4): the render drawn directly
  at that size against the ground truth ray-cast at that size, and the render drawn at full
  density and box-downsampled k× against the ground truth drawn and downsampled the same
  way. ``aliasing_db`` is the second PSNR minus the first: what drawing at the smaller size
  loses to drawing more pixels and averaging them (issue #40's target: ≤ 0.3 dB at ½, ¼);
* novel-view PSNR at 1 % and 5 % (metrics.json: the training views' own size);
* the static and dynamic stages' seconds (metrics.json), so the cost per step is compared
  within the pair;
* for the antialiased scene, ``pano4d export``'s .ply (the filter baked in for classic
  viewers) drawn classic, against the scene drawn antialiased, at the training views.

    .venv/bin/python bench/antialias.py [--kinds landscape room] [--presets draft balanced]
        [--balanced-iterations 200] [--width 1024] [--frames 2] [--json bench/out/antialias.json]

``--balanced-iterations`` runs balanced at that many optimisation steps (200: a tenth).
"""

from __future__ import annotations

import argparse
import math
import platform
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))

from pano4d import ply4d, synth
from pano4d.camera import Camera, focal_length
from pano4d.config import load_config
from pano4d.fsutil import write_json_atomic
from pano4d.gaussians import Gaussians
from pano4d.lift.export import read_gt_views
from pano4d.metrics import psnr
from pano4d.renderer import render
from pano4d.sphere import view_layout
from pano4d.synth.scene import SCENE_KINDS
from pano4d.synth.views import render_view
from pano4d.train import run_train

OUT = Path(__file__).resolve().parent / "out"
DENSITIES = (1, 2, 4)  # 1/k of the training views' pixel density
FILTER_3D = 0.2  # Mip-Splatting's 3D filter variance, in training pixels²
MODES = {"classic": False, "antialiased": True}


def resized(camera: Camera, width: int, height: int) -> Camera:
    """``camera``'s pose and field of view at another pixel size (square pixels kept)."""
    s = width / camera.width
    K = camera.K.clone()
    K[:2] *= s
    return Camera(K, camera.world_to_cam, width, height)


def box(image: torch.Tensor, k: int) -> torch.Tensor:
    """(H, W, 3) averaged over k×k blocks."""
    return F.avg_pool2d(image.permute(2, 0, 1)[None], k)[0].permute(1, 2, 0)


def full_density_size(view: Camera, knobs: dict[str, Any], fov_deg: float) -> int:
    """The side of ``view`` (square) whose pixels subtend what a training view's do: the
    training views have ``view_size`` pixels over ``fov_deg``; a multiple of 4, so that ½
    and ¼ are whole pixels."""
    focal = focal_length(fov_deg, knobs["view_size"])
    side = focal * view.width / float(view.fx)  # the gt view's 2·tan(fov/2), times that focal
    return max(4, round(side / 4) * 4)


def mean(values: list[float]) -> float:
    return sum(values) / len(values)


def aliasing(scene: ply4d.Scene4D, world: Any, views: list[dict], side: int) -> dict[str, Any]:
    """Per density: PSNR drawn directly and supersampled (both against ground truth made
    the same way) and their difference, mean over ``views``."""
    keys = ("direct", "supersampled", "direct_vs_box", "self_consistent")
    scores: dict[int, dict[str, list[float]]] = {k: {key: [] for key in keys} for k in DENSITIES}
    for v in views:
        t = min(int(v["time"]), scene.num_times - 1)
        g = scene.at(t)
        # The full-density render and truth, once a view: every density box-filters them.
        full = resized(v["camera"], side, side)
        with torch.no_grad():
            drawn_full = render(g, full, antialiased=scene.antialiased).rgb.clamp(0, 1).cpu()
        truth_full = render_view(world, full, t)[0]
        for k in DENSITIES:
            small = resized(v["camera"], side // k, side // k)
            with torch.no_grad():
                drawn_small = render(g, small, antialiased=scene.antialiased).rgb.clamp(0, 1)
            truth_small = render_view(world, small, t)[0]
            ideal = box(truth_full, k)
            supersampled_render = box(drawn_full, k)
            at = scores[k]
            at["direct"].append(psnr(drawn_small.cpu(), truth_small))
            at["supersampled"].append(psnr(supersampled_render, ideal))
            at["direct_vs_box"].append(psnr(drawn_small.cpu(), ideal))
            at["self_consistent"].append(psnr(drawn_small.cpu(), supersampled_render))
    rows: dict[str, Any] = {}
    for k, at in scores.items():
        d, s = mean(at["direct"]), mean(at["supersampled"])
        rows[f"1/{k}"] = {
            "size": side // k, "direct_db": d, "supersampled_db": s, "aliasing_db": s - d,
            # against one truth, the supersampled one (what a pixel of that size should show)
            "direct_vs_supersampled_truth_db": mean(at["direct_vs_box"]),
            "aliasing_vs_supersampled_truth_db": s - mean(at["direct_vs_box"]),
            # no truth at all: the direct render against the scene's own supersampled render
            "direct_vs_own_supersampled_db": mean(at["self_consistent"]),
        }  # fmt: skip
    return rows


def with_3d_filter(g: Gaussians, position: torch.Tensor, focal: float) -> Gaussians:
    """Mip-Splatting's 3D smoothing filter applied to a trained set: each Gaussian's
    covariance grown by ``FILTER_3D`` × (its distance / the training views' focal)² (the
    square of a training pixel's size where it stands; every training view looks out from
    ``position``), its opacity scaled by sqrt(det Σ / det Σ_filtered) so that its integral
    is kept. Applied after training, not trained with: the cheap half of the comparison."""
    distance = torch.linalg.norm(g.means.double() - position, dim=-1).clamp(min=1e-6)
    grow = FILTER_3D * (distance / focal) ** 2
    scales2 = (2 * g.log_scales.double()).exp()  # the covariance's eigenvalues
    filtered = scales2 + grow[:, None]
    factor = torch.sqrt((scales2 / filtered).prod(dim=-1))
    opacity = (torch.sigmoid(g.opacity_logits.double()) * factor).clamp(1e-12, 1 - 1e-7)
    return replace(g, log_scales=(0.5 * filtered.log()).float(),
                   opacity_logits=torch.logit(opacity).float())  # fmt: skip


def export_fidelity(output: Path, scene: ply4d.Scene4D, knobs: dict, cfg: Any) -> float | None:
    """PSNR of ``pano4d export``'s .ply (timestamp 0) drawn classic, as other viewers draw
    it, against the scene drawn in its own mode, over the training views."""
    from pano4d import share_formats

    ply = output / "export_t0.ply"
    share_formats.export(output / "scene.ply4d", ply, "ply", 0)
    exported = ply4d.read_ply(ply)
    ours = scene.at(0)
    cams = view_layout(cfg.lift.views, cfg.lift.fov_deg, int(knobs["view_size"]))
    squared, count = 0.0, 0
    with torch.no_grad():
        for cam in cams:
            a = render(exported, cam, antialiased=False).rgb.clamp(0, 1)
            b = render(ours, cam, antialiased=scene.antialiased).rgb.clamp(0, 1)
            squared += float(((a - b) ** 2).sum())
            count += a.numel()
    mse = squared / max(count, 1)
    return 10 * math.log10(1 / mse) if mse > 0 else math.inf


def scene_root(kind: str, width: int, frames: int, seed: int) -> Path:
    """Where a kind's synthetic scene and its trained pairs live."""
    return OUT / "antialias" / f"{kind}_w{width}_l{frames}_s{seed}"


def train_pair(kind: str, preset: str, args: argparse.Namespace) -> list[dict[str, Any]]:
    root = scene_root(kind, args.width, args.frames, args.seed)
    if not (root / "scene.yaml").is_file():
        made = synth.make_scene(
            args.seed, args.width, args.width // 2, args.frames, views=8, kind=kind
        )
        synth.write_scene(root, made)
    world = SCENE_KINDS[kind](args.seed, args.frames)  # the ground truth's ray caster
    views = read_gt_views(root / "panorama.png")
    rows = []
    for mode, antialiased in MODES.items():
        output = root / f"out_{preset}_{mode}"
        if output.exists():
            shutil.rmtree(output)
        shutil.copytree(root / "gt" / "frames", output / "animate" / "frames")
        overrides: dict[str, Any] = {"antialiased": antialiased}
        if preset == "balanced" and args.balanced_iterations:
            overrides["gaussian_iterations"] = args.balanced_iterations
        cfg = load_config(root / "scene.yaml").model_copy(
            update={"preset": preset, "output": output, "overrides": overrides}
        )
        start = time.perf_counter()
        metrics = run_train(cfg, progress=False)
        wall = time.perf_counter() - start
        scene = ply4d.read(output / "scene.ply4d")
        by = metrics["novel_views"]["by_displacement"]
        knobs = metrics["knobs"]
        side = full_density_size(views[0]["camera"], knobs, cfg.lift.fov_deg)
        row = {
            "kind": kind, "preset": preset, "mode": mode, "overrides": overrides,
            "wall_s": wall, "timings_s": metrics["timings_s"],
            "gaussians_stored": metrics["gaussians"]["stored"],
            "psnr_1pct": by.get("1%", {}).get("psnr"), "psnr_5pct": by.get("5%", {}).get("psnr"),
            "fit_psnr": metrics["training_fit"]["fit_psnr"], "full_density_side": side,
            "densities": aliasing(scene, world, views, side),
            "export_psnr": export_fidelity(output, scene, knobs, cfg) if antialiased else None,
        }  # fmt: skip
        print(summary_line(row), flush=True)
        rows.append(row)
        if antialiased:  # the 2D filter with Mip-Splatting's 3D filter added, after training
            focal = focal_length(cfg.lift.fov_deg, knobs["view_size"])
            position = torch.tensor(scene.camera["position"], dtype=torch.float64)
            filtered = replace(
                scene,
                static=with_3d_filter(scene.static, position, focal),
                dynamic=[with_3d_filter(g, position, focal) for g in scene.dynamic],
            )
            row3d = {**row, "mode": "antialiased+3D", "export_psnr": None,
                     "densities": aliasing(filtered, world, views, side),
                     "novel_views_psnr": novel_psnr(filtered, views)}  # fmt: skip
            row["novel_views_psnr"] = novel_psnr(scene, views)
            print(summary_line(row3d), flush=True)
            rows.append(row3d)
    return rows


def novel_psnr(scene: ply4d.Scene4D, views: list[dict]) -> dict[str, float]:
    """Mean PSNR at the ground-truth cameras by displacement, at their own size."""
    by: dict[str, list[float]] = {}
    for v in views:
        t = min(int(v["time"]), scene.num_times - 1)
        with torch.no_grad():
            rgb = render(scene.at(t), v["camera"], antialiased=scene.antialiased).rgb
        key = f"{100 * float(v['displacement_fraction']):g}%"
        by.setdefault(key, []).append(psnr(rgb.clamp(0, 1).cpu(), v["pixels"]))
    return {k: mean(p) for k, p in by.items()}


def summary_line(row: dict[str, Any]) -> str:
    d = row["densities"]
    t = row["timings_s"]
    export = f"  export {row['export_psnr']:.2f} dB" if row["export_psnr"] is not None else ""
    return (
        f"{row['kind']:>9} {row['preset']:>8} {row['mode']:>11}  "
        f"1% {row['psnr_1pct']:.2f} 5% {row['psnr_5pct']:.2f}  "
        + "  ".join(f"{k}: {v['direct_db']:.2f}/{v['supersampled_db']:.2f} "
                    f"({v['aliasing_db']:+.2f}, {v['aliasing_vs_supersampled_truth_db']:+.2f}; "
                    f"self {v['direct_vs_own_supersampled_db']:.1f})"
                    for k, v in d.items() if k != "1/1")
        + f"  static {t.get('static', 0):.1f}s dynamic {t.get('dynamic', 0):.1f}s{export}"
    )  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kinds", nargs="+", default=["landscape", "room"])
    parser.add_argument("--presets", nargs="+", default=["draft", "balanced"])
    parser.add_argument("--balanced-iterations", type=int, default=200)
    parser.add_argument("--width", type=int, default=1024)
    parser.add_argument("--frames", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=OUT / "antialias.json")
    args = parser.parse_args()
    rows = []
    for kind in args.kinds:
        for preset in args.presets:
            rows += train_pair(kind, preset, args)
            # After each pair: a balanced pair is most of an hour here, and a run cut short
            # keeps what it measured.
            write_json_atomic(args.json, {
                "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads",
                "args": {k: str(v) for k, v in vars(args).items()}, "rows": rows,
            })  # fmt: skip
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
