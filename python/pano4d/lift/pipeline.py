"""The lifting phase in order (Dynamic Panoramic Lifting): animation frames → 4D Gaussians.

``lift(cfg, frames_dir, …)`` runs the stages, each a function from typed inputs to typed
outputs, each checkpointed atomically in output/checkpoints/ (``lift.checkpoints``: a rerun
after a kill skips what is done and resumes an optimisation from its last checkpoint):

1. ``prepare``          frames at the working resolution, the moving region, the views;
2. ``estimate_depth``   Θ per frame and view (``lift.depth``);
3. ``align_depth``      spherical depth per frame (``lift.align``), frames after the first
                        re-fitted only in the moving region;
4. ``initial_sets``     Gaussians from frame 0's depth, split into a static and a dynamic
                        set by the moving region (``lift.initial``);
5. ``fit_static``       the static set, optimised once on frame 0 with the moving region
                        masked out;
6. ``fit_dynamic``      per timestamp, the dynamic set, warm-started from t − 1 (its
                        colours moved by the frame's change) and optimised against the
                        frozen static set, in the views that see it; or, with the knob
                        ``dynamic_model: spacetime``, ``fit_spacetime``: one set for every
                        timestamp, each Gaussian with functions of time
                        (``pano4d.spacetime``), optimised once on (view, time) pairs;
                        or, with ``dynamic_model: tracked``, ``fit_tracked``: the
                        per-timestamp loop with one set whose positions and colours
                        alone follow the frames, stored as one spacetime set;
then ``lift.export`` writes scene.ply4d, preview.mp4, contact.png and metrics.json, and
each optimisation's ``TrainLog`` (``lift.diagnosis``: loss terms, densify-and-prune counts,
kept in the stage checkpoints with the trainer) as densify.jsonl, losses.json and loss.png.

The lifting works at the resolution the views need: frames are area-downsampled to an
equirect whose pixel matches a view pixel (``view_size`` over ``fov_deg``), never above the
input's. Every optimiser is built by ``make_trainer``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

from pano4d.animate.frames import WholeFrames, frame_suffix, open_frames
from pano4d.camera import Camera
from pano4d.config import OptimisationKnobs, PresetKnobs, SceneConfig
from pano4d.device import resolve_device
from pano4d.gaussians import Gaussians
from pano4d.images import image_size
from pano4d.lift.align import DepthAligner, FrameAlignment
from pano4d.lift.checkpoints import Checkpoints, TrainError
from pano4d.lift.convergence import StopRule
from pano4d.lift.depth import make_depth_backend
from pano4d.lift.diagnosis import LOSS_EVERY, TrainLog
from pano4d.lift.features import make_feature_model
from pano4d.lift.initial import (
    follow_frame_change,
    init_gaussians,
    init_sphere,
    points_in_mask,
    spacetime_start,
)
from pano4d.lift.trainer import FeatureModel, Knobs, RenderFn, TrainedSet, Trainer, TrainViews
from pano4d.lift.trainers import trainer_kind
from pano4d.lift.windows import previous_in_windows, reach_window, touching, windowed
from pano4d.progress import Bars, Task
from pano4d.regions import grow, moving_in_video, moving_mask
from pano4d.resample import equirect_to_perspective
from pano4d.spacetime import SpacetimeGaussians, TimeModel
from pano4d.sphere import view_layout

# on_step(stage, step): called after every unit of work a stage can be interrupted after:
# a frame of the animate and depth stages (step: its index), an optimisation step of the
# align (step: the iteration within the frame), static and dynamic stages (step: steps
# done) and a file of the export (step: files written). Tests interrupt a run with it.
StepHook = Callable[[str, int], None]


@dataclass(frozen=True)
class SceneSnapshot:
    """The scene as the static and dynamic stages have it at one of the moments they read
    the trained Gaussians back anyway: a checkpoint (``run_trainer``) or an optimisation's
    end. What a live view shows (``pano4d.live``); nothing is read from the device for it.

    Its sets are the stages' own (never changed once handed over): copy nothing to keep
    one, and convert them off the training thread."""

    optimisation: str  # the one in progress, as its TrainLog names it: "static", "dynamic t=2"
    step: int  # its steps done
    iterations: int  # of at most this many
    static: Gaussians  # the static set (the one in training, in the static stage)
    # None in the static stage; in the dynamic stage one set per timestamp (those done and
    # the one in training, last) or one spacetime set for every timestamp.
    dynamic: list[Gaussians] | SpacetimeGaussians | None
    timestamps: int  # the animation's frames
    antialiased: bool  # trained in the antialiased mode (docs/rasterizer.md, "Two modes")
    focal_px: float  # the training views' focal length in pixels


# on_snapshot(snapshot): called with the scene at each checkpoint of the static and dynamic
# stages and at each of their optimisations' ends (``SceneSnapshot``), never in between.
SnapshotHook = Callable[[SceneSnapshot], None]
# Inside a stage: the trained set as read back, and its step.
ReadBackHook = Callable[[Gaussians | SpacetimeGaussians, int], None]


# --- 1. inputs -------------------------------------------------------------------------------
@dataclass(frozen=True)
class LiftInputs:
    """What every stage reads, fixed once by ``prepare``."""

    cfg: SceneConfig
    knobs: PresetKnobs
    device: torch.device
    cameras: list[Camera]  # the view layout, views of knobs.view_size pixels
    frames: torch.Tensor  # (L, H, W, 3) at the working resolution
    moving: torch.Tensor  # (H, W) bool, the grown moving region at the working resolution
    render_backend: str  # "wgpu" | "torch"
    trainer: str  # a key of trainers.TRAINERS

    def render(self, g: Gaussians, camera: Camera, background: torch.Tensor | None = None) -> Any:
        from pano4d.renderer import render

        return render(
            g, camera, background=background, backend=self.render_backend,
            antialiased=self.knobs.antialiased,
        )  # fmt: skip

    def moving_in_view(self, camera: Camera) -> torch.Tensor:
        """The moving region seen by ``camera``: (h, w) float in [0, 1]."""
        return equirect_to_perspective(self.moving.to(torch.float32), camera)


def working_size(width: int, view_size: int, fov_deg: float) -> tuple[int, int]:
    """Equirect size (W, H) whose pixel matches a view pixel, at most the input's width."""
    target = round(360.0 * view_size / fov_deg / 2) * 2
    w = min(width, max(64, target))
    return w, w // 2


def working_panorama(cfg: SceneConfig) -> tuple[PresetKnobs, tuple[int, int]]:
    """The preset's knobs and the working panorama's size (W, H) for ``cfg``, both from the
    input panorama's size (never from the frames', which may be the working size itself)."""
    input_width = image_size(cfg.panorama)[0]
    knobs = cfg.resolved_preset(input_width)
    return knobs, working_size(input_width, knobs.view_size, cfg.lift.fov_deg)


def read_frames(folder: Path, count: int, size: tuple[int, int], suffix: str) -> torch.Tensor:
    """The animation frames in ``folder`` (the animating phase's store at any size or whole
    frames put there by hand: ``animate.frames.open_frames``) as (L, H, W, 3)
    area-downsampled to ``size`` (W, H)."""
    return open_frames(folder, count, suffix).area_downsampled(size)


def animation_frames(
    cfg: SceneConfig, checkpoints: Checkpoints, progress: bool, on_step: StepHook | None
) -> Path:
    """The folder of the animation's frames the lifting reads, after running the animating
    phase at the working panorama's size if needed (its own store: ``run_animate(cfg,
    size)``; it skips when its inputs are unchanged).

    A complete set of whole frames put in output/animate/frames by hand, with no record of
    the animating phase beside it, is used as is (``prepare`` downsamples it)."""
    out = Path(cfg.output)
    frames_dir = out / "animate" / "frames"
    suffix = frame_suffix(cfg.panorama)
    recorded = (out / "animate" / "done.json").is_file()
    if recorded or not WholeFrames(frames_dir, cfg.animate.frames, suffix).complete():
        from pano4d.animate.pipeline import run_animate

        size = working_panorama(cfg)[1]
        animated = run_animate(cfg, size, progress=progress, on_step=on_step)
        checkpoints.resumed("animate", frame=animated.resumed_at)
        frames_dir = animated.store.folder
        if not animated.store.complete():
            raise TrainError(
                f"{frames_dir}: the animating phase did not write {cfg.animate.frames} frames"
            )
    return frames_dir


def moving_region(
    cfg: SceneConfig, frames: torch.Tensor, full_size: tuple[int, int]
) -> torch.Tensor:
    """(H, W) bool at the resolution of ``frames`` (L, H, W, 3): the configured regions
    (masks made at the panorama's ``full_size`` (W, H)) and every pixel that changes in the
    video, grown by regions.MARGIN_DEG on the sphere, as the animating phase grows them."""
    height, width = frames.shape[1:3]
    regions = moving_mask(cfg, *full_size)
    regions = F.interpolate(regions[None, None].float(), size=(height, width), mode="area")
    return grow(moving_in_video(frames, regions[0, 0] > 0))


def prepare(
    cfg: SceneConfig, frames_dir: Path, render_backend: str, trainer: str
) -> LiftInputs:
    """The frames at the working resolution and what moves in them (``moving_region``).

    ``frames_dir`` holds the animating phase's frames at any size (``animation_frames``:
    the working size itself, or whole frames put there by hand), area-downsampled here to
    the working size (``read_frames``)."""
    full_w, full_h = image_size(cfg.panorama)
    knobs, size = working_panorama(cfg)
    frames = read_frames(frames_dir, cfg.animate.frames, size, frame_suffix(cfg.panorama))
    return LiftInputs(
        cfg=cfg,
        knobs=knobs,
        device=resolve_device(cfg.device),
        cameras=view_layout(cfg.lift.views, cfg.lift.fov_deg, knobs.view_size),
        frames=frames,
        moving=moving_region(cfg, frames, (full_w, full_h)),
        render_backend=render_backend,
        trainer=trainer,
    )


# --- 2. depth --------------------------------------------------------------------------------
@dataclass(frozen=True)
class ViewDepth:
    depth: torch.Tensor  # (L, n, h, w) ray length per frame and view
    seconds: float


def estimate_depth(
    inputs: LiftInputs, checkpoints: Checkpoints, bars: Bars, on_step: StepHook | None
) -> ViewDepth:
    start = time.perf_counter()
    state = checkpoints.load("depth") or {"depth": []}
    done: list[torch.Tensor] = list(state["depth"])
    total = len(inputs.frames)
    checkpoints.resumed("depth", frame=len(done))
    if len(done) < total:
        backend = make_depth_backend(inputs.cfg.depth, inputs.device)
        task = bars.task(f"depth ({backend.name})", total, len(done))
        for t in range(len(done), total):
            frame = inputs.frames[t].to(inputs.device)
            done.append(backend.view_depth(frame, inputs.cameras).cpu())
            checkpoints.save("depth", {"depth": done})
            task.update(t + 1, loss=math.nan)
            if on_step is not None:
                on_step("depth", t)
    return ViewDepth(torch.stack(done), time.perf_counter() - start)


# --- 3. alignment ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Alignment:
    frames: list[FrameAlignment]
    depths: list[torch.Tensor]  # (H, W) aligned ray length per frame, working resolution
    median_depth: float  # of frame 0, sky and other far depth left out
    seconds: float


def align_depth(
    inputs: LiftInputs,
    view_depth: torch.Tensor,
    checkpoints: Checkpoints,
    bars: Bars,
    on_step: StepHook | None,
) -> Alignment:
    start = time.perf_counter()
    iterations = inputs.knobs.align_iterations
    aligner = DepthAligner(inputs.cameras, iterations=iterations, device=inputs.device)
    moving_points = points_in_mask(aligner.ico.points, inputs.moving)
    state = checkpoints.load("align") or {"frames": []}
    done = [FrameAlignment.from_dict(d, inputs.device) for d in state["frames"]]
    checkpoints.resumed("align", frame=len(done))  # a frame's fit is checkpointed when done
    for t in range(len(done), len(inputs.frames)):
        total = iterations if t == 0 else aligner.warm_iterations
        task = bars.task(f"align frame {t}", total)

        def step(i: int, n: int, loss: float, _task: Task = task) -> None:
            _task.update(i + 1, loss=loss)
            if on_step is not None:
                on_step("align", i)

        previous = done[-1] if done else None
        done.append(aligner.fit(view_depth[t], previous, moving_points if done else None, step))
        checkpoints.save("align", {"frames": [d.to_dict() for d in done]})
    seconds = time.perf_counter() - start
    height, width = inputs.frames.shape[1:3]
    depths = [aligner.equirect_depth(a, width, height) for a in done]
    far = 0.9 * inputs.cfg.depth.far
    finite = depths[0][depths[0] < far]
    median = float(finite.median()) if finite.numel() else float(depths[0].median())
    return Alignment(done, depths, median, seconds)


# --- 4. initial Gaussians --------------------------------------------------------------------
@dataclass(frozen=True)
class InitialSets:
    static: Gaussians
    dynamic: Gaussians
    points: int  # icosphere samples, static + dynamic
    spacing_rad: float


def initial_sets(inputs: LiftInputs, depth0: torch.Tensor) -> InitialSets:
    """One Gaussian per icosphere sample at frame 0's aligned depth ``depth0`` (H, W); the
    samples in the moving region form the dynamic set, the rest the static set."""
    knobs = inputs.knobs
    # The spacing counts working pixels, so a preset starts from as many Gaussians per pixel
    # of what it trains on whatever the input's width.
    width = inputs.frames.shape[2]
    stride = knobs.init_stride
    ico = init_sphere(width, stride)
    while len(ico) > knobs.max_gaussians:  # keep the initial set within budget
        stride += 1
        ico = init_sphere(width, stride)
    points = ico.points
    dynamic = points_in_mask(points, inputs.moving)
    frame0 = inputs.frames[0].to(inputs.device)
    depth = depth0.to(inputs.device)
    static = init_gaussians(points[~dynamic], ico.spacing_rad, depth, frame0, knobs.sh_degree)
    moving = init_gaussians(points[dynamic], ico.spacing_rad, depth, frame0, knobs.sh_degree)
    return InitialSets(static, moving, len(points), ico.spacing_rad)


# --- 5. and 6. optimisation ------------------------------------------------------------------
def make_trainer(
    kind: str,
    gaussians: TrainedSet,
    views: TrainViews,
    knobs: Knobs,
    render: RenderFn,
    static: Gaussians | None = None,
    features: FeatureModel | None = None,
    seed: int = 0,
) -> Trainer[TrainedSet]:
    """The optimiser of one set of Gaussians or spacetime set (its result of the same
    kind), over the frozen ``static`` set if given: the one place the stages build one.
    ``kind`` is a key of trainers.TRAINERS; both trainers see the same views in the same
    order (same seed). ``render`` is the torch trainer's rasteriser; the resident one
    renders on the device."""
    return trainer_kind(kind).build(gaussians, views, knobs, render, static, features, seed)


def resume(trainer: Trainer, state: dict[str, Any], kind: str, path: Path) -> None:
    """Continue ``trainer`` from a stage checkpoint's state, if it holds one; a checkpoint of
    the other trainer is refused (their states differ) with what to do."""
    if "trainer" not in state:
        return
    written = state.get("trainer_kind")
    if written != kind:
        raise TrainError(
            f"{path}: written by the {written} trainer, this run uses the {kind} one; rerun "
            f"with --trainer {written}, or delete the file to restart that stage"
        )
    trainer.load_state_dict(state["trainer"])


def trainer_knobs(
    knobs: PresetKnobs,
    iterations: int,
    budget: int,
    median_depth: float,
    cameras: list[Camera],
    working_width: int,
) -> Knobs:
    """One stage's optimisation knobs: the preset's optimisation knobs as they are, and this
    stage's steps, budget, densification interval and units, and L_sem scale. ``cameras``:
    the whole views the stage trains on."""
    view = cameras[0]
    return Knobs(
        **{name: getattr(knobs, name) for name in OptimisationKnobs.model_fields},
        iterations=iterations,
        max_gaussians=max(1, budget),
        # At least one pass over the views between two densify-and-prunes: room for the
        # children to settle before their gradients are judged.
        densify_every=max(10, iterations // 10, len(cameras)),
        pixel_angle=2 * math.pi / working_width,
        gradient_scale=view.width * view.height / float(view.fx),
        sem_scale=median_depth,
    )


def views_of_frame(
    inputs: LiftInputs,
    t: int,
    view_depth: torch.Tensor,
    weight_fn: Callable[[Camera], torch.Tensor],
    indices: list[int] | None = None,
) -> TrainViews:
    """Targets, loss weights and Θ's z-depth of frame ``t`` in the views ``indices``."""
    indices = indices if indices is not None else list(range(len(inputs.cameras)))
    cams = [inputs.cameras[i] for i in indices]
    image = inputs.frames[t].permute(2, 0, 1)
    targets = torch.stack([equirect_to_perspective(image, c).permute(1, 2, 0) for c in cams])
    weights = torch.stack([weight_fn(c) for c in cams])
    z = torch.stack([view_depth[i] / inputs.cameras[i].z_to_ray_factor() for i in indices])
    d = inputs.device
    return TrainViews(cams, targets.to(d), weights.to(d), z.to(d))


def run_trainer(
    trainer: Trainer,
    kind: str,
    log: TrainLog,
    checkpoints: Checkpoints,
    name: str,
    bars: Bars,
    on_step: StepHook | None,
    extra: Callable[[], dict[str, Any]],
    rule: StopRule,
    on_read_back: ReadBackHook | None = None,
) -> Gaussians:
    """Run a trainer (of ``kind``) with a progress bar, its loss terms (every LOSS_EVERY steps
    and at the last) and densify-and-prunes recorded in ``log``, and a checkpoint every
    ``checkpoints.every`` steps (``extra()`` adds the stage's own state to it, its log too).
    ``rule`` decides, at each loss record, whether it has converged; where and why it
    stopped goes into ``log.stop``. ``on_read_back(trained, step)`` gets the trained set each
    checkpoint has read back, and the result."""
    task = bars.task(log.name, trainer.knobs.iterations, trainer.step)

    def step(tr: Trainer) -> bool:
        task.update(tr.step, loss=tr.last_loss)
        stop = None
        if tr.step % LOSS_EVERY == 0 or tr.step == tr.knobs.iterations:
            log.record_loss(tr.step, tr.last_view, tr.last_terms)
            stop = rule.check(log.losses, tr.step)
        if tr.last_densify is not None and tr.last_densify.step == tr.step:
            log.densify.append(tr.last_densify)
        if stop is not None:
            log.stop = stop
            task.update(tr.knobs.iterations, loss=tr.last_loss)
        elif tr.step % checkpoints.every == 0:
            trainer_state = tr.state_dict()
            checkpoints.save(name, {**extra(), "trainer": trainer_state, "trainer_kind": kind})
            if on_read_back is not None:  # what the checkpoint read, not a read-back of its own
                on_read_back(tr.trained_in(trainer_state), tr.step)
        if on_step is not None:
            on_step(name, tr.step)
        return stop is not None

    result = trainer.run(step)
    if on_read_back is not None:
        on_read_back(result, trainer.step)
    return result


def snapshot_hook(
    on_snapshot: SnapshotHook | None,
    inputs: LiftInputs,
    optimisation: str,
    iterations: int,
    scene: Callable[[Any], tuple[Gaussians, list[Gaussians] | SpacetimeGaussians | None]],
) -> ReadBackHook | None:
    """``run_trainer``'s read-back hook for one optimisation: the scene ``scene(trained)``
    makes of the set read back (its static set and its dynamic sets), handed to
    ``on_snapshot``; None without one."""
    if on_snapshot is None:
        return None

    def show(trained: Gaussians | SpacetimeGaussians, step: int) -> None:
        static, dynamic = scene(trained)
        on_snapshot(SceneSnapshot(
            optimisation, step, iterations, static, dynamic, len(inputs.frames),
            inputs.knobs.antialiased, float(inputs.cameras[0].fx),
        ))  # fmt: skip

    return show


@dataclass(frozen=True)
class StaticSet:
    gaussians: Gaussians
    seconds: float  # optimisation time, over every resumed part
    per_step: float  # seconds per step of this run (what whole-timestamp training would cost)
    log: TrainLog


def fit_static(
    inputs: LiftInputs,
    initial: Gaussians,
    view_depth0: torch.Tensor,
    median_depth: float,
    checkpoints: Checkpoints,
    bars: Bars,
    on_step: StepHook | None,
    on_snapshot: SnapshotHook | None = None,
) -> StaticSet:
    state = checkpoints.load("static") or {"seconds": 0.0}
    knobs = inputs.knobs
    iterations = knobs.gaussian_iterations
    show = snapshot_hook(on_snapshot, inputs, "static", iterations, lambda g: (g, None))
    if "done" in state:
        checkpoints.resumed("static", step=iterations)
        done = Gaussians.from_numpy(state["done"], inputs.device)
        log = TrainLog.from_dict(state["log"])
        if show is not None:  # a rerun shows the static set it resumes the dynamic stage on
            show(done, iterations)
        return StaticSet(done, state["seconds"], state["per_step"], log)
    views = views_of_frame(
        inputs,
        0,
        view_depth0,
        lambda c: (inputs.moving_in_view(c) < 0.5).to(torch.float32),
    )
    trainer = make_trainer(
        inputs.trainer,
        initial,
        views,
        trainer_knobs(
            knobs,
            iterations,
            knobs.max_gaussians,
            median_depth,
            inputs.cameras,
            inputs.frames.shape[2],
        ),
        inputs.render,
        features=make_feature_model(inputs.cfg.features, inputs.device),
        seed=inputs.cfg.seed,
    )
    log = TrainLog("static", len(initial))
    if "trainer" in state:
        resume(trainer, state, inputs.trainer, checkpoints.path("static"))
        log = TrainLog.from_dict(state["log"])
    checkpoints.resumed("static", step=trainer.step)
    start, first_step = time.perf_counter(), trainer.step

    def seconds() -> float:
        return float(state["seconds"]) + time.perf_counter() - start

    result = run_trainer(
        trainer, inputs.trainer, log, checkpoints, "static", bars, on_step,
        lambda: {"seconds": seconds(), "log": log.to_dict()}, StopRule.fixed(iterations), show,
    )  # fmt: skip
    per_step = (time.perf_counter() - start) / max(1, trainer.step - first_step)
    checkpoints.save("static", {
        "done": result.to_numpy(), "seconds": seconds(), "per_step": per_step,
        "log": log.to_dict(),
    })  # fmt: skip
    return StaticSet(result, seconds(), per_step, log)


@dataclass(frozen=True)
class DynamicSets:
    # One set per timestamp (dynamic_model "per_timestamp"), or one set with functions of
    # time for every timestamp ("spacetime", "tracked").
    gaussians: list[Gaussians] | SpacetimeGaussians
    seconds: float
    # Seconds per step when a step renders the whole static set and the dynamic set in
    # whole views, as training each timestamp whole would (``whole_scene_step``); None when
    # nothing was optimised.
    full_scene_step: float | None
    logs: list[TrainLog]  # one per optimisation (a timestamp's, or the spacetime set's)


WHOLE_SCENE_STEPS = 10  # steps ``whole_scene_step`` times, after one to warm up


def dynamic_iterations(full: int, t: int, later_share: float) -> int:
    """At most this many steps for timestamp t: the full count first, ``later_share`` of it
    for the warm-started later ones; the stop rule (``convergence``) may end either sooner."""
    return full if t == 0 else max(1, round(full * later_share))


def previous_renders(
    inputs: LiftInputs, static: Gaussians, previous: Gaussians, cameras: list[Camera]
) -> torch.Tensor:
    """L_temporal's target in whole views: t − 1's scene (``static`` and ``previous``)
    rendered by ``cameras``, (V, h, w, 3)."""
    with torch.no_grad():
        scene = Gaussians.cat([static, previous])
        return torch.stack([inputs.render(scene, c).rgb for c in cameras])


def whole_scene_step(
    inputs: LiftInputs,
    static: Gaussians,
    dynamic: Gaussians,
    views: TrainViews,
    knobs: Knobs,
    features: FeatureModel | None,
) -> float:
    """Seconds per step of training ``dynamic`` over the whole ``static`` set in whole
    ``views`` (no windows), as training a timestamp whole would: metrics.json's estimate of
    what the dynamic stage saves (``export.run_metrics``). A timing only: the trainer is
    thrown away and draws from its own generator, so nothing it does reaches a result."""
    # As many steps as are timed (and the warm-up), so that L_sem's schedule runs on about
    # the share of them it runs on in a stage; no densification.
    knobs = knobs.model_copy(update={"iterations": 1 + WHOLE_SCENE_STEPS, "densify": False})
    trainer = make_trainer(
        inputs.trainer, dynamic, views, knobs, inputs.render, static=static, features=features,
        seed=inputs.cfg.seed,
    )  # fmt: skip
    trainer.train_step()  # the first step builds the device's pipelines and sizes its buffers
    trainer.result()  # reading the Gaussians back waits for the device's steps to finish
    start = time.perf_counter()
    for _ in range(WHOLE_SCENE_STEPS):
        trainer.train_step()
    trainer.result()
    return (time.perf_counter() - start) / WHOLE_SCENE_STEPS


def fit_dynamic(
    inputs: LiftInputs,
    static: Gaussians,
    initial: Gaussians,
    view_depth: torch.Tensor,
    median_depth: float,
    checkpoints: Checkpoints,
    bars: Bars,
    on_step: StepHook | None,
    on_snapshot: SnapshotHook | None = None,
    tracked: bool = False,
) -> DynamicSets:
    """Per timestamp, the dynamic set warm-started from t − 1's (its colours moved by the
    frame's change), optimised against the frozen static set in the views that see it.
    ``tracked``: after frame 0 only the positions and colours learn, so that the sets are
    one set posed at every frame (``fit_tracked``)."""
    state = checkpoints.load("dynamic") or {"done": [], "seconds": 0.0, "logs": []}
    done = [Gaussians.from_numpy(d, inputs.device) for d in state["done"]]
    logs = [TrainLog.from_dict(d) for d in state["logs"]]  # the one in progress last
    total = len(inputs.frames)
    checkpoints.resumed("dynamic", t=len(done), step=0)
    cameras = inputs.cameras
    # The moving region in each view, once: it is the same at every timestamp.
    moving = [inputs.moving_in_view(c) for c in cameras]
    seeing = [i for i, m in enumerate(moving) if float(m.max()) > 0]
    cams = [cameras[i] for i in seeing]
    if len(initial) == 0 or not cams:
        return DynamicSets([initial.detach() for _ in range(total)], 0.0, None, [])
    full = inputs.knobs.gaussian_iterations
    budget = inputs.knobs.max_gaussians - len(static)
    features = make_feature_model(inputs.cfg.features, inputs.device)
    start = time.perf_counter()

    def seconds() -> float:
        return float(state["seconds"]) + time.perf_counter() - start

    def saved() -> dict[str, Any]:
        return {
            "done": [g.to_numpy() for g in done], "seconds": seconds(), "t": len(done),
            "logs": [log.to_dict() for log in logs],
        }  # fmt: skip

    h, w = cameras[0].height, cameras[0].width
    # A step renders only the window of each view that the dynamic set can reach, against
    # the static Gaussians that can draw into it (lift.windows; not with L_sem, whose
    # features are the whole view's): the static set's render of the views, once.
    windows = inputs.knobs.dynamic_windows and features is None
    with torch.no_grad():
        static_renders = [inputs.render(static, c) for c in cams] if windows else []
    for t in range(len(done), total):
        dynamic = (
            initial if t == 0
            else follow_frame_change(done[-1], inputs.frames[t - 1], inputs.frames[t])
        )  # fmt: skip
        views = views_of_frame(inputs, t, view_depth[t], lambda _c: torch.ones(h, w), seeing)
        previous = done[-1] if t > 0 else None
        # The static Gaussians a step draws: all of them, or those that can draw into a window.
        static_drawn, reach = static, None
        if windows:
            # The window holds t − 1's set too, so that outside it t − 1's render (L_temporal's
            # target) is the static render.
            drawn = dynamic if previous is None else Gaussians.cat([dynamic, previous])
            mode = (inputs.render_backend, inputs.knobs.antialiased)
            reach = [reach_window(cameras[i], moving[i], drawn, *mode) for i in seeing]
            window_cameras = [r.camera(c) for r, c in zip(reach, cams, strict=True)]
            static_drawn = static[touching(static, window_cameras, *mode)]
        if previous is not None and reach is not None:  # L_temporal's target: t − 1's render
            with torch.no_grad():
                views.previous = previous_in_windows(
                    inputs.render, reach, cams, static_renders, static_drawn, previous
                )
        elif previous is not None:
            views.previous = previous_renders(inputs, static, previous, cams)
        if reach is not None:
            views = windowed(views, reach, static_renders)
        iterations = dynamic_iterations(full, t, inputs.knobs.later_iteration_share)
        stage = trainer_knobs(
            inputs.knobs, iterations, budget, median_depth, cams, inputs.frames.shape[2]
        )
        # A later timestamp starts from t − 1's set, densified where the region needed it:
        # densifying it again would compound over the frames.
        stage = stage.model_copy(update={"densify": stage.densify and t == 0})
        if tracked and t > 0:  # scale, rotation and opacity stay frame 0's
            frozen = {"lr_scale": 0.0, "lr_rotation": 0.0, "lr_opacity": 0.0}
            stage = stage.model_copy(update=frozen)
        trainer = make_trainer(
            inputs.trainer,
            dynamic,
            views,
            stage,
            inputs.render,
            static=static_drawn,
            features=features,
            seed=inputs.cfg.seed + 1 + t,
        )
        if "trainer" in state and state.get("t") == t:
            resume(trainer, state, inputs.trainer, checkpoints.path("dynamic"))
            checkpoints.resumed("dynamic", t=t, step=trainer.step)
        else:
            logs.append(TrainLog(f"dynamic t={t}", len(dynamic)))
        log = logs[t]
        log.static_drawn = len(static_drawn)
        log.window_share = sum(c.width * c.height for c in views.cameras) / (len(cams) * h * w)
        rule = (
            StopRule.for_count(full, iterations, [earlier.losses for earlier in logs[:t]])
            if inputs.knobs.stop_when_converged
            else StopRule.fixed(iterations)
        )
        # The timestamps done, and this one as read back.
        show = snapshot_hook(
            on_snapshot, inputs, log.name, iterations, lambda g: (static, [*done, g])
        )
        done.append(
            run_trainer(
                trainer, inputs.trainer, log, checkpoints, "dynamic", bars, on_step, saved, rule,
                show,
            )
        )  # fmt: skip
        checkpoints.save("dynamic", saved())
    spent = seconds()
    # The last timestamp's step, trained whole.
    t = total - 1
    views = views_of_frame(inputs, t, view_depth[t], lambda _c: torch.ones(h, w), seeing)
    if t > 0:
        views.previous = previous_renders(inputs, static, done[t - 1], cams)
    stage = trainer_knobs(inputs.knobs, full, budget, median_depth, cams, inputs.frames.shape[2])
    step = whole_scene_step(inputs, static, done[t], views, stage, features)
    return DynamicSets(done, spent, step, logs)


def fit_tracked(
    inputs: LiftInputs,
    static: Gaussians,
    initial: Gaussians,
    view_depth: torch.Tensor,
    median_depth: float,
    checkpoints: Checkpoints,
    bars: Bars,
    on_step: StepHook | None,
    on_snapshot: SnapshotHook | None = None,
) -> DynamicSets:
    """One dynamic set followed through the frames, as Dynamic 3D Gaussians fit theirs
    online: ``fit_dynamic``'s loop (frame after frame, each warm-started from the one
    before) with only the positions and colours learning after frame 0, then its poses over
    the loop fitted by the spacetime form's Fourier terms
    (``SpacetimeGaussians.through_frames``), stored once as a version-2 set. The frame by
    frame fit is what the (view, time) pairs of ``fit_spacetime`` fall short of
    (bench/RESULTS.md, "One dynamic set")."""
    knobs = inputs.knobs
    frames = fit_dynamic(
        inputs, static, initial, view_depth, median_depth, checkpoints, bars, on_step,
        on_snapshot, tracked=True,
    )  # fmt: skip
    assert isinstance(frames.gaussians, list)
    model = TimeModel(len(inputs.frames), knobs.colour_harmonics, knobs.position_harmonics)
    one_set = SpacetimeGaussians.through_frames(model, frames.gaussians)
    return replace(frames, gaussians=one_set)


def fit_spacetime(
    inputs: LiftInputs,
    static: Gaussians,
    initial: Gaussians,
    view_depth: torch.Tensor,
    median_depth: float,
    checkpoints: Checkpoints,
    bars: Bars,
    on_step: StepHook | None,
    on_snapshot: SnapshotHook | None = None,
) -> DynamicSets:
    """One dynamic set for every timestamp: the moving region's Gaussians, each with
    functions of time (``pano4d.spacetime``), started from frame 0's set with every
    frame's colours (``lift.initial.spacetime_start``) and optimised once against the frozen
    static set, a step on one (view, time) pair of the views that see the moving region."""
    state = checkpoints.load("dynamic") or {"seconds": 0.0}
    knobs = inputs.knobs
    total = len(inputs.frames)
    model = TimeModel(total, knobs.colour_harmonics, knobs.position_harmonics)
    iterations = max(1, round(knobs.spacetime_step_ratio * knobs.gaussian_iterations))
    if "result" in state:
        checkpoints.resumed("dynamic", step=iterations)
        result = SpacetimeGaussians.from_numpy(state["result"], inputs.device)
        return DynamicSets(result, state["seconds"], None, [TrainLog.from_dict(state["log"])])
    cameras = inputs.cameras
    moving = [inputs.moving_in_view(c) for c in cameras]
    seeing = [i for i, m in enumerate(moving) if float(m.max()) > 0]
    cams = [cameras[i] for i in seeing]
    start_set = spacetime_start(initial, inputs.frames.to(inputs.device), model)
    if len(initial) == 0 or not cams:
        checkpoints.resumed("dynamic", step=0)
        return DynamicSets(start_set, 0.0, None, [])
    features = make_feature_model(inputs.cfg.features, inputs.device)
    h, w = cameras[0].height, cameras[0].width
    # As the per-timestamp stage: a step renders only the window of a view the dynamic set
    # can reach, against the static Gaussians that can draw into it (not with L_sem).
    windows = knobs.dynamic_windows and features is None
    static_drawn, reach = static, None
    if windows:
        mode = (inputs.render_backend, knobs.antialiased)
        reach = [reach_window(cameras[i], moving[i], initial, *mode) for i in seeing]
        window_cameras = [r.camera(c) for r, c in zip(reach, cams, strict=True)]
        static_drawn = static[touching(static, window_cameras, *mode)]
        with torch.no_grad():
            static_renders = [inputs.render(static, c) for c in cams]
    frames = []
    for t in range(total):
        frame = views_of_frame(inputs, t, view_depth[t], lambda _c: torch.ones(h, w), seeing)
        frames.append(frame if reach is None else windowed(frame, reach, static_renders))
    views = joined(frames)
    budget = knobs.max_gaussians - len(static)
    trainer = make_trainer(
        inputs.trainer,
        start_set,
        views,
        trainer_knobs(knobs, iterations, budget, median_depth, cams, inputs.frames.shape[2]),
        inputs.render,
        static=static_drawn,
        features=features,
        seed=inputs.cfg.seed + 1,
    )
    log = TrainLog("dynamic", len(start_set))
    if "trainer" in state:
        resume(trainer, state, inputs.trainer, checkpoints.path("dynamic"))
        log = TrainLog.from_dict(state["log"])
    checkpoints.resumed("dynamic", step=trainer.step)
    log.static_drawn = len(static_drawn)
    log.window_share = sum(c.width * c.height for c in views.cameras) / (len(views.cameras) * h * w)
    start = time.perf_counter()

    def seconds() -> float:
        return float(state["seconds"]) + time.perf_counter() - start

    show = snapshot_hook(on_snapshot, inputs, log.name, iterations, lambda g: (static, g))
    result = run_trainer(
        trainer, inputs.trainer, log, checkpoints, "dynamic", bars, on_step,
        lambda: {"seconds": seconds(), "log": log.to_dict()}, StopRule.fixed(iterations), show,
    )  # fmt: skip
    assert isinstance(result, SpacetimeGaussians)
    checkpoints.save(
        "dynamic", {"result": result.to_numpy(), "seconds": seconds(), "log": log.to_dict()}
    )
    return DynamicSets(result, seconds(), None, [log])


def joined(frames: list[TrainViews]) -> TrainViews:
    """One frame's views after another, as one list of (view, time) pairs: frame ``t``'s
    views at time ``t``."""

    def listed(field: str) -> list[torch.Tensor]:
        return [image for views in frames for image in getattr(views, field)]

    def stacked(field: str) -> torch.Tensor | None:  # windows' normalisers and outside sums
        parts = [getattr(views, field) for views in frames]
        return None if parts[0] is None else torch.cat(parts)

    return TrainViews(
        cameras=[c for views in frames for c in views.cameras],
        targets=listed("targets"),
        weights=listed("weights"),
        depth=listed("depth"),
        weight_sums=stacked("weight_sums"),
        outside=stacked("outside"),
        times=[float(t) for t, views in enumerate(frames) for _ in views.cameras],
    )


# --- where a rerun picks up ------------------------------------------------------------------
def resume_point(checkpoints: Checkpoints, frames: int) -> str | None:
    """Where ``lift`` would pick a run of ``frames`` frames up, read from what the stages
    above keep in their checkpoints ("depth frame 2", "static step 50", "dynamic t=3",
    "export"); None when no stage has a checkpoint for these settings."""
    dynamic = checkpoints.load("dynamic")
    if dynamic is not None and "done" in dynamic:  # the per-timestamp stage
        done = len(dynamic["done"])
        return "export" if done == frames else _at_step(f"dynamic t={done}", dynamic)
    if dynamic is not None:  # the spacetime stage
        return "export" if "result" in dynamic else _at_step("dynamic", dynamic)
    static = checkpoints.load("static")
    if static is not None:
        return "dynamic t=0" if "done" in static else _at_step("static", static)
    align = checkpoints.load("align")
    if align is not None:
        done = len(align["frames"])
        return "static" if done == frames else f"align frame {done}"
    depth = checkpoints.load("depth")
    if depth is not None:
        done = len(depth["depth"])
        return "align frame 0" if done == frames else f"depth frame {done}"
    return None


def _at_step(label: str, state: dict[str, Any]) -> str:
    """``label`` and the step of the optimisation ``run_trainer`` checkpointed in ``state``."""
    step = state.get("trainer", {}).get("step", 0)
    return f"{label} step {step}" if step else label


# --- the phase -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Lifted:
    """What the stages made, for ``lift.export`` to write."""

    inputs: LiftInputs
    alignment: Alignment
    initial: InitialSets
    static: StaticSet
    dynamic: DynamicSets
    timings: dict[str, float]  # seconds: animate, depth, align, static, dynamic
    resumed_at: dict[str, dict[str, int]]  # where this run picked each stage up


def lift(
    cfg: SceneConfig,
    frames_dir: Path,
    checkpoints: Checkpoints,
    bars: Bars,
    render_backend: str,
    trainer: str,
    on_step: StepHook | None,
    animate_seconds: float,
    on_snapshot: SnapshotHook | None = None,
) -> Lifted:
    """Every stage in order on the animation in ``frames_dir``; ``trainer`` is a key of
    trainers.TRAINERS; ``on_snapshot`` sees the scene at the static and dynamic stages'
    read-backs (``SceneSnapshot``)."""
    inputs = prepare(cfg, frames_dir, render_backend, trainer)
    view_depth = estimate_depth(inputs, checkpoints, bars, on_step)
    alignment = align_depth(inputs, view_depth.depth, checkpoints, bars, on_step)
    initial = initial_sets(inputs, alignment.depths[0])
    median = alignment.median_depth
    static = fit_static(
        inputs, initial.static, view_depth.depth[0], median, checkpoints, bars, on_step,
        on_snapshot,
    )  # fmt: skip
    fit = {"per_timestamp": fit_dynamic, "spacetime": fit_spacetime, "tracked": fit_tracked}[
        inputs.knobs.dynamic_model
    ]
    dynamic = fit(
        inputs, static.gaussians, initial.dynamic, view_depth.depth, median, checkpoints, bars,
        on_step, on_snapshot,
    )  # fmt: skip
    timings = {
        "animate": animate_seconds,
        "depth": view_depth.seconds,
        "align": alignment.seconds,
        "static": static.seconds,
        "dynamic": dynamic.seconds,
    }
    return Lifted(inputs, alignment, initial, static, dynamic, timings, checkpoints.resumed_at)
