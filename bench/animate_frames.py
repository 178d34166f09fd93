"""The animating phase (backend flow) before and after its frames became the moving box.

For each scene, the phase of this checkout's HEAD commit and that of a base commit
(default e8560f2, the last one writing whole 16-bit PNG frames) run alternately, each in
its own process with its own sources, on the same scene.yaml: the phase's wall time (and
within it the preview video and metrics, which read every frame back), the bytes it
writes, and the time the lifting phase's ``read_frames`` (what ``prepare`` does) takes to
read the frames back at the working resolution of the draft preset. Then the two outputs
are compared: every whole frame and every downsampled frame must be equal bit for bit.

Scenes: the lake (``/work/shared/data/pano_lake.jpg``, 4096×2048, the README's box over
the water) and a synthetic landscape (``pano4d synth``, its own mask). Prints a table and
writes bench/out/animate_frames.json.

    .venv/bin/python bench/animate_frames.py [--frames 14] [--scenes lake synth]
        [--base e8560f2] [--repeats 1] [--synth-width 2048]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "python"))

from pano4d.animate.frames import FrameStore  # noqa: E402
from pano4d.fsutil import write_json_atomic  # noqa: E402
from pano4d.images import read_image  # noqa: E402
from pano4d.synth import run_synth  # noqa: E402

LAKE = Path("/work/shared/data/pano_lake.jpg")
LAKE_REGION = "  - box: [1950, 1050, 4000, 1350]\n    motion: {direction_deg: 0.0, speed: 0.3}\n"

# Run in a fresh process whose PYTHONPATH holds one variant's sources: the phase, then the
# lifting phase's frame reading, timed; the downsampled frames are saved for the comparison.
DRIVER = r"""
import json, os, sys, time
from pathlib import Path
import torch
from pano4d.animate import pipeline
from pano4d.config import load_config
from pano4d.lift import pipeline as lift

cfg = load_config(sys.argv[1])
measured = {}
write_video_and_measure = pipeline._write_video_and_measure
def timed(*args, **kwargs):
    start = time.perf_counter()
    try:
        return write_video_and_measure(*args, **kwargs)
    finally:
        measured["video_and_metrics_s"] = time.perf_counter() - start
pipeline._write_video_and_measure = timed
start = time.perf_counter()
pipeline.run_animate(cfg, progress=False)
animate_s = time.perf_counter() - start
folder = Path(cfg.output) / "animate"
frames_dir = folder / ("moving" if (folder / "moving").is_dir() else "frames")
written = {p.name: p.stat().st_size for p in frames_dir.iterdir() if not p.name.startswith(".")}
suffix = ".exr" if cfg.panorama.suffix.lower() == ".exr" else ".png"
width = int(sys.argv[3])
size = lift.working_size(width, cfg.resolved_preset(width).view_size, cfg.lift.fov_deg)
start = time.perf_counter()
frames = lift.read_frames(frames_dir, cfg.animate.frames, size, suffix)
read_s = time.perf_counter() - start
torch.save(frames, sys.argv[2])
print(json.dumps({"animate_s": animate_s, "read_frames_s": read_s, "working_size": size,
                  "frames_dir": str(frames_dir), "frame_bytes": sum(written.values()),
                  "files": len(written),
                  "video_bytes": (folder / "video.mp4").stat().st_size, **measured}))
"""


def commit_sources(commit: str, into: Path) -> Path:
    """A commit's python/ tree, exported (no worktree registered in the repository), with
    this checkout's compiled extension: edits made while the benchmark runs do not leak in."""
    target = into / f"sources-{commit}"
    if not (target / "python" / "pano4d").is_dir():
        target.mkdir(parents=True, exist_ok=True)
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", commit, "python"], check=True, capture_output=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", str(target)], input=archive, check=True)
        for so in (ROOT / "python" / "pano4d").glob("_core*.so"):
            (target / "python" / "pano4d" / so.name).write_bytes(so.read_bytes())
    return target / "python"


def scene_yaml(folder: Path, name: str, frames: int, synth_width: int) -> tuple[Path, int]:
    """A scene.yaml for ``name`` (its output key left for each variant) and its width."""
    folder.mkdir(parents=True, exist_ok=True)
    if name == "lake":
        text = f"panorama: {LAKE}\nregions:\n{LAKE_REGION}"
        text += f"animate: {{backend: flow, frames: {frames}}}\npreset: draft\n"
        path = folder / "scene.yaml"
        path.write_text(text)
        return path, 4096
    if name == "synth":
        path = run_synth(folder / "synth", synth_width, synth_width // 2, frames, 0, 2)
        return Path(path), synth_width
    raise ValueError(f"unknown scene {name!r}")


def run_variant(
    sources: Path, yaml: Path, output: Path, width: int, saved: Path
) -> dict[str, Any]:
    """One variant's phase on ``yaml`` with its output in ``output``."""
    config = yaml.with_name(f"scene-{output.name}.yaml")
    lines = yaml.read_text().splitlines()
    text = "\n".join(line for line in lines if not line.startswith("output"))
    config.write_text(f"{text}\noutput: {output}\n")
    env = {**os.environ, "PYTHONPATH": str(sources)}
    load_before = os.getloadavg()[0]
    done = subprocess.run(
        [sys.executable, "-c", DRIVER, str(config), str(saved), str(width)],
        env=env, capture_output=True, text=True, check=False,
    )  # fmt: skip
    if done.returncode != 0:
        raise RuntimeError(f"{sources}: the phase failed:\n{done.stderr[-3000:]}")
    row = json.loads(done.stdout.strip().splitlines()[-1])
    row["load_1min"] = [round(load_before, 2), round(os.getloadavg()[0], 2)]
    return row


def same_frames(base: Path, mine: Path, frames: int, suffix: str) -> bool:
    """Every whole frame of the base run equals this run's composed frame, bit for bit."""
    store = FrameStore(mine, frames, suffix)
    for t, frame in enumerate(store.frames()):
        old = read_image(base / f"{t:04d}{suffix}")[:, :, :3]
        if not np.array_equal(old.view(np.uint32), frame.view(np.uint32)):
            return False
    return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=14)
    parser.add_argument("--scenes", nargs="+", default=["lake", "synth"])
    parser.add_argument("--base", default="e8560f2")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--synth-width", type=int, default=2048)
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "out" / "animate_frames.json")
    args = parser.parse_args()

    work = Path(tempfile.mkdtemp(prefix="animate-frames-"))
    head = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
        check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip
    variants = {"base": commit_sources(args.base, work), "box": commit_sources(head, work)}
    results: dict[str, Any] = {}
    print(f"animate (flow) {args.frames} frames: base {args.base} against {head} (HEAD)")
    print(f"{'scene':>6} {'variant':>7} {'animate s':>10} {'video+metrics s':>16} "
          f"{'read_frames s':>14} {'frame MB':>9} {'files':>6} {'load':>11}")  # fmt: skip
    for index, name in enumerate(args.scenes):
        yaml, width = scene_yaml(work / name, name, args.frames, args.synth_width)
        rows: dict[str, list[dict[str, Any]]] = {"base": [], "box": []}
        saved: dict[str, Path] = {}
        for repeat in range(args.repeats):
            order = ["base", "box"] if (index + repeat) % 2 == 0 else ["box", "base"]
            for variant in order:
                output = work / name / f"out-{variant}-{repeat}"
                saved[variant] = work / name / f"{variant}.pt"
                row = run_variant(variants[variant], yaml, output, width, saved[variant])
                rows[variant].append(row)
                load = "→".join(f"{x:.1f}" for x in row["load_1min"])
                print(f"{name:>6} {variant:>7} {row['animate_s']:10.1f} "
                      f"{row['video_and_metrics_s']:16.1f} {row['read_frames_s']:14.2f} "
                      f"{row['frame_bytes'] / 1e6:9.1f} {row['files']:6d} {load:>11}",
                      flush=True)  # fmt: skip
        base_row, box_row = rows["base"][-1], rows["box"][-1]
        equal_whole = same_frames(
            Path(base_row["frames_dir"]), Path(box_row["frames_dir"]), args.frames, ".png"
        )
        equal_read = torch.equal(torch.load(saved["base"]), torch.load(saved["box"]))
        best = {v: min(r["animate_s"] for r in rows[v]) for v in rows}
        results[name] = {
            "width": width,
            "runs": rows,
            "frames_equal_bit_for_bit": equal_whole,
            "read_frames_equal_bit_for_bit": equal_read,
            "animate_speedup": best["base"] / best["box"],
            "bytes_ratio": box_row["frame_bytes"] / base_row["frame_bytes"],
        }
        print(f"{name:>6}: frames equal {equal_whole}, downsampled frames equal {equal_read}, "
              f"animate {best['base'] / best['box']:.2f}× faster, "
              f"{box_row['frame_bytes'] / base_row['frame_bytes']:.3f}× the bytes")  # fmt: skip
    record = {
        "benchmark": "animate_frames",
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "device": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "threads": torch.get_num_threads(),
        "frames": args.frames,
        "base": args.base,
        "head": head,
        "scenes": results,
    }
    write_json_atomic(args.out, record)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
