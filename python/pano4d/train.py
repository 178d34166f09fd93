"""``pano4d train``: both phases end to end, resumable, with the DESIGN.md output files.

Stages (each checkpointed atomically in ``output/checkpoints/``; a rerun after a kill skips
what is done and resumes an optimisation from its last checkpoint):

1. animate — ``pano4d.animate.pipeline.run_animate`` unless output/animate/frames is complete;
2. depth   — Θ per frame and view (``pano4d.lift.depth``);
3. align   — spherical depth per frame (``pano4d.lift.align``), frames after the first
             re-fitted only in the dilated moving region;
4. static  — Gaussians away from the moving region, optimised once on frame 0;
5. dynamic — per timestamp, Gaussians in the moving region, warm-started from t − 1,
             optimised against the frozen static set;
6. export  — scene.ply4d, preview.mp4, contact.png, metrics.json.

The lifting works at the resolution the views need: frames are area-downsampled to an equirect
whose pixel matches a view pixel (``view_size`` over ``fov_deg``), never above the input's.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from pano4d.camera import Camera
from pano4d.config import PresetKnobs, SceneConfig, config_hash, load_config
from pano4d.fsutil import write_json_atomic
from pano4d.gaussians import Gaussians
from pano4d.lift.align import DepthAligner, FrameAlignment
from pano4d.lift.depth import make_depth_backend
from pano4d.lift.features import make_feature_model
from pano4d.lift.initial import dilate_mask, init_gaussians, init_sphere, points_in_mask
from pano4d.lift.optimize import GaussianTrainer, Knobs, TrainViews, moved_camera, save_atomic
from pano4d.regions import moving_in_video, moving_mask
from pano4d.resample import equirect_to_perspective
from pano4d.sphere import view_layout

CHECKPOINT_EVERY = 50  # optimisation steps between checkpoints
DILATE_DEG = 2.0  # margin around the moving region, degrees of arc
PREVIEW_FRAMES = 24  # per turntable (origin, then the displaced orbit)
PREVIEW_ORBIT = 0.01  # orbit radius as a fraction of the median scene depth
CONTACT_TIMES = 3

StepHook = Callable[[str, int], None]


class TrainError(RuntimeError):
    """The run cannot go on (missing frames, broken checkpoint, ...)."""


# --- progress ----------------------------------------------------------------------------
class _Progress:
    """A rich progress bar per phase (phase, iteration, loss, ETA), or silence."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self._bar: Any = None

    @contextmanager
    def session(self) -> Iterator[_Progress]:
        if not self.enabled:
            yield self
            return
        from pano4d.progress import progress_bar

        with progress_bar("loss") as bar:
            self._bar = bar
            yield self
            self._bar = None

    def task(
        self, description: str, total: int, completed: int = 0
    ) -> Callable[[int, float], None]:
        if self._bar is None:
            return lambda _done, _loss: None
        task = self._bar.add_task(description, total=max(total, 1), completed=completed, loss="-")

        def update(done: int, loss: float) -> None:
            shown = f"{loss:.4f}" if math.isfinite(loss) else "-"
            self._bar.update(task, completed=done, loss=shown)

        return update


# --- inputs ---------------------------------------------------------------------------------
def working_size(width: int, view_size: int, fov_deg: float) -> tuple[int, int]:
    """Equirect size (W, H) whose pixel matches a view pixel, at most the input's width."""
    target = round(360.0 * view_size / fov_deg / 2) * 2
    w = min(width, max(64, target))
    return w, w // 2


def read_frames(
    folder: Path, count: int, size: tuple[int, int], suffix: str = ".png"
) -> torch.Tensor:
    """The animation frames (L, H, W, 3) area-downsampled to ``size`` (W, H)."""
    from pano4d.images import read_image

    frames = []
    for t in range(count):
        path = folder / f"{t:04d}{suffix}"
        if not path.is_file():
            raise TrainError(f"{path}: animation frame missing (run `pano4d animate` again)")
        image = torch.from_numpy(np.ascontiguousarray(read_image(path)[..., :3]))
        frames.append(_resize(image, size))
    return torch.stack(frames)


def _resize(image: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    w, h = size
    if image.shape[:2] == (h, w):
        return image.to(torch.float32)
    x = image.permute(2, 0, 1)[None].to(torch.float32)
    return F.interpolate(x, size=(h, w), mode="area")[0].permute(1, 2, 0).contiguous()


def _frame_suffix(cfg: SceneConfig) -> str:
    """The animating phase writes EXR frames for an EXR panorama, PNG otherwise."""
    return ".exr" if Path(cfg.panorama).suffix.lower() == ".exr" else ".png"


def _frames_complete(folder: Path, count: int, suffix: str) -> bool:
    return all((folder / f"{t:04d}{suffix}").is_file() for t in range(count))


def resolve_device(cfg: SceneConfig) -> torch.device:
    if cfg.device == "cuda" and not torch.cuda.is_available():
        raise TrainError("device: cuda was asked for but torch sees no CUDA device")
    if cfg.device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(cfg.device)


# --- checkpoints ----------------------------------------------------------------------------
@dataclass
class Checkpoints:
    folder: Path
    config_hash: str
    every: int = CHECKPOINT_EVERY  # optimisation steps between checkpoints

    def path(self, name: str) -> Path:
        return self.folder / f"{name}.pt"

    def load(self, name: str) -> dict[str, Any] | None:
        """The stage's saved state, or None if absent or written for another config."""
        path = self.path(name)
        if not path.is_file():
            return None
        try:
            state = torch.load(path, map_location="cpu", weights_only=False)
        except (OSError, RuntimeError, EOFError) as error:
            raise TrainError(
                f"{path}: unreadable checkpoint ({error}); delete it to restart that stage"
            ) from error
        return state if state.get("config_hash") == self.config_hash else None

    def save(self, name: str, state: dict[str, Any]) -> None:
        save_atomic(self.path(name), {**state, "config_hash": self.config_hash})


# --- the run --------------------------------------------------------------------------------
@dataclass
class LiftContext:
    cfg: SceneConfig
    knobs: PresetKnobs
    device: torch.device
    cameras: list[Camera]
    frames: torch.Tensor  # (L, H, W, 3) working resolution
    moving: torch.Tensor  # (H, W) dilated moving mask at working resolution
    full_width: int
    render_backend: str
    timings: dict[str, float] = field(default_factory=dict)
    median_depth: float = 1.0

    def render(self, g: Gaussians, camera: Camera, background: torch.Tensor | None = None) -> Any:
        from pano4d.render import render

        return render(g, camera, background=background, backend=self.render_backend)


def run_train(
    cfg: SceneConfig,
    progress: bool = True,
    render_backend: str = "wgpu",
    on_step: StepHook | None = None,
    checkpoint_every: int = CHECKPOINT_EVERY,
) -> dict[str, Any]:
    """Run ``cfg`` end to end (resuming from checkpoints); returns the metrics written.

    ``on_step(stage, step)`` is called after every optimisation step of the align, static and
    dynamic stages (tests use it to interrupt a run at a known point). ``checkpoint_every``:
    optimisation steps between checkpoints (stages are always checkpointed when done).
    """
    if checkpoint_every < 1:
        raise ValueError(f"checkpoint_every must be ≥ 1, got {checkpoint_every}")
    out = Path(cfg.output)
    out.mkdir(parents=True, exist_ok=True)
    ckpt = Checkpoints(out / "checkpoints", config_hash(cfg), checkpoint_every)
    bar = _Progress(progress)
    timings: dict[str, float] = {}
    with bar.session():
        start = time.perf_counter()
        frames_dir = out / "animate" / "frames"
        suffix = _frame_suffix(cfg)
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
        timings["animate"] = time.perf_counter() - start
        ctx = _context(cfg, frames_dir, render_backend)
        ctx.timings = timings
        view_depth = _stage_depth(ctx, ckpt, bar)
        alignments, aligner = _stage_align(ctx, ckpt, bar, view_depth, on_step)
        depths = [
            aligner.equirect_depth(a, ctx.frames.shape[2], ctx.frames.shape[1]) for a in alignments
        ]
        far = 0.9 * ctx.cfg.depth.far
        finite = depths[0][depths[0] < far]
        ctx.median_depth = float(finite.median()) if finite.numel() else float(depths[0].median())
        static, dynamic_init, split = _initial_sets(ctx, depths)
        static = _stage_static(ctx, ckpt, bar, static, view_depth[0], on_step)
        dynamic = _stage_dynamic(ctx, ckpt, bar, static, dynamic_init, view_depth, on_step)
        return _export(ctx, static, dynamic, depths, split)


def _context(cfg: SceneConfig, frames_dir: Path, render_backend: str) -> LiftContext:
    from pano4d.images import read_image

    suffix = _frame_suffix(cfg)
    first = read_image(frames_dir / f"0000{suffix}")
    full_h, full_w = first.shape[:2]
    knobs = cfg.resolved_preset(full_w)
    size = working_size(full_w, knobs.view_size, cfg.lift.fov_deg)
    frames = read_frames(frames_dir, cfg.animate.frames, size, suffix)
    regions = moving_mask(cfg, full_w, full_h)
    regions = F.interpolate(regions[None, None].float(), size=(size[1], size[0]), mode="area")
    moving = moving_in_video(frames, regions[0, 0] > 0)
    radius = max(1, round(DILATE_DEG / 360.0 * size[0]))
    device = resolve_device(cfg)
    cameras = view_layout(cfg.lift.views, cfg.lift.fov_deg, knobs.view_size)
    return LiftContext(
        cfg, knobs, device, cameras, frames, dilate_mask(moving, radius), full_w, render_backend
    )


def _stage_depth(ctx: LiftContext, ckpt: Checkpoints, bar: _Progress) -> torch.Tensor:
    start = time.perf_counter()
    state = ckpt.load("depth") or {"depth": []}
    done: list[torch.Tensor] = list(state["depth"])
    total = len(ctx.frames)
    if len(done) < total:
        backend = make_depth_backend(ctx.cfg.depth, ctx.device)
        update = bar.task(f"depth ({backend.name})", total, len(done))
        for t in range(len(done), total):
            done.append(backend.view_depth(ctx.frames[t].to(ctx.device), ctx.cameras).cpu())
            ckpt.save("depth", {"depth": done})
            update(t + 1, math.nan)
    ctx.timings["depth"] = time.perf_counter() - start
    return torch.stack(done)


def _stage_align(
    ctx: LiftContext,
    ckpt: Checkpoints,
    bar: _Progress,
    view_depth: torch.Tensor,
    on_step: StepHook | None,
) -> tuple[list[FrameAlignment], DepthAligner]:
    start = time.perf_counter()
    iterations = ctx.knobs.align_iterations
    aligner = DepthAligner(ctx.cameras, iterations=iterations, device=ctx.device)
    moving_points = points_in_mask(aligner.ico.points, ctx.moving)
    state = ckpt.load("align") or {"frames": []}
    done = [FrameAlignment.from_dict(d, ctx.device) for d in state["frames"]]
    for t in range(len(done), len(ctx.frames)):
        total = iterations if t == 0 else aligner.warm_iterations
        update = bar.task(f"align frame {t}", total)

        def step(i: int, n: int, loss: float, _update: Callable = update) -> None:
            _update(i + 1, loss)
            if on_step is not None:
                on_step("align", i)

        previous = done[-1] if done else None
        done.append(aligner.fit(view_depth[t], previous, moving_points if done else None, step))
        ckpt.save("align", {"frames": [d.to_dict() for d in done]})
    ctx.timings["align"] = time.perf_counter() - start
    return done, aligner


@dataclass
class Split:
    points: int
    static: int
    dynamic: int
    spacing_rad: float


def _initial_sets(
    ctx: LiftContext, depths: list[torch.Tensor]
) -> tuple[Gaussians, Gaussians, Split]:
    stride = ctx.knobs.init_stride
    ico = init_sphere(ctx.full_width, stride)
    while len(ico) > ctx.knobs.max_gaussians:  # keep the initial set within budget
        stride += 1
        ico = init_sphere(ctx.full_width, stride)
    points = ico.points
    dynamic = points_in_mask(points, ctx.moving)
    degree = ctx.knobs.sh_degree
    frame0 = ctx.frames[0].to(ctx.device)
    depth0 = depths[0].to(ctx.device)
    static = init_gaussians(points[~dynamic], ico.spacing_rad, depth0, frame0, degree)
    moving = init_gaussians(points[dynamic], ico.spacing_rad, depth0, frame0, degree)
    return static, moving, Split(len(points), len(static), len(moving), ico.spacing_rad)


def _views_of_frame(
    ctx: LiftContext,
    t: int,
    view_depth: torch.Tensor,
    weight_fn: Callable[[Camera], torch.Tensor],
    indices: list[int] | None = None,
) -> TrainViews:
    """Targets, loss weights and Θ's z-depth of frame ``t`` in the views ``indices``."""
    indices = indices if indices is not None else list(range(len(ctx.cameras)))
    cams = [ctx.cameras[i] for i in indices]
    image = ctx.frames[t].permute(2, 0, 1)
    targets = torch.stack([equirect_to_perspective(image, c).permute(1, 2, 0) for c in cams])
    weights = torch.stack([weight_fn(c) for c in cams])
    z = torch.stack([view_depth[i] / ctx.cameras[i].z_to_ray_factor() for i in indices])
    d = ctx.device
    return TrainViews(cams, targets.to(d), weights.to(d), z.to(d))


def _moving_in_view(ctx: LiftContext, camera: Camera) -> torch.Tensor:
    return equirect_to_perspective(ctx.moving.to(torch.float32), camera)


def _knobs(ctx: LiftContext, iterations: int, budget: int) -> Knobs:
    k = ctx.knobs
    return Knobs(
        iterations=iterations,
        lambda_temporal=k.lambda_temporal,
        lambda_geo=k.lambda_geo,
        lambda_sem=k.lambda_sem,
        densify=k.densify,
        max_gaussians=max(1, budget),
        densify_every=max(10, iterations // 10),
        sem_scale=ctx.median_depth,
    )


def _train(
    trainer: GaussianTrainer,
    ckpt: Checkpoints,
    name: str,
    label: str,
    bar: _Progress,
    on_step: StepHook | None,
    extra: Callable[[], dict[str, Any]],
) -> Gaussians:
    """Run a trainer with a progress bar and a checkpoint every ``ckpt.every`` steps."""
    update = bar.task(label, trainer.knobs.iterations, trainer.step)

    def step(tr: GaussianTrainer) -> None:
        update(tr.step, tr.last_loss)
        if tr.step % ckpt.every == 0 and tr.step < tr.knobs.iterations:
            ckpt.save(name, {**extra(), "trainer": tr.state_dict()})
        if on_step is not None:
            on_step(name, tr.step)

    return trainer.run(step)


def _stage_static(
    ctx: LiftContext,
    ckpt: Checkpoints,
    bar: _Progress,
    init: Gaussians,
    view_depth0: torch.Tensor,
    on_step: StepHook | None,
) -> Gaussians:
    state = ckpt.load("static") or {"seconds": 0.0}
    if "done" in state:
        ctx.timings["static"] = state["seconds"]
        ctx.timings["static_per_step"] = state["per_step"]
        return Gaussians.from_numpy(state["done"], ctx.device)
    iterations = ctx.knobs.gaussian_iterations
    views = _views_of_frame(
        ctx, 0, view_depth0, lambda c: (_moving_in_view(ctx, c) < 0.5).to(torch.float32)
    )
    trainer = GaussianTrainer(
        init,
        views,
        _knobs(ctx, iterations, ctx.knobs.max_gaussians),
        ctx.render,
        features=make_feature_model(ctx.cfg.features, ctx.device),
        seed=ctx.cfg.seed,
    )
    if "trainer" in state:
        trainer.load_state_dict(state["trainer"])
    start, first_step = time.perf_counter(), trainer.step

    def seconds() -> float:
        return float(state["seconds"]) + time.perf_counter() - start

    result = _train(
        trainer, ckpt, "static", "static set", bar, on_step, lambda: {"seconds": seconds()}
    )
    per_step = (time.perf_counter() - start) / max(1, trainer.step - first_step)
    ckpt.save("static", {"done": result.to_numpy(), "seconds": seconds(), "per_step": per_step})
    ctx.timings["static"], ctx.timings["static_per_step"] = seconds(), per_step
    return result


def _render_views(ctx: LiftContext, g: Gaussians, cameras: list[Camera]) -> torch.Tensor:
    with torch.no_grad():
        return torch.stack([ctx.render(g, c).rgb for c in cameras])


def _stage_dynamic(
    ctx: LiftContext,
    ckpt: Checkpoints,
    bar: _Progress,
    static: Gaussians,
    init: Gaussians,
    view_depth: torch.Tensor,
    on_step: StepHook | None,
) -> list[Gaussians]:
    state = ckpt.load("dynamic") or {"done": [], "seconds": 0.0}
    done = [Gaussians.from_numpy(d, ctx.device) for d in state["done"]]
    total = len(ctx.frames)
    seeing = [i for i, c in enumerate(ctx.cameras) if float(_moving_in_view(ctx, c).max()) > 0]
    cams = [ctx.cameras[i] for i in seeing]
    if len(init) == 0 or not cams:
        ctx.timings["dynamic"] = 0.0
        return [init.detach() for _ in range(total)]
    full = ctx.knobs.gaussian_iterations
    budget = ctx.knobs.max_gaussians - len(static)
    features = make_feature_model(ctx.cfg.features, ctx.device)
    start = time.perf_counter()

    def seconds() -> float:
        return float(state["seconds"]) + time.perf_counter() - start

    def saved() -> dict[str, Any]:
        return {"done": [g.to_numpy() for g in done], "seconds": seconds(), "t": len(done)}

    h, w = ctx.cameras[0].height, ctx.cameras[0].width
    for t in range(len(done), total):
        views = _views_of_frame(ctx, t, view_depth[t], lambda _c: torch.ones(h, w), seeing)
        if t > 0:
            views.previous = _render_views(ctx, Gaussians.cat([static, done[-1]]), cams)
        iterations = _dynamic_iterations(full, t)
        trainer = GaussianTrainer(
            init if t == 0 else done[-1],
            views,
            _knobs(ctx, iterations, budget),
            ctx.render,
            context=static,
            features=features,
            seed=ctx.cfg.seed + 1 + t,
        )
        if "trainer" in state and state.get("t") == t:
            trainer.load_state_dict(state["trainer"])
        done.append(_train(trainer, ckpt, "dynamic", f"dynamic t={t}", bar, on_step, saved))
        ckpt.save("dynamic", saved())
    ctx.timings["dynamic"] = seconds()
    # A dynamic step renders static + dynamic: what a step of whole-timestamp training costs.
    steps = sum(_dynamic_iterations(full, t) for t in range(total))
    ctx.timings["full_scene_step"] = seconds() / steps
    return done


def _dynamic_iterations(full: int, t: int) -> int:
    """Steps for timestamp t: the full count first, half for the warm-started later ones."""
    return full if t == 0 else max(1, full // 2)


# --- outputs -------------------------------------------------------------------------------
def _scene(ctx: LiftContext, static: Gaussians, dynamic: list[Gaussians], split: Split) -> Any:
    from pano4d import __version__, ply4d

    fps = ctx.cfg.animate.fps
    return ply4d.Scene4D(
        static=static.detach().to("cpu"),
        dynamic=[g.detach().to("cpu") for g in dynamic],
        timestamps=[t / fps for t in range(len(dynamic))],
        fps=fps,
        camera={
            "position": [0.0, 0.0, 0.0],
            "params": {
                "views": len(ctx.cameras),
                "fov_deg": ctx.cfg.lift.fov_deg,
                "view_size": ctx.knobs.view_size,
            },
        },
        provenance={"tool_version": __version__, "config_hash": config_hash(ctx.cfg)},
        extra={
            "preset": ctx.cfg.preset,
            "knobs": ctx.knobs.model_dump(),
            "median_depth": ctx.median_depth,
            "init_points": split.points,
        },
    )


def turntable_cameras(size: tuple[int, int], median_depth: float, count: int) -> list[Camera]:
    """``count`` cameras turning 360° at the origin, then ``count`` on a small orbit looking out."""
    w, h = size
    out = []
    radius = PREVIEW_ORBIT * median_depth
    for orbit in (0.0, radius):
        for i in range(count):
            yaw = 2 * math.pi * i / count
            forward = (math.cos(yaw), math.sin(yaw), 0.0)
            position = (
                orbit * math.cos(yaw + math.pi / 2),
                orbit * math.sin(yaw + math.pi / 2),
                0.0,
            )
            out.append(Camera.from_fov(90.0, w, h, position, forward))
    return out


def read_gt_views(panorama: Path) -> list[dict[str, Any]]:
    """gt/views.json entries beside the panorama (with 'camera' and 'image' loaded), or []."""
    from pano4d.images import read_image

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


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(((a - b) ** 2).mean())
    return 10 * math.log10(1.0 / max(mse, 1e-12))


def ssim(a: torch.Tensor, b: torch.Tensor) -> float:
    import kornia

    x, y = a.permute(2, 0, 1)[None].float(), b.permute(2, 0, 1)[None].float()
    return float(kornia.metrics.ssim(x, y, 11).mean())


def novel_view_metrics(scene: Any, views: list[dict[str, Any]], render: Callable) -> dict[str, Any]:
    """PSNR/SSIM of renders at the gt cameras, overall and per displacement fraction."""
    per_view, groups = [], {}
    for v in views:
        t = min(int(v["time"]), scene.num_times - 1)
        with torch.no_grad():
            rgb = render(scene.at(t), v["camera"]).rgb.clamp(0, 1).cpu()
        p, s = psnr(rgb, v["pixels"]), ssim(rgb, v["pixels"])
        fraction = float(v.get("displacement_fraction", 0.0))
        per_view.append(
            {
                "image": v["image"],
                "time": t,
                "displacement_fraction": fraction,
                "psnr": p,
                "ssim": s,
            }
        )
        groups.setdefault(f"{100 * fraction:g}%", []).append((p, s))
    summary = {
        k: {
            "psnr": float(np.mean([p for p, _ in g])),
            "ssim": float(np.mean([s for _, s in g])),
            "views": len(g),
        }
        for k, g in groups.items()
    }
    return {"views": per_view, "by_displacement": summary}


def contact_cameras(ctx: LiftContext, count: int = 4) -> list[Camera]:
    """Test views for the contact sheet: those that see most of the moving region, then the
    most level ones, each moved sideways by 1 % of the median depth to show parallax."""
    n = len(ctx.cameras)
    seen = [float(_moving_in_view(ctx, c).mean()) for c in ctx.cameras]
    moving = [i for i in sorted(range(n), key=lambda i: -seen[i]) if seen[i] > 0][: count // 2]
    level = sorted((i for i in range(n) if i not in moving),
                   key=lambda i: abs(float(ctx.cameras[i].forward[2])))  # fmt: skip
    chosen = (moving + level)[:count]
    offset = PREVIEW_ORBIT * ctx.median_depth
    cams = []
    for i in chosen:
        right = ctx.cameras[i].R[0]  # the camera's x axis in world coordinates
        cams.append(moved_camera(ctx.cameras[i], right * offset))
    return cams


def _export(
    ctx: LiftContext,
    static: Gaussians,
    dynamic: list[Gaussians],
    depths: list[torch.Tensor],
    split: Split,
) -> dict[str, Any]:
    from pano4d import ply4d
    from pano4d.images import write_contact_sheet, write_video

    start = time.perf_counter()
    out = Path(ctx.cfg.output)
    scene = _scene(ctx, static, dynamic, split)
    ply4d.write(out / "scene.ply4d", scene)
    render = ctx.render
    size = ctx.knobs.view_size
    preview_size = (2 * size, (2 * size * 9 // 16) // 2 * 2)  # 16:9, as wide as two views
    cams = turntable_cameras(preview_size, ctx.median_depth, PREVIEW_FRAMES)
    on_device = [scene.at(t).to(ctx.device) for t in range(scene.num_times)]
    with torch.no_grad():
        frames = [
            render(on_device[i % scene.num_times], c).rgb.clamp(0, 1).cpu().numpy()
            for i, c in enumerate(cams)
        ]
    write_video(out / "preview.mp4", frames, ctx.cfg.animate.fps)

    gt = read_gt_views(Path(ctx.cfg.panorama))
    metrics_views = (
        novel_view_metrics(scene, gt, lambda g, c: render(g.to(ctx.device), c)) if gt else None
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
        test = contact_cameras(ctx)
        for t in times:
            for c in test:
                with torch.no_grad():
                    tiles.append(render(on_device[t], c).rgb.clamp(0, 1).cpu().numpy())
                labels.append(f"t={t}")
        columns = len(test)
    write_contact_sheet(out / "contact.png", tiles, columns, labels)
    ctx.timings["export"] = time.perf_counter() - start

    metrics = _metrics(ctx, scene, split, depths, out / "scene.ply4d", metrics_views)
    write_json_atomic(out / "metrics.json", metrics)
    return metrics


def _metrics(
    ctx: LiftContext,
    scene: Any,
    split: Split,
    depths: list[torch.Tensor],
    path: Path,
    views: dict[str, Any] | None,
) -> dict[str, Any]:
    n_static = len(scene.static)
    n_dynamic = [len(g) for g in scene.dynamic]
    stored = n_static + sum(n_dynamic)
    whole = sum(n_static + n for n in n_dynamic)  # every timestamp stored whole
    size = path.stat().st_size
    bytes_per = size / max(stored, 1)
    iters = ctx.knobs.gaussian_iterations
    step = ctx.timings.get("full_scene_step", ctx.timings.get("static_per_step", 0.0))
    whole_seconds = len(scene.dynamic) * iters * step
    spent = ctx.timings.get("static", 0.0) + ctx.timings.get("dynamic", 0.0)
    helpers = ("static_per_step", "full_scene_step")
    timings = {k: v for k, v in ctx.timings.items() if k not in helpers}
    return {
        "preset": ctx.cfg.preset,
        "knobs": ctx.knobs.model_dump(),
        "config_hash": config_hash(ctx.cfg),
        "working_size": [int(ctx.frames.shape[2]), int(ctx.frames.shape[1])],
        "timings_s": timings,
        "gaussians": {
            "static": n_static,
            "dynamic": n_dynamic,
            "stored": stored,
            "initial_points": split.points,
        },
        "moving_fraction": float(ctx.moving.float().mean()),
        "median_depth": ctx.median_depth,
        "size_bytes": size,
        "saving": {
            "storage_whole_bytes_estimate": int(whole * bytes_per),
            "storage_ratio": size / max(whole * bytes_per, 1.0),
            "train_whole_seconds_estimate": whole_seconds,
            "train_seconds": spent,
            "train_ratio": spent / whole_seconds if whole_seconds > 0 else None,
        },
        "novel_views": views,
    }


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
