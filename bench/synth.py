"""Speed of the synthetic scene generator (pano4d.synth).

For each panorama size: building the landscape, rendering the panorama + depth, the 13
further frames of an L = 14 loop (only the moving pixels are shaded again), and 8 views of
256×256. Prints a table and writes bench/out/synth.json.

    .venv/bin/python bench/synth.py [--sizes 1024 2048 4096] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))

from pano4d.fsutil import write_json_atomic
from pano4d.synth.landscape import Landscape
from pano4d.synth.scene import SynthFrames
from pano4d.synth.views import make_views, render_panorama

FRAMES = 14
VIEWS = 8
VIEW_SIZE = 256


def _timed(fn):  # type: ignore[no-untyped-def]
    start = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - start


def bench_size(width: int, seed: int) -> dict[str, float | int]:
    height = width // 2
    landscape, t_build = _timed(lambda: Landscape(seed, FRAMES))
    (pano, _depth, labels, hits, dirs), t_pano = _timed(
        lambda: render_panorama(landscape, width, height)
    )
    mask = landscape.moves(labels)
    moving = mask.view(-1).nonzero()[:, 0]
    frames = SynthFrames(landscape, pano, moving, dirs[moving], hits.subset(moving))
    _, t_frames = _timed(lambda: [frames[t] for t in range(1, FRAMES)])
    _, t_views = _timed(lambda: make_views(landscape, VIEWS, VIEW_SIZE))
    return {
        "width": width,
        "height": height,
        "landscape_s": round(t_build, 3),
        "panorama_depth_s": round(t_pano, 3),
        "frames_1_to_13_s": round(t_frames, 3),
        "views_s": round(t_views, 3),
        "moving_fraction": round(float(mask.float().mean()), 4),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1024, 2048, 4096])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rows = [bench_size(w, args.seed) for w in args.sizes]
    header = f"{'size':>11} {'landscape':>10} {'pano+depth':>11} {'13 frames':>10} {'8 views':>8}"
    print(header)
    for r in rows:
        print(
            f"{r['width']:>5}x{r['height']:<5} {r['landscape_s']:>9.2f}s"
            f" {r['panorama_depth_s']:>10.2f}s {r['frames_1_to_13_s']:>9.2f}s {r['views_s']:>7.2f}s"
        )
    out = Path(__file__).resolve().parent / "out" / "synth.json"
    write_json_atomic(
        out,
        {
            "frames": FRAMES,
            "views": VIEWS,
            "view_size": VIEW_SIZE,
            "torch_threads": torch.get_num_threads(),
            "cpu_count": os.cpu_count(),
            "load_average_1min_at_end": os.getloadavg()[0],
            "machine": platform.platform(),
            "results": rows,
        },
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
