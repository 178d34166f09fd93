"""The files a lifting run writes (docs/design.md, "Files a run writes").

``output/scene.ply4d`` (the static set once, then the spacetime set once — version 2 — or a
dynamic set per timestamp — version 1, the per-timestamp stage), ``preview.mp4``
(a turntable at the origin, then on a small orbit), ``contact.png`` (ground-truth views
beside their renders when gt/views.json lies beside the panorama, else test views of the
moving region at a few times), ``metrics.json`` (timings, Gaussian counts, sizes, what
storing the static part once saved, novel-view PSNR/SSIM) and the diagnosis of every
optimisation (``lift.diagnosis``: densify.jsonl, losses.json, loss.png).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pano4d import __version__, ply4d
from pano4d.camera import Camera
from pano4d.camera_paths import turntable
from pano4d.config import config_hash
from pano4d.fsutil import write_json_atomic
from pano4d.gaussians import Gaussians
from pano4d.images import read_image, write_contact_sheet, write_video
from pano4d.lift.diagnosis import write_diagnosis
from pano4d.lift.losses import moved_camera
from pano4d.lift.pipeline import (
    Alignment,
    DynamicSets,
    InitialSets,
    Lifted,
    LiftInputs,
    StaticSet,
    StepHook,
)
from pano4d.metrics import novel_view_metrics, psnr_of_mse
from pano4d.resample import equirect_sampler, equirect_to_perspective
from pano4d.spacetime import SpacetimeGaussians
from pano4d.sphere import view_layout

PREVIEW_FRAMES = 24  # per turntable (origin, then the displaced orbit)
PREVIEW_ORBIT = 0.01  # orbit radius as a fraction of the median scene depth
CONTACT_TIMES = 3
# training_fit's resolution figure compares the working panorama with the input on every
# 4th row and column of views at the input's pixel size (a 6144-wide input: 16× fewer samples).
RESOLUTION_STRIDE = 4


def export(lifted: Lifted, on_step: StepHook | None = None) -> dict[str, Any]:
    """Write every output file of a lifted scene; returns the metrics (also metrics.json,
    written last). ``on_step("export", n)`` is called after the n-th file
    (the three diagnosis files count as one)."""
    inputs, alignment, initial = lifted.inputs, lifted.alignment, lifted.initial
    static, dynamic = lifted.static, lifted.dynamic
    start = time.perf_counter()
    out = Path(inputs.cfg.output)
    written = 0

    def wrote() -> None:
        nonlocal written
        written += 1
        if on_step is not None:
            on_step("export", written)

    scene = scene4d(inputs, static.gaussians, dynamic.gaussians, alignment, initial)
    ply4d.write(out / "scene.ply4d", scene)
    wrote()
    render = inputs.render
    size = inputs.knobs.view_size
    w, h = 2 * size, (2 * size * 9 // 16) // 2 * 2  # 16:9, as wide as two views
    orbit = PREVIEW_ORBIT * alignment.median_depth
    cams = turntable(w, h, PREVIEW_FRAMES) + turntable(w, h, PREVIEW_FRAMES, orbit)
    on_device = [scene.at(t).to(inputs.device) for t in range(scene.num_times)]
    with torch.no_grad():
        frames = [
            render(on_device[i % scene.num_times], c).rgb.clamp(0, 1).cpu().numpy()
            for i, c in enumerate(cams)
        ]
    write_video(out / "preview.mp4", frames, inputs.cfg.animate.fps)
    wrote()

    gt = read_gt_views(Path(inputs.cfg.panorama))
    metrics_views = (
        novel_view_metrics(scene, gt, lambda g, c: render(g.to(inputs.device), c)) if gt else None
    )
    tiles, labels = [], []
    if gt:
        for v in gt[:8]:
            t = min(int(v["time"]), scene.num_times - 1)
            with torch.no_grad():
                rgb = render(on_device[t], v["camera"]).rgb.clamp(0, 1).cpu()
            pct = f"{100 * float(v.get('displacement_fraction', 0)):g}%"
            tiles += [v["pixels"].numpy(), rgb.numpy()]
            labels += [f"gt t={t} {pct}", f"render t={t}"]
        columns = 4
    else:
        times = sorted({0, scene.num_times // 2, scene.num_times - 1})[:CONTACT_TIMES]
        test = contact_cameras(inputs, alignment.median_depth)
        for t in times:
            for c in test:
                with torch.no_grad():
                    tiles.append(render(on_device[t], c).rgb.clamp(0, 1).cpu().numpy())
                labels.append(f"t={t}")
        columns = len(test)
    write_contact_sheet(out / "contact.png", tiles, columns, labels)
    wrote()
    # A one-set scene (spacetime, tracked) stored the same set after every optimisation.
    one_set = isinstance(scene.dynamic, SpacetimeGaussians)
    dynamic_stored = [len(scene.dynamic)] * len(dynamic.logs) if one_set else dynamic_counts(scene)
    stored = [len(static.gaussians), *dynamic_stored]
    write_diagnosis(out, list(zip([static.log, *dynamic.logs], stored, strict=False)))
    wrote()
    fit = training_fit(inputs, scene)
    timings = {**lifted.timings, "export": time.perf_counter() - start}

    metrics = run_metrics(
        inputs, scene, alignment, initial, static, dynamic, timings, out / "scene.ply4d",
        metrics_views, fit,
    )  # fmt: skip
    metrics["resumed_at"] = lifted.resumed_at
    write_json_atomic(out / "metrics.json", metrics)
    wrote()
    return metrics


def scene4d(
    inputs: LiftInputs,
    static: Gaussians,
    dynamic: list[Gaussians] | SpacetimeGaussians,
    alignment: Alignment,
    initial: InitialSets,
) -> ply4d.Scene4D:
    """The .ply4d scene: the static set once, the spacetime set (or a dynamic set per
    timestamp), provenance."""
    cfg = inputs.cfg
    fps = cfg.animate.fps
    return ply4d.Scene4D(
        static=static.detach().to("cpu"),
        dynamic=(
            dynamic.detach().to("cpu")
            if isinstance(dynamic, SpacetimeGaussians)
            else [g.detach().to("cpu") for g in dynamic]
        ),
        timestamps=[t / fps for t in range(len(inputs.frames))],
        fps=fps,
        camera={
            "position": [0.0, 0.0, 0.0],
            "params": {
                "views": len(inputs.cameras),
                "fov_deg": cfg.lift.fov_deg,
                "view_size": inputs.knobs.view_size,
            },
        },
        provenance={"tool_version": __version__, "config_hash": config_hash(cfg)},
        antialiased=inputs.knobs.antialiased,
        extra={
            "preset": cfg.preset,
            "knobs": inputs.knobs.model_dump(),
            "median_depth": alignment.median_depth,
            "init_points": initial.points,
        },
    )


def dynamic_counts(scene: ply4d.Scene4D) -> list[int]:
    """The Gaussians of each stored dynamic set: one spacetime set, or one per timestamp."""
    if isinstance(scene.dynamic, SpacetimeGaussians):
        return [len(scene.dynamic)]
    return [len(g) for g in scene.dynamic]


def read_gt_views(panorama: Path) -> list[dict[str, Any]]:
    """gt/views.json entries beside the panorama (with 'camera' and 'image' loaded), or []."""
    path = panorama.parent / "gt" / "views.json"
    if not path.is_file():
        return []
    data = json.loads(path.read_text())
    views = []
    for entry in data["views"]:
        image = torch.from_numpy(
            np.ascontiguousarray(read_image(path.parent / entry["image"])[..., :3])
        )
        views.append({**entry, "camera": Camera.from_dict(entry), "pixels": image})
    return views


def contact_cameras(inputs: LiftInputs, median_depth: float, count: int = 4) -> list[Camera]:
    """Test views for the contact sheet: those that see most of the moving region, then the
    most level ones, each moved sideways by 1 % of the median depth to show parallax."""
    cameras = inputs.cameras
    n = len(cameras)
    seen = [float(inputs.moving_in_view(c).mean()) for c in cameras]
    moving = [i for i in sorted(range(n), key=lambda i: -seen[i]) if seen[i] > 0][: count // 2]
    level = sorted((i for i in range(n) if i not in moving),
                   key=lambda i: abs(float(cameras[i].forward[2])))  # fmt: skip
    chosen = (moving + level)[:count]
    offset = PREVIEW_ORBIT * median_depth
    cams = []
    for i in chosen:
        right = cameras[i].R[0]  # the camera's x axis in world coordinates
        cams.append(moved_camera(cameras[i], right * offset))
    return cams


def training_fit(inputs: LiftInputs, scene: ply4d.Scene4D) -> dict[str, Any]:
    """The two limits of what a scene can show, from its training data alone (a real
    panorama has no ground truth; bench/quality.py's layout fit and resampling ceiling are
    their twins against one). ``fit_psnr``: the Gaussians at t = 0 rendered at the training
    views against the working panorama they were fitted to. ``resolution_psnr``: the working
    panorama against the input, both resampled into the same views at the input's
    resolution, over the pixels that do not move (None when the working panorama is the
    input's own size). The larger error of the two says where more quality would come from:
    more Gaussians, or a finer working panorama."""
    frame0 = inputs.frames[0].permute(2, 0, 1).to(torch.float32)
    g = scene.at(0).to(inputs.device)
    squared, count = 0.0, 0
    with torch.no_grad():
        for cam in inputs.cameras:
            target = equirect_to_perspective(frame0, cam).permute(1, 2, 0)
            rgb = inputs.render(g, cam).rgb.clamp(0, 1).cpu()
            squared += float(((rgb - target) ** 2).sum())
            count += target.numel()
    fit = psnr_of_mse(squared / max(count, 1))
    working_w = int(frame0.shape[2])
    panorama = torch.from_numpy(read_image(inputs.cfg.panorama)).permute(2, 0, 1)
    input_w = int(panorama.shape[2])
    resolution = None
    if input_w > working_w:
        size = round(inputs.knobs.view_size * input_w / working_w)
        still = (~inputs.moving).to(torch.float32)
        working_frame = torch.cat([frame0, still[None]])
        squared, count = 0.0, 0
        for cam in view_layout(len(inputs.cameras), inputs.cfg.lift.fov_deg, size):
            # Views at the input's pixel size, sampled on every RESOLUTION_STRIDE-th row and
            # column: the same per-pixel comparison at a sixteenth of the samples (the mean
            # over 10⁵ pixels a view at draft), instead of tens of seconds at 6144 wide.
            dirs = cam.world_directions(torch.float64)[::RESOLUTION_STRIDE, ::RESOLUTION_STRIDE]
            # frame 0 and its still mask share the working size: one resampling.
            working = equirect_sampler(dirs, working_w, working_frame.shape[1])
            working = working.apply(working_frame)
            keep = working[3] > 0.999
            full = equirect_sampler(dirs, input_w, int(panorama.shape[1])).apply(panorama)
            error = working[:3] - full
            squared += float((error**2 * keep).sum())
            count += 3 * int(keep.sum())
        if count:
            resolution = psnr_of_mse(squared / count)
    return {
        "fit_psnr": fit,
        "resolution_psnr": resolution,
        "working_size": [working_w, int(frame0.shape[1])],
        "input_size": [input_w, int(panorama.shape[1])],
    }


def run_metrics(
    inputs: LiftInputs,
    scene: ply4d.Scene4D,
    alignment: Alignment,
    initial: InitialSets,
    static: StaticSet,
    dynamic: DynamicSets,
    timings: dict[str, float],
    path: Path,
    views: dict[str, Any] | None,
    fit: dict[str, Any],
) -> dict[str, Any]:
    """metrics.json: what the run took and made, what storing the static set once saved
    against storing (and training) every timestamp whole, and its limits (``training_fit``)."""
    n_static = len(scene.static)
    n_dynamic = dynamic_counts(scene)
    stored = n_static + sum(n_dynamic)
    # Every timestamp stored whole: the static set and its dynamic Gaussians (a spacetime
    # set's are all of them at every time).
    spacetime = isinstance(scene.dynamic, SpacetimeGaussians)
    per_time = n_dynamic * scene.num_times if spacetime else n_dynamic
    whole = sum(n_static + n for n in per_time)
    size = path.stat().st_size
    bytes_per = size / max(stored, 1)
    iters = inputs.knobs.gaussian_iterations
    # Every timestamp trained whole: at a step timed on the whole scene in whole views
    # (pipeline.whole_scene_step), or the static stage's step when nothing moved.
    step = dynamic.full_scene_step if dynamic.full_scene_step is not None else static.per_step
    whole_seconds = scene.num_times * iters * step
    spent = static.seconds + dynamic.seconds
    cfg = inputs.cfg
    return {
        "preset": cfg.preset,
        "knobs": inputs.knobs.model_dump(),
        "config_hash": config_hash(cfg),
        "working_size": [int(inputs.frames.shape[2]), int(inputs.frames.shape[1])],
        "timings_s": timings,
        "gaussians": {
            "static": n_static,
            "dynamic": n_dynamic,
            "timestamps": scene.num_times,
            # "spacetime", "tracked": one set, "dynamic" its count; "per_timestamp": a count
            # per timestamp
            "dynamic_model": inputs.knobs.dynamic_model,
            "stored": stored,
            "initial_points": initial.points,
        },
        "moving_fraction": float(inputs.moving.float().mean()),
        "median_depth": alignment.median_depth,
        "size_bytes": size,
        "saving": {
            "storage_whole_bytes_estimate": int(whole * bytes_per),
            "storage_ratio": size / max(whole * bytes_per, 1.0),
            "train_whole_seconds_estimate": whole_seconds,
            "train_seconds": spent,
            "train_ratio": spent / whole_seconds if whole_seconds > 0 else None,
        },
        "novel_views": views,
        "training_fit": fit,
    }
