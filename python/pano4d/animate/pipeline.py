"""The animating phase as one resumable step: ``run_animate(cfg, size)`` (``pano4d animate``).

Reads the panorama and the regions, runs the configured backend (``flow``: the embedded
cinemagraph animator; ``svd``: the Panoramic Denoiser with a diffusers model), copies the
input into every pixel outside the soft region blend so static pixels are bit-identical,
and writes (docs/design.md, "Files a run writes")::

    output/animate/moving/static.png   the panorama as the frames hold it, once
    output/animate/moving/box.json     the bounding box of the blend (columns wrap at u = W)
    output/animate/moving/0000.png …   frame t inside that box (``pano4d.animate.frames``;
                                       16-bit PNG, 32-bit float EXR for an EXR input)
    output/animate/video.mp4           8-bit preview, at most PREVIEW_MAX_WIDTH wide
    output/animate/metrics.json        pano4d.metrics.animate_metrics of the frames, and
                                       the backend's own (svd: how it batched the UNet)
    output/animate/done.json           the inputs' hash: a finished run is skipped

That is the full-resolution store (``pano4d animate``, ``--frames-out``, ``pano4d eval``).
With ``size`` (w, h) smaller than the panorama, as ``pano4d train`` and ``pano4d views``
ask for the working panorama the lifting reads, the phase animates the input
area-downsampled once to that size (``animation_input``: prepare's filter; the regions
too, each keeping at least one pixel) and keeps the same files in a store of its own,
``output/animate/WxH/`` (frames as 32-bit float EXR, so the lifting reads exactly what was
made). Neither store invalidates the other; at the panorama's own size they are one.

Nothing outside the box is computed or written per frame: the flow backend warps only
the blend's pixels (``FlowAnimator.frame(t, box)``). Every file is written atomically.
``run.json`` records the same hash when a run starts: a run killed part-way resumes from
the first missing frame (the flow backend is
deterministic, so the frames it keeps are the frames it would write again; metrics.json
and done.json record that frame as ``resumed_at``); with another config or another input
the old frames are deleted first, once the new panorama and regions have been read.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
import torch.nn.functional as F
from rich.console import Console
from rich.table import Table

from pano4d.animate.frames import FrameBox, FrameStore, area_resize, frame_suffix
from pano4d.config import SceneConfig, config_hash
from pano4d.errors import InputError
from pano4d.fsutil import write_json_atomic
from pano4d.images import image_size, read_panorama, write_video
from pano4d.metrics import VideoMetrics
from pano4d.progress import Bars
from pano4d.regions import Regions, build_regions, moving_mask

# A working-size store keeps its frames as 32-bit float EXR: what the lifting reads is
# exactly what the animator made (a 16-bit PNG would round it).
WORKING_SUFFIX = ".exr"

PREVIEW_MAX_WIDTH = 2048


class AnimateError(InputError, RuntimeError):
    """The animating phase cannot run as configured; the message says what to fix."""


@dataclass
class AnimateResult:
    """Where the phase's outputs are, and what it measured."""

    folder: Path  # output/animate
    store: FrameStore  # the frames: output/animate/moving
    video: Path
    metrics: dict[str, Any]
    skipped: bool  # True when a finished run with the same inputs was found
    seconds: float
    resumed_at: int  # the first frame this run made (the frame count when none was missing)


def store_size(cfg: SceneConfig, size: tuple[int, int] | None) -> tuple[int, int] | None:
    """``size`` (w, h) when it is smaller than the panorama, None for the panorama's own
    size (the full-resolution store)."""
    if size is None or size == image_size(cfg.panorama):
        return None
    return size


def animate_folder(cfg: SceneConfig, size: tuple[int, int] | None = None) -> Path:
    """output/animate for the panorama's own size, output/animate/WxH for a smaller one."""
    folder = Path(cfg.output) / "animate"
    at = store_size(cfg, size)
    return folder if at is None else folder / f"{at[0]}x{at[1]}"


def frame_store(cfg: SceneConfig, size: tuple[int, int] | None = None) -> FrameStore:
    """Where ``run_animate`` keeps the frames of ``cfg`` at ``size``."""
    suffix = frame_suffix(cfg.panorama) if store_size(cfg, size) is None else WORKING_SUFFIX
    return FrameStore(animate_folder(cfg, size) / "moving", cfg.animate.frames, suffix)


@dataclass(frozen=True)
class AnimationInput:
    """What an animation is made from, at the size it is made at."""

    full: np.ndarray  # (H, W, 3) the panorama as read
    panorama: np.ndarray  # (h, w, 3) the panorama at the animation's size
    regions: Regions  # the regions at that size


def animation_input(cfg: SceneConfig, size: tuple[int, int] | None = None) -> AnimationInput:
    """The panorama and its regions at ``size`` (w, h; None: the panorama's own): the input
    area-downsampled once with the filter the lifting's ``prepare`` uses, and the regions
    on it (``regions.masks_at_size``: a region covering any input pixel keeps a pixel)."""
    full = read_panorama(cfg.panorama)
    height, width = full.shape[:2]
    regions = build_regions(cfg, width, height, size)
    if size is None or size == (width, height):
        return AnimationInput(full, full, regions)
    panorama = area_resize(torch.from_numpy(full), size).numpy()
    return AnimationInput(full, panorama, regions)


def run_animate(
    cfg: SceneConfig,
    size: tuple[int, int] | None = None,
    progress: bool = True,
    on_step: Callable[[str, int], None] | None = None,
) -> AnimateResult:
    """Run (or resume, or skip) the animating phase of ``cfg`` at ``size`` (w, h; None: the
    panorama's own); see the module docstring. ``on_step("animate", t)`` is called when
    frame t is written."""
    started = time.perf_counter()
    console = Console(stderr=True, quiet=not progress)
    size = store_size(cfg, size)
    folder = animate_folder(cfg, size)
    store = frame_store(cfg, size)
    count = cfg.animate.frames
    video = folder / "video.mp4"
    key = inputs_hash(cfg, size)

    done = _read_json(folder / "done.json")
    if done.get("inputs_hash") == key and store.complete() and video.is_file():
        metrics = _read_json(folder / "metrics.json")
        if metrics:
            console.print(f"[green]animate:[/] up to date in {folder}, skipped")
            print_metrics(console, metrics)
            return AnimateResult(folder, store, video, metrics, True, 0.0, count)

    # Bad input (the panorama, the regions, the backend's weights) fails here, before
    # anything of an earlier run is deleted.
    source = animation_input(cfg, size)
    panorama, regions = source.panorama, source.regions
    box = FrameBox.around(regions.blend > 0)
    run: dict[str, Any] = {"inputs_hash": key, "config_hash": config_hash(cfg)}
    previous = _read_json(folder / "run.json")
    stale = previous.get("inputs_hash") != key or not _same_box(store, box)
    missing = [t for t, p in enumerate(store.paths) if stale or not p.is_file()]
    render = None
    if missing:
        render, run["backend"] = frame_renderer(cfg, source, box)
    elif "backend" in previous:
        run["backend"] = previous["backend"]  # what made the frames kept

    if stale:
        # frames/: whole frames of a run before the frames were stored as boxes.
        old_frames = folder / "frames"
        for old in (store.folder, old_frames, folder / "done.json", folder / "metrics.json", video):
            if old.is_dir():
                shutil.rmtree(old)
            else:
                old.unlink(missing_ok=True)
    (folder / "done.json").unlink(missing_ok=True)
    # Kept with the run, so that a run resumed after its last frame still reports them.
    write_json_atomic(folder / "run.json", run)

    resumed_at = missing[0] if missing else count
    if render is not None:
        if not store.has_layout():
            store.write_layout(panorama, box)
        static_crop = box.crop(panorama)
        blend_crop = box.crop(regions.blend.numpy()[:, :, None])[:, :, 0]
        with Bars(enabled=progress, console=console) as bars:
            task = bars.task(f"animate ({cfg.animate.backend})", count, count - len(missing))
            for t in missing:
                store.write_crop(t, enforce_static(render(t), static_crop, blend_crop))
                task.advance()
                if on_step is not None:
                    on_step("animate", t)

    metrics = _write_video_and_measure(store, video, panorama, regions, cfg.animate.fps)
    metrics["backend"] = cfg.animate.backend
    metrics.update(run.get("backend", {}))
    metrics["seconds"] = time.perf_counter() - started
    metrics["resumed_at"] = resumed_at
    write_json_atomic(folder / "metrics.json", metrics)
    write_json_atomic(
        folder / "done.json",
        {"inputs_hash": key, "config_hash": config_hash(cfg), "frames": count,
         "resumed_at": resumed_at},
    )  # fmt: skip
    print_metrics(console, metrics)
    return AnimateResult(folder, store, video, metrics, False, metrics["seconds"], resumed_at)


def _same_box(store: FrameStore, box: FrameBox) -> bool:
    """Whether the store's frames are crops of ``box`` (True when it has none yet)."""
    if not store.box_path.is_file():
        return True
    try:
        return store.box() == box
    except InputError:
        return False


def progress(
    cfg: SceneConfig, size: tuple[int, int] | None = None
) -> Literal["done", "started"] | None:
    """How far the phase at ``size`` got in ``cfg``'s output folder: "done" (done.json,
    which a rerun checks against its inputs), "started" (frames written, not all: in the
    frame store, or whole frames put there by hand), or None (nothing)."""
    folder = animate_folder(cfg, size)
    if (folder / "done.json").is_file():
        return "done"
    if any((folder / "moving").glob("*")) or any((folder / "frames").glob("*")):
        return "started"
    return None


def inputs_hash(cfg: SceneConfig, size: tuple[int, int] | None = None) -> str:
    """sha256 of what the frames depend on: the animate settings, regions and seed, the
    size they are made at (None: the panorama's own), and the bytes of the panorama and of
    every mask file."""
    digest = hashlib.sha256()
    settings = {
        "panorama": str(cfg.panorama),
        "regions": [r.model_dump(mode="json") for r in cfg.regions],
        "animate": cfg.animate.model_dump(mode="json"),
        "seed": cfg.seed,
    }
    if size is not None:  # the full-resolution store's hash is what it was before sizes
        settings["size"] = list(size)
    digest.update(json.dumps(settings, sort_keys=True).encode())
    files = [Path(cfg.panorama)] + [Path(r.mask) for r in cfg.regions if r.mask is not None]
    for path in files:
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 22), b""):
                digest.update(block)
    return digest.hexdigest()


def enforce_static(
    frame: np.ndarray | torch.Tensor, panorama: np.ndarray, blend: np.ndarray
) -> np.ndarray:
    """The frame with the panorama's own pixels wherever the blend weight is 0 (any same
    part of the three: the whole image or the frame box)."""
    frame = frame.numpy() if isinstance(frame, torch.Tensor) else np.asarray(frame)
    if frame.shape != panorama.shape:
        raise AnimateError(
            f"the backend made a frame of shape {frame.shape}, expected {panorama.shape}"
        )
    return np.where(blend[:, :, None] > 0, frame.astype(np.float32), panorama)


# --- backends ----------------------------------------------------------------------------
def frame_renderer(
    cfg: SceneConfig, source: AnimationInput, box: FrameBox | None
) -> tuple[Callable[[int], np.ndarray | torch.Tensor], dict[str, Any]]:
    """A function from frame index to the frame's pixels at ``source``'s size (in ``box``,
    or whole for None) for the configured backend, and what the backend reports for the
    metrics (svd: how it batched the UNet)."""
    crop = (lambda image: image) if box is None else box.crop
    if cfg.animate.backend == "flow":
        from pano4d.animate.flow import FlowAnimator

        panorama = torch.from_numpy(source.panorama)
        animator = FlowAnimator(panorama, source.regions, cfg.animate.frames, cfg.seed)
        return lambda t: animator.frame(t, box), {}
    if cfg.animate.backend == "svd":
        weights = cfg.animate.weights
        if weights is None or not Path(weights).is_dir():
            raise AnimateError(
                f"backend 'svd' needs a local diffusers model folder in animate.weights, "
                f"got {weights} (not found)"
            )
        try:
            from pano4d.animate.svd import AttentionLimitError, OutputFrames, animate_svd
        except ImportError as error:
            raise AnimateError(
                f"backend 'svd' is not available in this installation ({error}); use backend: flow"
            ) from error
        height, width = source.full.shape[:2]
        at_full_size = source.panorama is source.full
        # The UNet's views come from the input at its own resolution; the video is decoded
        # and blended at the animation's size.
        full_mask = source.regions.mask if at_full_size else moving_mask(cfg, width, height)
        output = OutputFrames(
            torch.from_numpy(source.panorama).permute(2, 0, 1), source.regions.blend
        )
        try:
            made = animate_svd(
                cfg, torch.from_numpy(source.full).permute(2, 0, 1), full_mask, output=output
            )
        except AttentionLimitError as error:
            raise AnimateError(str(error)) from error
        video = made.video
        expected = (cfg.animate.frames, 3, *source.panorama.shape[:2])
        if tuple(video.shape) != expected:
            raise AnimateError(f"backend 'svd' returned {tuple(video.shape)}, expected {expected}")
        return lambda t: crop(video[t].permute(1, 2, 0).float().cpu().numpy()), made.batching
    raise AnimateError(f"unknown animate backend {cfg.animate.backend!r}")


# --- outputs -----------------------------------------------------------------------------
def _write_video_and_measure(
    store: FrameStore, video: Path, panorama: np.ndarray, regions: Regions, fps: float
) -> dict[str, Any]:
    """Read the frames back once (whole, as a user gets them): encode the preview and
    measure them on the way."""
    metrics = VideoMetrics(panorama, regions.mask)
    box = store.box()

    def frames() -> Iterator[np.ndarray]:
        for frame in store.frames():
            metrics.add(frame, rows=(box.top, box.bottom))  # the rest is the static panorama
            yield _preview(frame)

    write_video(video, frames(), fps)
    return metrics.result()


def _preview(frame: np.ndarray) -> np.ndarray:
    """The frame area-averaged by a power of two to at most PREVIEW_MAX_WIDTH wide."""
    factor = 1
    height, width = frame.shape[:2]
    while width // factor > PREVIEW_MAX_WIDTH and height % (2 * factor) == 0:
        factor *= 2
    if factor == 1:
        return frame
    t = torch.from_numpy(np.ascontiguousarray(frame)).permute(2, 0, 1)[None]
    return F.avg_pool2d(t, factor)[0].permute(1, 2, 0).numpy()


def print_metrics(console: Console, metrics: dict[str, Any]) -> None:
    table = Table(title="animate metrics", show_header=True)
    table.add_column("metric")
    table.add_column("value", justify="right")
    for name, value in metrics.items():
        shown = f"{value:.6g}" if isinstance(value, float) else str(value)
        table.add_row(name, shown)
    console.print(table)


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}
