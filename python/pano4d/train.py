"""``pano4d train``: both phases end to end, resumable (docs/design.md, "Files a run writes").

1. the animating phase (``pano4d.animate.pipeline.run_animate``), unless
   output/animate/frames holds a complete set put there by hand;
2. the lifting phase (``pano4d.lift.pipeline.lift``): depth, alignment, the static and the
   dynamic Gaussians, each stage checkpointed in output/checkpoints/;
3. its outputs (``pano4d.lift.export``): scene.ply4d, preview.mp4, contact.png, metrics.json.

A rerun after a kill skips what is done and resumes an optimisation from its last
checkpoint. ``demo`` makes a synthetic scene and trains it.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from pano4d.config import SceneConfig, config_hash, load_config
from pano4d.lift.checkpoints import CHECKPOINT_EVERY, Checkpoints, TrainError
from pano4d.lift.export import export
from pano4d.lift.pipeline import StepHook, frame_suffix, lift, trainer_for
from pano4d.progress import Bars


def run_train(
    cfg: SceneConfig,
    progress: bool = True,
    render_backend: str = "wgpu",
    on_step: StepHook | None = None,
    checkpoint_every: int = CHECKPOINT_EVERY,
    trainer: str | None = None,
) -> dict[str, Any]:
    """Run ``cfg`` end to end (resuming from checkpoints); returns the metrics written.

    ``on_step(stage, step)`` is called after every optimisation step of the align, static and
    dynamic stages (tests use it to interrupt a run at a known point). ``checkpoint_every``:
    optimisation steps between checkpoints (stages are always checkpointed when done).
    ``trainer``: "resident" (the training loop on the GPU) or "torch" (the torch reference);
    by default the resident one with the wgpu rasteriser, the torch one with the torch one.
    """
    if checkpoint_every < 1:
        raise ValueError(f"checkpoint_every must be ≥ 1, got {checkpoint_every}")
    trainer = trainer_for(render_backend, trainer)
    out = Path(cfg.output)
    out.mkdir(parents=True, exist_ok=True)
    checkpoints = Checkpoints(out / "checkpoints", config_hash(cfg), checkpoint_every)
    with Bars("loss", enabled=progress) as bars:
        start = time.perf_counter()
        frames_dir = out / "animate" / "frames"
        suffix = frame_suffix(cfg)
        # Frames written by the animating phase are re-checked by it (it skips when its inputs
        # are unchanged); a complete set put there by hand, with no record, is used as is.
        recorded = (out / "animate" / "done.json").is_file()
        if recorded or not _frames_complete(frames_dir, cfg.animate.frames, suffix):
            from pano4d.animate.pipeline import run_animate

            run_animate(cfg, progress=progress)
            if not _frames_complete(frames_dir, cfg.animate.frames, suffix):
                raise TrainError(
                    f"{frames_dir}: the animating phase did not write {cfg.animate.frames} frames"
                )
        animate_seconds = time.perf_counter() - start
        lifted = lift(
            cfg, frames_dir, checkpoints, bars, render_backend, trainer, on_step, animate_seconds
        )
        return export(lifted)


def _frames_complete(folder: Path, count: int, suffix: str) -> bool:
    return all((folder / f"{t:04d}{suffix}").is_file() for t in range(count))


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
