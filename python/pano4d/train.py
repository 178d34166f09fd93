"""``pano4d train``: both phases end to end, resumable (docs/design.md, "Files a run writes").

1. the animating phase at the working panorama's size (``lift.pipeline.animation_frames``:
   ``pano4d.animate.pipeline.run_animate``, its frames in output/animate/WxH/moving),
   unless output/animate/frames holds a complete set of whole frames put there by hand;
2. the lifting phase (``pano4d.lift.pipeline.lift``): depth, alignment, the static and the
   dynamic Gaussians, each stage checkpointed in output/checkpoints/;
3. its outputs (``pano4d.lift.export``): scene.ply4d, preview.mp4, contact.png, metrics.json.

A rerun after a kill skips what is done and resumes each stage where its last checkpoint
left it; metrics.json's ``resumed_at`` says where that was. ``demo`` makes a synthetic
scene and trains it.

Tests kill a real ``pano4d train`` inside a stage through one environment variable,
``PANO4D_TEST_KILL_AT=stage:n`` (``kill_hook_from_env``): the process sends itself SIGKILL
at the n-th step callback of that stage (animate, depth, align, static, dynamic, export;
what a step is: ``lift.pipeline.StepHook``).
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path
from typing import Any

from pano4d.config import SceneConfig, config_hash, load_config
from pano4d.lift.checkpoints import CHECKPOINT_EVERY, Checkpoints
from pano4d.lift.export import export
from pano4d.lift.pipeline import (
    SnapshotHook,
    StepHook,
    animation_frames,
    lift,
    working_panorama,
)
from pano4d.lift.pipeline import resume_point as lift_resume_point
from pano4d.lift.trainers import trainer_for
from pano4d.progress import Bars

KILL_AT_ENV = "PANO4D_TEST_KILL_AT"


def run_train(
    cfg: SceneConfig,
    progress: bool = True,
    render_backend: str = "wgpu",
    on_step: StepHook | None = None,
    checkpoint_every: int = CHECKPOINT_EVERY,
    trainer: str | None = None,
    on_snapshot: SnapshotHook | None = None,
) -> dict[str, Any]:
    """Run ``cfg`` end to end (resuming from checkpoints); returns the metrics written.

    ``on_step(stage, step)`` is called after every step of every stage (what a step is:
    ``lift.pipeline.StepHook``); without one, ``PANO4D_TEST_KILL_AT`` may set one.
    ``checkpoint_every``: optimisation steps between checkpoints (stages are always
    checkpointed when done). ``trainer``: "resident" (the training loop on the GPU) or
    "torch" (the torch reference); by default the resident one with the wgpu rasteriser,
    the torch one with the torch one. ``on_snapshot(snapshot)`` sees the scene whenever the
    static and dynamic stages read their Gaussians back anyway (``lift.pipeline.SceneSnapshot``:
    at checkpoints and each optimisation's end): ``pano4d train --serve``'s live view.
    """
    if checkpoint_every < 1:
        raise ValueError(f"checkpoint_every must be ≥ 1, got {checkpoint_every}")
    trainer = trainer_for(render_backend, trainer)
    on_step = on_step if on_step is not None else kill_hook_from_env()
    out = Path(cfg.output)
    out.mkdir(parents=True, exist_ok=True)
    checkpoints = checkpoints_of(cfg, checkpoint_every)
    with Bars("loss", enabled=progress) as bars:
        start = time.perf_counter()
        frames_dir = animation_frames(cfg, checkpoints, progress, on_step)
        animate_seconds = time.perf_counter() - start
        lifted = lift(
            cfg, frames_dir, checkpoints, bars, render_backend, trainer, on_step, animate_seconds,
            on_snapshot,
        )  # fmt: skip
        return export(lifted, on_step)


def checkpoints_of(cfg: SceneConfig, every: int = CHECKPOINT_EVERY) -> Checkpoints:
    """The stage checkpoints of ``cfg``'s run, in OUTPUT/checkpoints."""
    return Checkpoints.for_config(Path(cfg.output) / "checkpoints", cfg, every)


def finished_metrics(cfg: SceneConfig) -> dict[str, Any] | None:
    """The run's metrics.json if ``run_train`` finished this very config, else None.

    ``run_train`` writes metrics.json last, after scene.ply4d, so a file carrying this
    config's hash means the whole run is done.
    """
    out = Path(cfg.output)
    try:
        metrics = json.loads((out / "metrics.json").read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(metrics, dict) or metrics.get("config_hash") != config_hash(cfg):
        return None
    return metrics if (out / "scene.ply4d").is_file() else None


def resume_point(cfg: SceneConfig) -> str | None:
    """Where ``run_train`` would pick ``cfg``'s run up, as each phase reads its own state
    (``lift.pipeline.resume_point``, ``animate.pipeline.progress``); None for a fresh
    start."""
    from pano4d.animate.pipeline import progress

    lifted = lift_resume_point(checkpoints_of(cfg), cfg.animate.frames)
    if lifted is not None:
        return lifted
    animated = progress(cfg, working_panorama(cfg)[1])
    if animated == "done":
        return "depth frame 0"
    return "animate" if animated == "started" else None


def kill_hook_from_env() -> StepHook | None:
    """For tests: ``PANO4D_TEST_KILL_AT=stage:n`` kills this process (SIGKILL, no clean-up)
    at the n-th step callback of ``stage``, counted from 1 in this process; unset: None."""
    spec = os.environ.get(KILL_AT_ENV)
    if not spec:
        return None
    stage, _, count = spec.partition(":")
    if not count.isdigit() or int(count) < 1:
        raise ValueError(f"{KILL_AT_ENV}={spec!r}: expected stage:n with n ≥ 1")
    calls = 0

    def kill(name: str, _step: int) -> None:
        nonlocal calls
        if name == stage:
            calls += 1
            if calls == int(count):
                os.kill(os.getpid(), signal.SIGKILL)

    return kill


def demo(
    out: Path,
    width: int = 1024,
    frames: int = 8,
    seed: int = 0,
    preset: str = "draft",
    progress: bool = True,
    render_backend: str = "wgpu",
) -> dict[str, Any]:
    """Synthetic scene + ``train`` at ``preset`` into ``out``; returns the metrics."""
    from pano4d.synth import run_synth

    scene_yaml = run_synth(Path(out), width, width // 2, frames, seed)
    cfg = load_config(scene_yaml)
    cfg = cfg.model_copy(update={"preset": preset})
    return run_train(cfg, progress=progress, render_backend=render_backend)
