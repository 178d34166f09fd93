"""Side by side with the peers (issue 22): OpenSplat and ours on the same views, same machine.

Builds OpenSplat (C++ on libtorch, CPU rasteriser) from pinned sources in a cache folder
outside the repository, trains it and ours on the same whole t = 0 views of the synthetic
landscape (``pano4d views``), and reports side by side: seconds per step at a fixed Gaussian
count (densification off everywhere), Gaussians, peak memory, and PSNR at the ground-truth
novel views (1 % / 5 % displacement, rendered by OUR renderer from each tool's .ply) after
the same wall time with each tool's own densification. Prints a table and writes
bench/out/peers.json.

    .venv/bin/python bench/peers.py [--cache /work/peers-cache] [--width 1024] [--steps 60]
        [--budget-s 300] [--build-only]

The build needs cmake, g++ and libopencv-dev (Debian) and the torch wheel of the venv (its
libtorch; the wheel's CMake config asks for CUDA, so a patched copy of it that links the
CPU libraries only is made in the cache). OpenSplat's CMake FetchContent dependencies are
given as local source trees (``FETCHCONTENT_SOURCE_DIR_<NAME>``): the cache's src/ must hold
the pinned snapshots below (the bench's caller brings them, e.g. ``git archive`` of a
mirror). None of OpenSplat's code enters this repository.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))

from pano4d import ply4d, synth
from pano4d.camera import Camera
from pano4d.config import SceneConfig, load_config
from pano4d.fsutil import write_json_atomic
from pano4d.gaussians import Gaussians
from pano4d.images import read_image
from pano4d.lift.views_export import ViewsDataset, export_views

OUT = Path(__file__).resolve().parent / "out"
# The pinned sources: folder under <cache>/src → (repository, commit or tag).
SOURCES = {
    "opensplat": ("pierotofy/OpenSplat", "15b7e80016bb25107f07956b5682231f226f62b9"),
    "nlohmann_json": ("nlohmann/json", "v3.11.3"),  # OpenSplat's CMakeLists pins these tags
    "nanoflann": ("jlblancoc/nanoflann", "v1.5.5"),
    "cxxopts": ("jarro2783/cxxopts", "v3.2.0"),
}


def torch_cpu_prefix(cache: Path) -> Path:
    """A libtorch prefix whose CMake config links the CPU libraries only.

    The torch wheel is a CUDA build: its Caffe2Config fails without a CUDA toolkit and its
    ``torch`` target pulls torch_cuda. The prefix links lib/ and include/ to the wheel and
    carries a copy of share/cmake with those two switched off."""
    wheel = Path(torch.__file__).resolve().parent
    prefix = cache / "libtorch-cpu"
    if prefix.exists():
        shutil.rmtree(prefix)
    prefix.mkdir(parents=True)
    (prefix / "lib").symlink_to(wheel / "lib")
    (prefix / "include").symlink_to(wheel / "include")
    shutil.copytree(wheel / "share" / "cmake", prefix / "share" / "cmake")
    caffe2 = prefix / "share" / "cmake" / "Caffe2" / "Caffe2Config.cmake"
    text = caffe2.read_text()
    text = text.replace(
        "if(1)\n  # The file public/cuda.cmake", "if(0)\n  # The file public/cuda.cmake"
    )
    caffe2.write_text(text)
    targets = prefix / "share" / "cmake" / "Caffe2" / "Caffe2Targets.cmake"
    text = targets.read_text()
    text = text.replace(
        'INTERFACE_LINK_LIBRARIES "torch_cpu_library;torch_cuda_library"',
        'INTERFACE_LINK_LIBRARIES "torch_cpu_library"',
    )
    targets.write_text(text)
    config = prefix / "share" / "cmake" / "Torch" / "TorchConfig.cmake"
    text = config.read_text()
    text = re.sub(
        r"if\(1\)\n  if\(MSVC\)\n    find_library\(CAFFE2_NVRTC",
        "if(0)\n  if(MSVC)\n    find_library(CAFFE2_NVRTC",
        text,
    )
    config.write_text(text)
    return prefix


# OpenSplat scales the scene by 1 / the cameras' spread, which is 0 for the views of one
# panorama (one centre): the patch takes the scale from OPENSPLAT_SCENE_SCALE when it is set
# (transforms.json's scene_scale), the rule unchanged otherwise.
SCALE_RULE = "float f = 1.0f / torch::max(torch::abs(origins)).item<float>();"
SCALE_PATCHED = (
    'const char *given = std::getenv("OPENSPLAT_SCENE_SCALE");\n'
    "    float f = given != nullptr ? std::stof(given) : "
    "1.0f / torch::max(torch::abs(origins)).item<float>();"
)


def patch_opensplat(source: Path) -> None:
    """The cache's local patches of OpenSplat, idempotent: C++20 (torch ≥ 2.10's headers need
    it; OpenSplat's CMakeLists asks for C++17) and the scene scale (SCALE_RULE)."""
    lists = source / "CMakeLists.txt"
    lists.write_text(re.sub(r"CXX_STANDARD 17\b", "CXX_STANDARD 20", lists.read_text()))
    math = source / "tensor_math.cpp"
    text = math.read_text()
    if SCALE_RULE in text and "OPENSPLAT_SCENE_SCALE" not in text:
        text = "#include <cstdlib>\n#include <string>\n" + text.replace(SCALE_RULE, SCALE_PATCHED)
        math.write_text(text)
    if "OPENSPLAT_SCENE_SCALE" not in math.read_text():
        raise SystemExit(f"error: {math}: the scale rule to patch is not there (a new commit?)")


def build_opensplat(cache: Path, jobs: int = 2) -> Path:
    """Configure and build OpenSplat's CPU runtime in <cache>/build; the binary's path."""
    src = cache / "src"
    missing = [name for name in SOURCES if not (src / name / "CMakeLists.txt").is_file()]
    if missing:
        lines = [f"  {src / n}: {SOURCES[n][0]} at {SOURCES[n][1]}" for n in missing]
        raise SystemExit("error: sources missing in the cache:\n" + "\n".join(lines))
    binary = cache / "build" / "opensplat"
    if binary.is_file():
        return binary
    prefix = torch_cpu_prefix(cache)
    patch_opensplat(src / "opensplat")
    build = cache / "build"
    build.mkdir(parents=True, exist_ok=True)
    configure = [
        "cmake",
        str(src / "opensplat"),
        "-DGPU_RUNTIME=CPU",
        "-DCMAKE_BUILD_TYPE=Release",
        f"-DTorch_DIR={prefix / 'share' / 'cmake' / 'Torch'}",
        "-DFETCHCONTENT_FULLY_DISCONNECTED=ON",
    ]
    configure += [
        f"-DFETCHCONTENT_SOURCE_DIR_{name.upper()}={src / name}"
        for name in SOURCES
        if name != "opensplat"
    ]
    env = dict(os.environ, TORCH_INSTALL_PREFIX=str(prefix))
    subprocess.run(configure, cwd=build, check=True, env=env)
    subprocess.run(["nice", "make", f"-j{jobs}", "opensplat"], cwd=build, check=True, env=env)
    return binary


# --- the views --------------------------------------------------------------------------------
def make_views(root: Path, width: int, preset: str) -> tuple[SceneConfig, ViewsDataset]:
    """The synthetic landscape (its true animation standing in for the animating phase, its
    true depth for the depth stage, as bench/quality.py) and its whole t = 0 views."""
    if not (root / "scene.yaml").is_file():
        scene = synth.make_scene(0, width, width // 2, 2, views=8, kind="landscape")
        synth.write_scene(root, scene)
    output = root / f"out_{preset}"
    frames = output / "animate" / "frames"
    if not frames.is_dir():
        shutil.copytree(root / "gt" / "frames", frames)
    cfg = load_config(root / "scene.yaml")
    depth = cfg.depth.model_copy(update={"backend": "file", "path": root / "depth.exr"})
    cfg = cfg.model_copy(update={"preset": preset, "output": output, "depth": depth})
    return cfg, export_views(cfg, root / f"views_{preset}", 0, progress=False)


def camera_of(frame: dict[str, Any]) -> Camera:
    """A transforms.json frame as our Camera (its OpenGL camera-to-world back to OpenCV)."""
    K = [[frame["fl_x"], 0.0, frame["cx"]], [0.0, frame["fl_y"], frame["cy"]], [0.0, 0.0, 1.0]]
    return Camera.from_camera_to_world_gl(frame["transform_matrix"], K, frame["w"], frame["h"])


# --- ours, in a child process (its own peak memory) ---------------------------------------------
def run_ours(views: Path, steps: int, densify: bool, out: Path, knobs_json: str) -> None:
    """The static stage's trainer (resident, wgpu) on the dataset's whole views (weight 1
    everywhere, as the peers see them), from ours_initial.ply; writes out (.ply) and
    out.json (seconds per step after the first, the Gaussian count)."""
    from pano4d.lift.resident import ResidentTrainer
    from pano4d.lift.trainer import Knobs, TrainViews

    data = json.loads((views / "transforms.json").read_text())
    preset = json.loads(knobs_json)
    cameras = [camera_of(f) for f in data["frames"]]
    targets = torch.stack([
        torch.from_numpy(read_image(views / f["file_path"])[..., :3]) for f in data["frames"]
    ])  # fmt: skip
    depth = torch.stack([
        torch.from_numpy(np.load(views / f["depth_file_path"])) for f in data["frames"]
    ])  # fmt: skip
    train_views = TrainViews(cameras, targets, torch.ones(targets.shape[:3]), depth)
    knobs = Knobs(
        iterations=steps, lambda_geo=preset["lambda_geo"], densify=densify,
        max_gaussians=preset["max_gaussians"], densify_every=max(10, steps // 10),
        sem_scale=data["pano4d"]["median_depth"],
        # Classic, as OpenSplat trains and as both tools' .ply files are drawn here.
        antialiased=False,
    )  # fmt: skip
    initial = ply4d.read_ply(views / "ours_initial.ply")
    trainer = ResidentTrainer(initial, train_views, knobs)  # it renders on the device
    trainer.train_step()  # the first step builds pipelines and sizes buffers
    trainer._session.loss()
    start = time.perf_counter()
    result = trainer.run()  # reading the result back waits for the last step
    seconds = time.perf_counter() - start
    ply4d.write_ply(out, result)
    per_step = seconds / max(1, steps - 1)
    out.with_suffix(".json").write_text(
        json.dumps({"per_step": per_step, "gaussians": len(result)})
    )


def child(
    command: list[str], env: dict[str, str] | None = None
) -> tuple[list[tuple[float, str]], float, int]:
    """Run ``command``; its stdout lines with the time each arrived, its wall time and its
    peak resident memory (bytes, from wait4)."""
    start = time.perf_counter()
    process = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env={**os.environ, **(env or {})},
    )  # fmt: skip
    assert process.stdout is not None
    lines = [(time.perf_counter(), line.rstrip()) for line in process.stdout]
    _, status, usage = os.wait4(process.pid, 0)
    process.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - start
    if process.returncode != 0:
        tail = "\n".join(line for _, line in lines[-15:])
        raise RuntimeError(f"{command[0]} exited {process.returncode}:\n{tail}")
    return lines, wall, usage.ru_maxrss * 1024


def ours(views: Path, steps: int, densify: bool, knobs: dict[str, Any], tag: str) -> dict[str, Any]:
    out = views.parent / f"ours_{tag}.ply"
    command = [sys.executable, __file__, "--run-ours", str(views), "--steps", str(steps),
               "--out", str(out), "--knobs", json.dumps(knobs)]  # fmt: skip
    if densify:
        command.append("--densify")
    _, wall, peak = child(command)
    result = json.loads(out.with_suffix(".json").read_text())
    return {"tool": "pano4d", "steps": steps, "wall_s": wall, "peak_bytes": peak, "ply": str(out),
            "per_step_s": result["per_step"], "gaussians": result["gaussians"]}  # fmt: skip


# --- OpenSplat -----------------------------------------------------------------------------------
STEP_LINE = re.compile(r"^Step (\d+): ")


def opensplat(
    binary: Path, views: Path, steps: int, densify: bool, sh_degree: int, scale: float, tag: str
) -> dict[str, Any]:
    """OpenSplat's CPU trainer on the dataset: full resolution from the first step (its
    downscale schedule off), SH degree ``sh_degree`` from the start, its scene scale the
    dataset's. Densification off: its first refinement after the last step. On: its own
    rule, its schedule (made for 30 000 steps) scaled to ``steps`` as ours is (warm-up
    10 %, refinement every 5 %, screen-size splits stopped at 13 %, no opacity reset)."""
    out = views.parent / f"opensplat_{tag}.ply"
    command = [str(binary), str(views), "-o", str(out), "-n", str(steps), "--keep-crs",
               "--num-downscales", "0", "--sh-degree", str(sh_degree),
               "--sh-degree-interval", "1", "--cpu"]  # fmt: skip
    if densify:
        command += ["--warmup-length", str(max(1, steps // 10)),
                    "--refine-every", str(max(1, steps // 20)),
                    "--stop-screen-size-at", str(max(1, steps * 4 // 30)),
                    "--reset-alpha-every", str(10 * steps)]  # fmt: skip
    else:
        command += ["--warmup-length", str(steps + 1), "--refine-every", str(steps + 1)]
    lines, wall, peak = child(command, {"OPENSPLAT_SCENE_SCALE": repr(scale)})
    stamps = [(int(m.group(1)), t) for t, line in lines if (m := STEP_LINE.match(line))]
    if len(stamps) < 2:
        raise RuntimeError(f"OpenSplat printed {len(stamps)} step lines; expected {steps}")
    (first, t0), (last, t1) = stamps[0], stamps[-1]
    gaussians = len(ply4d.read_ply(out))
    return {"tool": "OpenSplat", "steps": steps, "wall_s": wall, "peak_bytes": peak,
            "ply": str(out), "per_step_s": (t1 - t0) / max(1, last - first),
            "gaussians": gaussians}  # fmt: skip


# --- quality -------------------------------------------------------------------------------------
class StaticScene:
    """One set of Gaussians as the scene novel_view_metrics reads (every time the same)."""

    num_times = 1

    def __init__(self, gaussians: Gaussians) -> None:
        self.gaussians = gaussians

    def at(self, _t: int) -> Gaussians:
        return self.gaussians


def novel_psnr(ply: str, panorama: Path) -> dict[str, float]:
    """PSNR at gt/views.json's t = 0 cameras (1 % and 5 % displaced), rendered by ours."""
    from pano4d.lift.export import read_gt_views
    from pano4d.metrics import novel_view_metrics
    from pano4d.renderer import render

    views = [v for v in read_gt_views(panorama) if int(v["time"]) == 0]
    scene = StaticScene(ply4d.read_ply(ply))
    metrics = novel_view_metrics(scene, views, lambda g, c: render(g, c, backend="wgpu"))
    return {k: v["psnr"] for k, v in metrics["by_displacement"].items()}


def table(rows: list[dict[str, Any]]) -> str:
    head = (f"{'run':<22}{'tool':<11}{'steps':>6}{'s/step':>9}{'wall s':>8}{'Gaussians':>10}"
            f"{'peak MiB':>9}{'PSNR 1%':>9}{'PSNR 5%':>9}")  # fmt: skip
    lines = [head]
    for r in rows:
        lines.append(
            f"{r['run']:<22}{r['tool']:<11}{r['steps']:>6}{r['per_step_s']:>9.3f}"
            f"{r['wall_s']:>8.1f}{r['gaussians']:>10}{r['peak_bytes'] / 2**20:>9.0f}"
            f"{r['psnr'].get('1%', float('nan')):>9.2f}{r['psnr'].get('5%', float('nan')):>9.2f}"
        )
    return "\n".join(lines)


def bench(args: argparse.Namespace) -> None:
    load_before = os.getloadavg()
    binary = build_opensplat(args.cache)
    root = OUT / "peers" / f"landscape_w{args.width}"
    cfg, dataset = make_views(root, args.width, args.preset)
    views = dataset.folder
    ply4d.write_ply(views / "ours_initial.ply", dataset.initial)
    knobs = cfg.resolved_preset(args.width).model_dump()
    steps = args.steps or int(knobs["gaussian_iterations"])
    sh, scale = int(knobs["sh_degree"]), dataset.scene_scale
    report: dict[str, Any] = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "torch": torch.__version__, "load_before": load_before},
        "opensplat": {"commit": SOURCES["opensplat"][1], "binary": str(binary)},
        "scene": {"kind": "landscape", "width": args.width, "preset": args.preset,
                  "views": dataset.views, "view_size": knobs["view_size"], "sh_degree": sh,
                  "initial_points": dataset.points, "scene_scale": scale},
        "rows": [],
    }  # fmt: skip
    rows: list[dict[str, Any]] = report["rows"]

    def add(row: dict[str, Any], run: str) -> None:
        """A row with its PSNR; the JSON rewritten after each (a long run keeps what it has)."""
        row = {**row, "run": run, "psnr": novel_psnr(row["ply"], Path(cfg.panorama))}
        rows.append(row)
        report["machine"]["load_after"] = os.getloadavg()
        write_json_atomic(args.json, report)
        print(table([row]), flush=True)

    # 1. the same Gaussians, no densification anywhere: seconds per step (OpenSplat first: a
    # failure of the peer shows before ours has spent its time)
    add(opensplat(binary, views, steps, False, sh, scale, "fixed"), "fixed count")
    add(ours(views, steps, False, knobs, "fixed"), "fixed count")
    theirs, mine = rows[0]["per_step_s"], rows[1]["per_step_s"]
    # 2. each its own densification for the same wall time: PSNR
    budget = args.budget_s or 3 * mine * steps
    report["budget_s"] = budget
    add(opensplat(binary, views, max(10, int(budget / theirs)), True, sh, scale, "densify"),
        f"densify, {budget:.0f} s")  # fmt: skip
    add(
        ours(views, max(10, int(budget / mine)), True, knobs, "densify"), f"densify, {budget:.0f} s"
    )
    print(table(rows))
    print(f"wrote {args.json}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, default=Path("/work/peers-cache"))
    parser.add_argument("--build-only", action="store_true")
    parser.add_argument("--width", type=int, default=1024)
    parser.add_argument("--preset", choices=["draft", "balanced"], default="draft")
    parser.add_argument("--steps", type=int, default=0, help="default: the preset's")
    parser.add_argument("--budget-s", type=float, default=0.0,
                        help="wall time of the densifying runs; default 3× ours fixed")  # fmt: skip
    parser.add_argument("--json", type=Path, default=OUT / "peers.json")
    # the child process that runs ours (its own peak memory)
    parser.add_argument("--run-ours", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--densify", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--knobs", default="{}", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.run_ours:
        run_ours(args.run_ours, args.steps, args.densify, args.out, args.knobs)
    elif args.build_only:
        print(f"OpenSplat: {build_opensplat(args.cache)}")
    else:
        bench(args)


if __name__ == "__main__":
    main()
