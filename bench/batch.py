"""`pano4d batch` on the local Ray instance against the same scenes one after another.

N synthetic scenes (`pano4d synth`, WIDTH wide, FRAMES frames, the draft preset, with
`--overrides` if given: on a loaded machine a pure draft scene takes many minutes, and what
is measured here, Ray's cost per task, does not depend on the scene) are trained three
ways, each into its own output folders, in one run:

1. one after another, `pano4d train scene.yaml` per scene: what a shell loop does (a fresh
   process per scene, each with the whole machine);
2. `pano4d batch`, one scene at a time (`--cpus-per-scene` = every CPU): the same work as 1
   through Ray, so the difference is Ray's overhead;
3. `pano4d batch` with one CPU per scene: as many scenes at once as there are CPUs.

For the Ray runs, from batch.json: Ray's start-up (`ray.init`), and per task the gap before
it (from submission for a worker's first task: the worker process starts and imports
pano4d; from the end of that worker's previous task otherwise: scheduling alone), its own
time, and its result's way back to the driver. Prints a table, writes bench/out/batch.json
(batch-reverse.json with --reverse).

    .venv/bin/python bench/batch.py [--scenes 4] [--width 512] [--frames 2]
        [--overrides '{"gaussian_iterations": 20}'] [--reverse]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))

from pano4d.fsutil import write_json_atomic
from pano4d.synth import run_synth

PANO4D = str(Path(sys.executable).parent / "pano4d")


def make_scenes(
    root: Path, count: int, width: int, frames: int, overrides: dict[str, Any]
) -> list[Path]:
    """``count`` synthetic scenes at the draft preset (what `pano4d synth` writes), with
    ``overrides`` of its knobs."""
    scenes = [run_synth(root / f"s{i}", width, width // 2, frames, i, 2) for i in range(count)]
    for scene in scenes:
        scene.write_text(scene.read_text() + f"overrides: {json.dumps(overrides)}\n")
    return scenes


def variant(scenes: list[Path], mode: str) -> list[Path]:
    """Each scene's yaml again, writing into output-<mode>: the modes never share outputs."""
    out = []
    for scene in scenes:
        path = scene.with_name(f"{mode}.yaml")
        path.write_text(scene.read_text().replace("output: output", f"output: output-{mode}"))
        out.append(path)
    return out


def one_after_another(scenes: list[Path]) -> dict[str, Any]:
    per_scene = []
    start = time.perf_counter()
    for scene in scenes:
        t0 = time.perf_counter()
        subprocess.run([PANO4D, "train", str(scene)], check=True, capture_output=True)
        wall = time.perf_counter() - t0
        metrics = json.loads((scene.parent / "output-seq" / "metrics.json").read_text())
        per_scene.append({"wall_s": wall, "stages_s": sum(metrics["timings_s"].values())})
    return {"wall_s": time.perf_counter() - start, "scenes": per_scene}


def through_batch(scenes: list[Path], cpus: int, root: Path, mode: str) -> dict[str, Any]:
    listing = root / f"{mode}.txt"
    listing.write_text("".join(f"{s}\n" for s in scenes))
    report = root / f"{mode}.json"
    start = time.perf_counter()
    subprocess.run(
        [PANO4D, "batch", str(listing), "--cpus-per-scene", str(cpus), "--report", str(report)],
        check=True,
        capture_output=True,
    )
    wall = time.perf_counter() - start
    data = json.loads(report.read_text())
    rows = sorted((s for s in data["scenes"]), key=lambda s: s["ray"]["started"])
    first, later, previous = [], [], {}
    for s in rows:
        r = s["ray"]
        key = (r["node"], r["pid"])
        if key in previous:
            later.append(r["started"] - previous[key])
        else:
            first.append(r["started"] - r["submitted"])
        previous[key] = r["finished"]
    tasks = [s["wall_s"] for s in rows]
    stages = [sum(s["timings_s"].values()) for s in rows]
    return {
        "wall_s": wall,
        "cpus_per_scene": cpus,
        "ray_init_s": data["ray_init_s"],
        "workers": len(previous),
        "first_task_gap_s": first,  # worker start + imports, per worker
        "later_task_gap_s": later,  # scheduling between tasks on a warm worker
        "result_s": [s["ray"]["result_s"] for s in rows],
        "task_s": tasks,
        "in_task_outside_stages_s": [t - st for t, st in zip(tasks, stages, strict=True)],
        "stages_s": stages,
        "statuses": [s["status"] for s in rows],
    }


def _mean(values: list[float]) -> float:
    return statistics.fmean(values) if values else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=4)
    parser.add_argument("--width", type=int, default=512)
    parser.add_argument("--frames", type=int, default=2)
    parser.add_argument("--overrides", type=json.loads, default={}, help="preset knobs, JSON")
    parser.add_argument(
        "--reverse", action="store_true", help="run the modes last to first (a load that "
        "changes during the run favours one order: run both)"
    )  # fmt: skip
    args = parser.parse_args()
    cpus = os.cpu_count() or 1
    root = Path(tempfile.mkdtemp(prefix="pano4d-bench-batch-"))
    try:
        scenes = make_scenes(root, args.scenes, args.width, args.frames, args.overrides)
        load_before = os.getloadavg()[0]
        modes = {
            "one after another (pano4d train each)": lambda: one_after_another(
                variant(scenes, "seq")
            ),
            f"pano4d batch, 1 scene at a time ({cpus} CPUs each)": lambda: through_batch(
                variant(scenes, "ray1"), cpus, root, "ray1"
            ),
            f"pano4d batch, {cpus} scenes at a time (1 CPU each)": lambda: through_batch(
                variant(scenes, "rayN"), 1, root, "rayN"
            ),
        }
        order = list(modes)[::-1] if args.reverse else list(modes)
        results = {mode: modes[mode]() for mode in order}
    finally:
        shutil.rmtree(root, ignore_errors=True)
    base = results[next(iter(modes))]["wall_s"]
    size = f"{args.width}×{args.width // 2}"
    print(f"{args.scenes} synthetic scenes, {size}, {args.frames} frames, draft {args.overrides}")
    print(f"{'mode':<44} {'wall':>7} {'×':>5} {'ray.init':>8} {'1st gap':>8} {'gap':>6} "
          f"{'result':>7} {'task':>6}")  # fmt: skip
    for mode, r in results.items():
        if "task_s" not in r:
            print(f"{mode:<44} {r['wall_s']:>6.1f}s {r['wall_s'] / base:>5.2f}")
            continue
        print(
            f"{mode:<44} {r['wall_s']:>6.1f}s {r['wall_s'] / base:>5.2f} {r['ray_init_s']:>7.1f}s "
            f"{_mean(r['first_task_gap_s']):>7.2f}s {_mean(r['later_task_gap_s']):>5.3f}s "
            f"{_mean(r['result_s']):>6.3f}s {_mean(r['task_s']):>5.1f}s"
        )
    name = "batch-reverse.json" if args.reverse else "batch.json"
    out = Path(__file__).resolve().parent / "out" / name
    write_json_atomic(
        out,
        {
            "scenes": args.scenes,
            "width": args.width,
            "frames": args.frames,
            "overrides": args.overrides,
            "order": order,
            "cpu_count": cpus,
            "load_average_1min_before": load_before,
            "load_average_1min_at_end": os.getloadavg()[0],
            "machine": platform.platform(),
            "results": results,
        },
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
