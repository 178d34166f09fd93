"""Quality presets of the lifting phase on synthetic scenes with exact ground truth.

For each preset: train on a synthetic scene (the true animation stands in for the animating
phase, so the figures measure lifting alone), then measure wall time, novel-view PSNR/SSIM at
cameras displaced by 1 % and 5 % of the median scene depth, depth AbsRel of the aligned
depth against the true depth (raw, and after one median scale for relative backends), and
temporal flicker (mean |render_t − render_t−1| in the layout views, outside and inside the
moving region, the latter next to the true video's). Prints a table and writes
bench/out/quality.json.

    .venv/bin/python bench/quality.py [--kind landscape|room] [--presets draft balanced]
        [--width 1024] [--frames 4] [--depth file|layout] [--backend wgpu|torch]
        [--trainer resident|torch] [--overrides JSON] [--maps] [--resume]
        [--json bench/out/quality_<kind>.json]

``--overrides`` sets preset knobs for every preset run (as scene.yaml's ``overrides:``);
``--maps`` adds where the quality is lost (bench/quality_maps.py) to each row.
``--resume`` keeps an earlier, interrupted run's output folder, so that training picks up
where it was killed (the pipeline's checkpoints): a preset that does not fit one sitting on
this machine is measured in parts. Its row's ``wall_s`` is then the last part's; the stage
times (``timings_s``, summed over every part by the pipeline) and ``resumed_at`` give the
whole run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))

from pano4d import ply4d, synth
from pano4d.config import load_config
from pano4d.fsutil import write_json_atomic
from pano4d.images import read_depth, read_image, read_mask
from pano4d.lift.align import FrameAlignment, sphere_for_views
from pano4d.lift.trainers import trainer_for
from pano4d.resample import equirect_to_perspective, sphere_to_equirect
from pano4d.sphere import view_layout
from pano4d.synth.scene import SCENE_KINDS
from pano4d.train import run_train

OUT = Path(__file__).resolve().parent / "out"


def depth_absrel(output: Path, gt_depth: np.ndarray, cameras: list) -> dict[str, float]:
    """AbsRel of frame 0's aligned depth against the truth, sky excluded."""
    state = torch.load(output / "checkpoints" / "align.pt", map_location="cpu")
    first = FrameAlignment.from_dict(state["frames"][0])
    height, width = gt_depth.shape
    aligned = sphere_to_equirect(first.log_depth, sphere_for_views(cameras), width, height).exp()
    truth = torch.from_numpy(gt_depth)
    ground = truth < 0.99 * float(truth.max())
    pred, gt = aligned[ground], truth[ground]
    scaled = pred * (gt.median() / pred.median())
    return {
        "absrel": float(((pred - gt).abs() / gt).mean()),
        "absrel_median_scaled": float(((scaled - gt).abs() / gt).mean()),
    }


def flicker(scene: ply4d.Scene4D, frames: list[np.ndarray], mask: np.ndarray, backend: str) -> dict:
    """Mean absolute change between consecutive timestamps in the layout views."""
    from pano4d.renderer import render

    cams = view_layout(20, 80.0, 96)[::5]
    still, moving, truth = [], [], []
    with torch.no_grad():
        for cam in cams:
            inside = equirect_to_perspective(torch.from_numpy(mask).float(), cam) > 0.5
            renders = [
                render(scene.at(t), cam, backend=backend, antialiased=scene.antialiased).rgb
                for t in range(scene.num_times)
            ]
            gts = [
                equirect_to_perspective(torch.from_numpy(f).permute(2, 0, 1), cam).permute(1, 2, 0)
                for f in frames
            ]
            for t in range(1, len(renders)):
                change = (renders[t] - renders[t - 1]).abs().mean(-1)
                true_change = (gts[t] - gts[t - 1]).abs().mean(-1)
                still.append(float(change[~inside].mean()) if (~inside).any() else 0.0)
                if inside.any():
                    moving.append(float(change[inside].mean()))
                    truth.append(float(true_change[inside].mean()))
    return {
        "static": float(np.mean(still)),
        "moving": float(np.mean(moving)) if moving else 0.0,
        "moving_truth": float(np.mean(truth)) if truth else 0.0,
    }


def bench_preset(preset: str, args: argparse.Namespace) -> dict:
    root = OUT / "quality" / f"{args.kind}_w{args.width}_l{args.frames}_s{args.seed}"
    if not (root / "scene.yaml").is_file():
        scene = synth.make_scene(
            args.seed, args.width, args.width // 2, args.frames, views=8, kind=args.kind
        )
        synth.write_scene(root, scene)
    output = root / f"out_{preset}_{args.depth}{args.tag}"
    if output.exists() and not args.resume:
        shutil.rmtree(output)
    if not output.exists():
        shutil.copytree(root / "gt" / "frames", output / "animate" / "frames")
    cfg = load_config(root / "scene.yaml")
    update: dict = {"preset": preset, "output": output}
    if args.depth == "file":
        update["depth"] = cfg.depth.model_copy(
            update={"backend": "file", "path": root / "depth.exr"}
        )
    if args.overrides:
        update["overrides"] = json.loads(args.overrides)
    cfg = cfg.model_copy(update=update)
    start = time.perf_counter()
    metrics = run_train(cfg, progress=False, render_backend=args.backend, trainer=args.trainer)
    wall = time.perf_counter() - start
    scene = ply4d.read(output / "scene.ply4d")
    gt_depth = read_depth(root / "depth.exr")
    frames = [read_image(p)[..., :3] for p in sorted((root / "gt" / "frames").glob("*.png"))]
    mask = read_mask(root / "mask.png", args.width, args.width // 2)
    cameras = view_layout(cfg.lift.views, cfg.lift.fov_deg, int(metrics["knobs"]["view_size"]))
    views = metrics["novel_views"]["by_displacement"]
    maps = None
    if args.maps:
        from quality_maps import analyse

        from pano4d.renderer import render

        maps = analyse(
            root, output, int(metrics["working_size"][0]),
            lambda g, c: render(g, c, backend=args.backend, antialiased=scene.antialiased),
        )  # fmt: skip
    return {
        "preset": preset,
        "kind": args.kind,
        "overrides": json.loads(args.overrides) if args.overrides else {},
        "trainer": trainer_for(args.backend, args.trainer),
        "depth_backend": args.depth,
        "wall_s": wall,
        "timings_s": metrics["timings_s"],
        "resumed_at": metrics["resumed_at"],
        "gaussians_stored": metrics["gaussians"]["stored"],
        "size_bytes": metrics["size_bytes"],
        "psnr_1pct": views.get("1%", {}).get("psnr"),
        "ssim_1pct": views.get("1%", {}).get("ssim"),
        "psnr_5pct": views.get("5%", {}).get("psnr"),
        "ssim_5pct": views.get("5%", {}).get("ssim"),
        "depth": depth_absrel(output, gt_depth, cameras),
        "flicker": flicker(scene, frames, mask, args.backend),
        "saving": metrics["saving"],
        "novel_views": metrics["novel_views"]["views"],
        "maps": maps,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=sorted(SCENE_KINDS), default="landscape")
    parser.add_argument("--presets", nargs="+", default=["draft", "balanced"],
                        choices=["draft", "balanced", "max"])  # fmt: skip
    parser.add_argument("--width", type=int, default=1024)
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--depth", choices=["file", "layout"], default="file")
    parser.add_argument("--backend", choices=["wgpu", "torch"], default="wgpu")
    parser.add_argument("--trainer", choices=["resident", "torch"],
                        help="default: resident with wgpu, torch with --backend torch")  # fmt: skip
    parser.add_argument("--overrides", default="", help="JSON object of preset knobs")
    parser.add_argument("--tag", default="", help="suffix of the output folders' names")
    parser.add_argument("--maps", action="store_true", help="where the quality is lost")
    parser.add_argument("--resume", action="store_true",
                        help="go on from an interrupted run's checkpoints")  # fmt: skip
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    args.json = args.json or OUT / f"quality_{args.kind}.json"

    rows = [bench_preset(p, args) for p in args.presets]
    header = (f"{'preset':<9}{'wall s':>9}{'PSNR 1%':>9}{'SSIM 1%':>9}{'PSNR 5%':>9}"
              f"{'SSIM 5%':>9}{'AbsRel':>8}{'flick st':>9}{'flick mv':>9}{'gauss':>9}")  # fmt: skip
    print(header)
    for r in rows:
        print(
            f"{r['preset']:<9}{r['wall_s']:>9.1f}"
            f"{r['psnr_1pct'] or 0:>9.2f}{r['ssim_1pct'] or 0:>9.3f}"
            f"{r['psnr_5pct'] or 0:>9.2f}{r['ssim_5pct'] or 0:>9.3f}{r['depth']['absrel']:>8.3f}"
            f"{r['flicker']['static']:>9.4f}{r['flicker']['moving']:>9.4f}"
            f"{r['gaussians_stored']:>9}"
        )
    write_json_atomic(args.json, {
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "torch": torch.__version__, "cuda": torch.cuda.is_available()},
        "scene": {"kind": args.kind, "width": args.width, "frames": args.frames,
                  "seed": args.seed},
        "rows": rows,
    })  # fmt: skip
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
