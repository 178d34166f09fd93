"""One training step of the lifting phase, resident loop against today's path, per preset size.

    .venv/bin/python bench/train_step.py [--sizes draft balanced max] [--steps 3]
        [--width 4096] [--json bench/out/train_step.json] [--gsplat]

A size is a preset's view side (128 / 512 / 1024) and SH degree, with the initial Gaussians
the lifting pipeline places on a ``--width`` panorama at the preset's ``init_stride`` (made
coarser until they fit ``max_gaussians``, as the pipeline does): 98k / 690k / 1.5M at 4096.
The scene is the synthetic landscape (``pano4d.synth``): its panorama and depth seed the
Gaussians and give the 20 layout views' targets and depths; every loss term of the static
stage is on (L1 + D-SSIM, L_geo).

For each size, in one run and from the same start on the same views:
- resident: ``ResidentTrainer`` (``pano4d._core.TrainSession``), the parameters, moments and
  targets on the device, in the knobs' default rasteriser mode (antialiased), and the same
  in the classic mode (``classic s``: what a step cost before the mode, on the same set);
- today's path: ``GaussianTrainer`` with the wgpu render backend (parameters uploaded and
  image read back for the forward, again for the backward, gradients read back, losses and
  Adam in torch on the host).
Time per step is the mean of ``--steps`` steps after one warm-up step (the resident loop's
steps are queued without waiting; the timing ends when the last one has finished).
Bytes per step are what crosses between host and device: for the resident loop the session's
own counter (``TrainSession.traffic``), for today's path every array passed to and returned
by the rasteriser's bindings; the renderer's small per-frame uniforms come on top of both
(see RESULTS.md). The resident loop's intersection counts stay on the device (frames are
sized on the GPU); its frame check rides with the loss read every 10 steps.

The semantic loss (optional DINOv2) is timed on the resident loop as well, with L_sem on every
step: each such step reads the render and the moved render back, runs the feature model in
torch and uploads the moved render's pixel gradient for a second backward. A tiny random
DINOv2 (one layer, width 32, patch 14) stands in for the real model, so the figure is the
loop's overhead; the real model's own forward and backward come on top.

``--gsplat`` adds gsplat's CUDA ``rasterization`` with torch Adam (``GaussianTrainer`` with a
gsplat render function) on the same scene and views; it needs a CUDA device and the gsplat
package, and says so and skips that part otherwise. Prints a table and writes JSON
(``--json``, default bench/out/train_step.json).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import platform
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))

from pano4d.camera import Camera
from pano4d.config import PRESETS
from pano4d.gaussians import Gaussians
from pano4d.lift.initial import init_gaussians, init_sphere
from pano4d.lift.random_dinov2 import random_feature_model
from pano4d.lift.resident import ResidentTrainer
from pano4d.lift.torch_trainer import GaussianTrainer
from pano4d.lift.trainer import Knobs, TrainViews
from pano4d.renderer import RenderOutput, adapter_info, render
from pano4d.resample import equirect_to_perspective
from pano4d.sphere import view_layout
from pano4d.synth.landscape import Landscape
from pano4d.synth.views import render_panorama

OUT = Path(__file__).resolve().parent / "out" / "train_step.json"
VIEWS, FOV_DEG = 20, 80.0  # the lifting phase's layout (scene.yaml lift: defaults)
SIZES = ("draft", "balanced", "max")


def initial_set(depth: torch.Tensor, rgb: torch.Tensor, preset: str) -> Gaussians:
    """The pipeline's initial Gaussians for ``preset`` on this panorama."""
    knobs = PRESETS[preset]
    stride = int(knobs["init_stride"])
    width = depth.shape[1]
    ico = init_sphere(width, stride)
    while len(ico) > int(knobs["max_gaussians"]):  # as the pipeline keeps within budget
        stride += 1
        ico = init_sphere(width, stride)
    return init_gaussians(ico.points, ico.spacing_rad, depth, rgb, int(knobs["sh_degree"]))


def train_views(rgb: torch.Tensor, depth: torch.Tensor, side: int) -> TrainViews:
    cams = view_layout(VIEWS, FOV_DEG, side)
    image = rgb.permute(2, 0, 1)
    targets = torch.stack([equirect_to_perspective(image, c).permute(1, 2, 0) for c in cams])
    z = torch.stack([equirect_to_perspective(depth[None], c)[0] / c.z_to_ray_factor()
                     for c in cams])  # fmt: skip
    return TrainViews(cams, targets, torch.ones(VIEWS, side, side), z)


def wgpu_render(g: Gaussians, camera: Camera, background: Any = None) -> RenderOutput:
    return render(g, camera, background=background, backend="wgpu")


@contextlib.contextmanager
def counted_bindings() -> Iterator[list[int]]:
    """Counts the bytes of every array passed to or returned by the rasteriser's bindings."""
    total = [0]
    core = importlib.import_module("pano4d._core")  # the module itself, to wrap its functions
    originals = {name: getattr(core, name) for name in ("render_forward", "render_backward")}

    def size(value: Any) -> int:
        if isinstance(value, np.ndarray):
            return value.nbytes
        if isinstance(value, core.GaussianArrays):
            arrays = (value.means, value.log_scales, value.quats, value.opacity_logits, value.sh)
            return sum(a.nbytes for a in arrays)
        if isinstance(value, core.RasterOutput):
            return value.pixels.nbytes
        return 0

    def wrap(fn: Callable[..., Any]) -> Callable[..., Any]:
        def counted(*args: Any, **kwargs: Any) -> Any:
            out = fn(*args, **kwargs)
            total[0] += sum(size(a) for a in (*args, *kwargs.values())) + size(out)
            return out

        return counted

    for name, fn in originals.items():
        setattr(core, name, wrap(fn))
    try:
        yield total
    finally:
        for name, fn in originals.items():
            setattr(core, name, fn)


def moved_bytes(before: Any, after: Any) -> int:
    """Bytes uploaded and read back between two of a session's ``traffic()`` readings."""
    return after.uploaded - before.uploaded + after.read_back - before.read_back


def time_steps(trainer: Any, steps: int, finish: Callable[[], Any]) -> float:
    trainer.train_step()  # warm-up: pipelines, buffer sizes
    finish()
    start = time.perf_counter()
    for _ in range(steps):
        trainer.train_step()
    finish()
    return (time.perf_counter() - start) / steps


def resident_row(g: Gaussians, views: TrainViews, knobs: Knobs, steps: int) -> dict[str, Any]:
    trainer = ResidentTrainer(g, views, knobs)
    session = trainer._session
    before = session.traffic()
    seconds = time_steps(trainer, steps, session.loss)
    after = session.traffic()
    # The two loss read-backs around the timing are the benchmark's, not the loop's.
    loss_bytes = 2 * 7 * 4
    moved = moved_bytes(before, after) - loss_bytes
    return {"seconds": seconds, "bytes": moved / (steps + 1)}


def semantic_row(
    g: Gaussians, views: TrainViews, knobs: Knobs, steps: int, features: Any
) -> dict[str, Any]:
    """The resident loop with L_sem on every step (past 54 % of the iterations)."""
    sem = Knobs(iterations=knobs.iterations, lambda_geo=knobs.lambda_geo, lambda_sem=0.01,
                sem_scale=10.0)  # fmt: skip
    trainer = ResidentTrainer(g, views, sem, features=features)
    trainer.step = sem.iterations // 2 + sem.iterations // 10  # L_sem's schedule has begun
    session = trainer._session
    before = session.traffic()
    seconds = time_steps(trainer, steps, session.loss)
    after = session.traffic()
    moved = moved_bytes(before, after) - 2 * 7 * 4  # less the benchmark's own loss reads
    return {"seconds": seconds, "bytes": moved / (steps + 1)}


def torch_row(g: Gaussians, views: TrainViews, knobs: Knobs, steps: int) -> dict[str, Any]:
    trainer = GaussianTrainer(g, views, knobs, wgpu_render)
    with counted_bindings() as moved:
        seconds = time_steps(trainer, steps, lambda: None)
    return {"seconds": seconds, "bytes": moved[0] / (steps + 1)}


def gsplat_row(g: Gaussians, views: TrainViews, knobs: Knobs, steps: int) -> dict[str, Any]:
    from gsplat import rasterization

    cuda = torch.device("cuda")

    def gsplat_render(g: Gaussians, camera: Camera, background: Any = None) -> RenderOutput:
        colors, alphas, _ = rasterization(
            g.means, g.quats, g.log_scales.exp(), torch.sigmoid(g.opacity_logits), g.sh,
            camera.world_to_cam[None].to(cuda, torch.float32),
            camera.K[None].to(cuda, torch.float32), camera.width, camera.height,
            sh_degree=g.sh_degree, render_mode="RGB+ED",
        )  # fmt: skip
        return RenderOutput(colors[0, ..., :3], alphas[0, ..., 0], colors[0, ..., 3])

    on_cuda = TrainViews(views.cameras, views.targets.to(cuda), views.weights.to(cuda),
                         views.depth.to(cuda))  # fmt: skip
    trainer = GaussianTrainer(g.to(cuda), on_cuda, knobs, gsplat_render)
    return {"seconds": time_steps(trainer, steps, torch.cuda.synchronize), "bytes": None}


def gsplat_available() -> str | None:
    """None when the gsplat part can run, else why not."""
    if not torch.cuda.is_available():
        return "needs a CUDA device (torch sees none)"
    try:
        import gsplat  # noqa: F401
    except ImportError:
        return "needs the gsplat package (pip install gsplat, built against this torch)"
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", choices=SIZES, default=list(SIZES))
    parser.add_argument("--steps", type=int, default=3, help="timed steps per path")
    parser.add_argument("--width", type=int, default=4096, help="panorama width")
    parser.add_argument("--json", type=Path, default=OUT, help="where to write the results")
    parser.add_argument("--gsplat", action="store_true",
                        help="also gsplat's CUDA rasterization + torch Adam")  # fmt: skip
    args = parser.parse_args()
    if args.steps < 1:
        parser.error("--steps must be ≥ 1")
    info = adapter_info()
    print(f"adapter: {info['name']} ({info['backend']}, {info['device_type']})", flush=True)
    skip_gsplat = gsplat_available() if args.gsplat else "not asked for (--gsplat)"
    if args.gsplat and skip_gsplat:
        print(f"gsplat part skipped: it {skip_gsplat}", flush=True)
    start = time.perf_counter()
    rgb, depth, *_ = render_panorama(Landscape(0, 2, 2.0), args.width, args.width // 2)
    print(f"synthetic {args.width}x{args.width // 2} panorama: "
          f"{time.perf_counter() - start:.1f} s", flush=True)  # fmt: skip
    with tempfile.TemporaryDirectory() as folder:
        features = random_feature_model(Path(folder), patch_size=14, image_size=518,
                                        hidden_size=32)  # fmt: skip
    header = (f"{'size':>9} {'view':>5} {'Gaussians':>10} {'SH':>3} {'resident s':>11} "
              f"{'classic s':>10} {'today s':>8} {'speed-up':>9} {'resident B':>11} "
              f"{'today B':>12} "
              f"{'L_sem s':>8} {'L_sem B':>11} {'gsplat s':>9}")  # fmt: skip
    print(header, flush=True)
    rows = []
    for name in args.sizes:
        preset = PRESETS[name]
        side = int(preset["view_size"])
        g = initial_set(depth, rgb, name)
        views = train_views(rgb, depth, side)
        knobs = Knobs(iterations=10**6, lambda_geo=float(preset["lambda_geo"]))
        row: dict[str, Any] = {"size": name, "view": side, "gaussians": len(g),
                               "sh_degree": g.sh_degree}  # fmt: skip
        paths: dict[str, Callable[..., dict[str, Any]]] = {
            "resident": resident_row,
            "resident_classic": lambda g, v, k, s: resident_row(
                g, v, k.model_copy(update={"antialiased": False}), s
            ),
            "today": torch_row,
            "resident_sem": lambda *a: semantic_row(*a, features),
        }
        for path, fn in paths.items():
            try:
                row[path] = fn(g, views, knobs, args.steps)
            except (RuntimeError, ValueError) as e:  # e.g. beyond a binding limit
                row[path] = {"error": str(e)}
        if skip_gsplat is None:
            row["gsplat"] = gsplat_row(g, views, knobs, args.steps)
        else:
            row["gsplat"] = {"skipped": skip_gsplat}
        rows.append(row)
        print_row(row)
    payload = {
        "date": time.strftime("%Y-%m-%d"),
        "adapter": info,
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs",
        "torch_threads": torch.get_num_threads(),
        "panorama_width": args.width,
        "steps": args.steps,
        "rows": rows,
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile("w", dir=args.json.parent, delete=False,
                                     suffix=".tmp") as f:  # fmt: skip
        json.dump(payload, f, indent=2)
    os.replace(f.name, args.json)
    print(f"wrote {args.json}")


def print_row(row: dict[str, Any]) -> None:
    res, today, sem, gs = row["resident"], row["today"], row["resident_sem"], row["gsplat"]
    classic = row["resident_classic"]

    def secs(part: dict[str, Any]) -> str:
        return f"{part['seconds']:.3f}" if "seconds" in part else "-"

    def size(part: dict[str, Any]) -> str:
        return f"{part['bytes']:,.0f}" if part.get("bytes") is not None else "-"

    speedup = (f"{today['seconds'] / res['seconds']:.2f}x"
               if "seconds" in res and "seconds" in today else "-")  # fmt: skip
    print(f"{row['size']:>9} {row['view']:>5} {row['gaussians']:>10,} {row['sh_degree']:>3} "
          f"{secs(res):>11} {secs(classic):>10} {secs(today):>8} {speedup:>9} {size(res):>11} "
          f"{size(today):>12} "
          f"{secs(sem):>8} {size(sem):>11} {secs(gs):>9}", flush=True)  # fmt: skip
    for path in ("resident", "resident_classic", "today", "resident_sem"):
        if "error" in row[path]:
            print(f"{'':>9} {path} refused: {row[path]['error']}", flush=True)


if __name__ == "__main__":
    main()
