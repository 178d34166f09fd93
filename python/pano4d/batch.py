"""``pano4d batch``: many scenes at once, one Ray task per scene.

The driver (``run_batch``) reads every scene.yaml, skips the scenes whose ``metrics.json``
says they are finished for this very config, and hands each other scene to Ray as one task
that runs ``run_train`` on a worker. Each task declares its resources (``num_gpus`` per scene
where the cluster has GPUs, else ``num_cpus``: one scene per CPU slot, rendering through
lavapipe), so Ray's scheduler places the scenes; pano4d schedules nothing itself. Outputs go
where each scene.yaml says (on a cluster that is a shared filesystem): a rerun of the same
batch finds them, and a scene killed half-way resumes from its own checkpoints.

Workers train silently (their output goes to ``OUTPUT/batch.log``) and post their stage to
a small Ray actor, the ``StageBoard``; the driver polls it and draws the only progress
display: one bar for the batch and a line per running scene. A failed scene becomes one
line in the table and in ``batch.json`` and never stops the others.

Ray is an optional dependency (``pip install 'pano4d[cluster]'``); nothing here imports it
at module level, so the rest of pano4d works without it.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import socket
import subprocess
import time
import traceback
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from rich import box
from rich.console import Console
from rich.markup import escape
from rich.table import Table
from rich.text import Text

from pano4d.config import ConfigError, SceneConfig, config_hash, load_config
from pano4d.errors import InputError
from pano4d.fsutil import write_json_atomic

# The rasteriser's adapter choice (splat-core raster/context.rs); read when it first starts.
ADAPTER_ENV = "PANO4D_ADAPTER"

INSTALL_HINT = "pano4d batch needs Ray: pip install 'pano4d[cluster]' (or: pip install 'ray>=2.60')"
SCENE_SUFFIXES = (".yaml", ".yml")
POLL_S = 0.5  # how often the driver reads the stage board and checks for finished tasks
REPORT_EVERY_S = 0.5  # a worker posts its step at most this often (stage changes at once)
LOG_NAME = "batch.log"  # in each scene's output folder: the worker's output and tracebacks
# A task whose worker or node dies is tried once more; it resumes from its checkpoints.
MAX_RETRIES = 1


class BatchError(InputError, ValueError):
    """Bad input for the whole batch (missing scene files, impossible resources, no Ray)."""


# --- which scenes -------------------------------------------------------------------------
def collect_scenes(arguments: Sequence[Path]) -> list[Path]:
    """The scene.yaml files the arguments name, in order, each once.

    An argument is a scene file (``.yaml`` / ``.yml``), a folder (every scene file below
    it, sorted; hidden folders left out), or a list file: one scene file or folder a line,
    relative to the list's folder, with blank lines and ``#`` comments ignored.
    """
    found: list[Path] = []

    def add(path: Path, where: str, in_list: bool) -> None:
        if not path.exists():
            raise BatchError(f"{where}: {path} not found")
        if path.is_dir():
            inside = sorted(
                p
                for p in path.rglob("*")
                if p.suffix in SCENE_SUFFIXES
                and p.is_file()
                and not any(part.startswith(".") for part in p.relative_to(path).parts)
            )
            if not inside:
                raise BatchError(f"{where}: {path} holds no .yaml scene files")
            found.extend(p.resolve() for p in inside)
        elif path.suffix in SCENE_SUFFIXES:
            found.append(path.resolve())
        elif in_list:
            raise BatchError(f"{where}: {path} is neither a scene .yaml nor a folder")
        else:
            for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                entry = line.split("#", 1)[0].strip()
                if entry:
                    add(path.parent / entry, f"{path} line {number}", in_list=True)

    for argument in arguments:
        add(Path(argument), "scene argument", in_list=False)
    if not found:
        raise BatchError("no scenes given")
    return list(dict.fromkeys(found))


def scene_name(path: Path, root: Path) -> str:
    """A short name for a scene: its path relative to ``root`` when below it, and only the
    folder for a file called scene.yaml (what ``pano4d synth`` writes)."""
    shown = path.parent if path.name == "scene.yaml" else path
    with contextlib.suppress(ValueError):
        return str(shown.relative_to(root)) if shown != root else path.name
    return str(shown)


# --- what a scene's output folder says ---------------------------------------------------
def finished_metrics(cfg: SceneConfig) -> dict[str, Any] | None:
    """The scene's metrics.json if ``run_train`` finished this very config, else None.

    ``run_train`` writes metrics.json last, after scene.ply4d, so a file carrying this
    config's hash means the whole run is done.
    """
    out = Path(cfg.output)
    try:
        metrics = json.loads((out / "metrics.json").read_text())
    except (OSError, ValueError):
        return None
    if metrics.get("config_hash") != config_hash(cfg) or not (out / "scene.ply4d").is_file():
        return None
    return metrics


def resume_point(cfg: SceneConfig) -> str | None:
    """Where ``run_train`` will pick this scene up, read from its checkpoints; None when
    nothing of it is there yet (a fresh start)."""
    from pano4d.lift.checkpoints import Checkpoints

    out = Path(cfg.output)
    ckpt = Checkpoints.for_config(out / "checkpoints", cfg)
    frames = cfg.animate.frames
    dynamic = ckpt.load("dynamic")
    if dynamic is not None:
        done = len(dynamic["done"])
        return "export" if done == frames else _with_step(f"dynamic t={done}", dynamic)
    static = ckpt.load("static")
    if static is not None:
        return "dynamic t=0" if "done" in static else _with_step("static", static)
    for stage, key, after in (("align", "frames", "static"), ("depth", "depth", "align frame 0")):
        state = ckpt.load(stage)
        if state is not None:
            done = len(state[key])
            return after if done == frames else f"{stage} frame {done}"
    animate = out / "animate"
    if (animate / "done.json").is_file():
        return "depth frame 0"
    if any((animate / "moving").glob("*")) or any((animate / "frames").glob("*")):
        return "animate"
    return None


def _with_step(label: str, state: dict[str, Any]) -> str:
    step = state.get("trainer", {}).get("step", 0)
    return f"{label} step {step}" if step else label


def summarise(metrics: dict[str, Any]) -> dict[str, Any]:
    """What the batch table shows of a scene's metrics.json."""
    views = metrics.get("novel_views") or {}
    return {
        "timings_s": metrics.get("timings_s", {}),
        "gaussians": metrics.get("gaussians", {}).get("stored"),
        "psnr": {k: v["psnr"] for k, v in (views.get("by_displacement") or {}).items()},
    }


def one_line(error: BaseException) -> str:
    """An error as one line: pano4d's own errors already say what to fix; anything else
    keeps its type name. A multi-line message (a ConfigError) is joined with '; '."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    text = "; ".join(lines) or "(no message)"
    if type(error).__module__.split(".")[0] == "pano4d":
        return text
    return f"{type(error).__name__}: {text}"


# --- the worker side ---------------------------------------------------------------------
class StageBoard:
    """The stage each running scene is at, posted by the workers, read by the driver.

    Ray runs it as an actor (no CPU reserved): the workers' ``post`` calls are fire and
    forget, and only the latest post per scene is kept, so a slow driver never backs up.
    """

    def __init__(self) -> None:
        self.stages: dict[int, tuple[str, int]] = {}

    def post(self, index: int, stage: str, step: int) -> None:
        self.stages[index] = (stage, step)

    def read(self) -> dict[int, tuple[str, int]]:
        return self.stages


class StagePoster:
    """``run_train``'s ``on_step`` hook: posts (stage, step) to the board, at most every
    REPORT_EVERY_S seconds unless the stage changed."""

    def __init__(self, board: Any, index: int) -> None:
        self.board, self.index = board, index
        self.stage, self.last = "", 0.0

    def post(self, stage: str, step: int) -> None:
        self.board.post.remote(self.index, stage, step)
        self.stage, self.last = stage, time.monotonic()

    def __call__(self, stage: str, step: int) -> None:
        if stage != self.stage or time.monotonic() - self.last >= REPORT_EVERY_S:
            self.post(stage, step)


def train_scene(scene: str, backend: str, board: Any, index: int) -> dict[str, Any]:
    """One Ray task: ``run_train`` on one scene. Never raises for the scene's own errors:
    they come back as ``{"status": "failed", "error": one line}``, the traceback goes to
    OUTPUT/batch.log."""
    started = time.time()
    record: dict[str, Any] = {"node": socket.gethostname(), "pid": os.getpid()}
    cpus = _assigned_cpus()
    # Ray sets OMP_NUM_THREADS per task, but torch reads it once per (reused) worker process.
    import torch

    torch.set_num_threads(cpus)
    os.environ.setdefault("LP_NUM_THREADS", str(cpus))  # lavapipe: stay within the slot
    record["adapter"] = _pin_adapter()
    from pano4d.train import run_train

    record["import_s"] = time.time() - started

    def failed(error: Exception, log: Path | None = None) -> dict[str, Any]:
        log_path = str(log) if log else None
        return {**record, "status": "failed", "error": one_line(error), "log": log_path,
                "started": started, "finished": time.time()}  # fmt: skip

    try:
        cfg = load_config(scene)
    except ConfigError as error:  # changed since the driver read it
        return failed(error)
    out = Path(cfg.output)
    out.mkdir(parents=True, exist_ok=True)
    poster = StagePoster(board, index)
    with open(out / LOG_NAME, "a", encoding="utf-8") as log:
        log.write(f"--- pano4d batch, {time.strftime('%Y-%m-%d %H:%M:%S')}, {scene}\n")
        log.flush()
        with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
            try:
                resumed = resume_point(cfg)
                poster.post(f"from {resumed}" if resumed else "animate, depth", 0)
                metrics = run_train(cfg, progress=False, render_backend=backend, on_step=poster)
            except Exception as error:
                traceback.print_exc(file=log)
                return failed(error, out / LOG_NAME)
    return {
        **record,
        **summarise(metrics),
        "status": "resumed" if resumed else "ok",
        "resumed_from": resumed,
        "started": started,
        "finished": time.time(),
    }


def _assigned_cpus() -> int:
    import ray

    cpus = ray.get_runtime_context().get_assigned_resources().get("CPU", 1.0)
    return max(1, math.floor(cpus))


def _pin_adapter() -> str | None:
    """Point the rasteriser at the GPU Ray gave this task (``PANO4D_ADAPTER=pci:<bus id>``).

    Ray hands a task its GPU through ``CUDA_VISIBLE_DEVICES``, which wgpu does not read: on a
    machine with several GPUs every scene would otherwise render on the first one. Returns
    the preference set, or None (no GPU assigned, one set by the user, or no nvidia-smi to
    name the GPU's slot: then wgpu picks, as ``pano4d train`` does).
    """
    import ray

    gpu_ids = ray.get_gpu_ids()
    if not gpu_ids or os.environ.get(ADAPTER_ENV):
        return os.environ.get(ADAPTER_ENV)
    try:
        listing = subprocess.run(
            ["nvidia-smi", "--query-gpu=index,pci.bus_id", "--format=csv,noheader"],
            capture_output=True, text=True, timeout=30, check=True,
        ).stdout  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return None
    bus = pci_bus_of_gpu(listing, str(gpu_ids[0]))
    if bus is not None:
        os.environ[ADAPTER_ENV] = f"pci:{bus}"
    return os.environ.get(ADAPTER_ENV)


def pci_bus_of_gpu(listing: str, index: str) -> str | None:
    """The PCI bus id of GPU ``index`` in ``nvidia-smi --query-gpu=index,pci.bus_id
    --format=csv,noheader`` output (``0, 00000000:3B:00.0`` per line)."""
    for line in listing.splitlines():
        fields = [field.strip() for field in line.split(",")]
        if len(fields) == 2 and fields[0] == index:
            return fields[1]
    return None


# --- the driver side ---------------------------------------------------------------------
@dataclass
class SceneOutcome:
    """One row of the batch table and of batch.json."""

    scene: str  # the scene.yaml
    name: str
    output: str | None = None
    status: str = "queued"  # ok | resumed | skipped | failed | interrupted
    resumed_from: str | None = None  # the stage a resumed scene picked up at
    error: str | None = None  # one line, for failed scenes
    log: str | None = None
    wall_s: float | None = None  # the task's run time on its worker (None: not run now)
    timings_s: dict[str, float] = field(default_factory=dict)  # metrics.json's, per stage
    gaussians: int | None = None
    psnr: dict[str, float] = field(default_factory=dict)  # per camera displacement
    ray: dict[str, Any] = field(default_factory=dict)  # when, where, and Ray's overhead

    def take(self, result: dict[str, Any], submitted: float, received: float) -> None:
        """Fill the row from a task's result and the driver's clock."""
        for key in ("status", "resumed_from", "error", "log", "timings_s", "gaussians", "psnr"):
            if key in result:
                setattr(self, key, result[key])
        self.wall_s = result["finished"] - result["started"]
        self.ray = {
            "node": result["node"],
            "pid": result["pid"],
            "adapter": result.get("adapter"),  # PANO4D_ADAPTER as the task ran (None: wgpu's pick)
            "submitted": submitted,
            "started": result["started"],
            "finished": result["finished"],
            "received": received,
            "import_s": result["import_s"],
            # from submission to the task's first line: queueing behind other scenes,
            # scheduling and, for a new worker, its start
            "wait_s": result["started"] - submitted,
            "result_s": received - result["finished"],  # result back to the driver
        }


@dataclass
class BatchReport:
    scenes: list[SceneOutcome]
    wall_s: float
    resources: dict[str, Any]
    ray_init_s: float | None

    @property
    def ok(self) -> bool:
        return all(s.status in ("ok", "resumed", "skipped") for s in self.scenes)

    def to_dict(self) -> dict[str, Any]:
        counts: dict[str, int] = {}
        for s in self.scenes:
            counts[s.status] = counts.get(s.status, 0) + 1
        return {
            "wall_s": self.wall_s,
            "counts": counts,
            "resources": self.resources,
            "ray_init_s": self.ray_init_s,
            "scenes": [asdict(s) for s in self.scenes],
        }


def require_ray() -> Any:
    """The ray module, or BatchError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise BatchError(INSTALL_HINT) from None
    return ray


def run_batch(
    arguments: Sequence[Path],
    report: Path,
    address: str | None = None,
    gpus_per_scene: float = 1.0,
    cpus_per_scene: float = 1.0,
    backend: str = "wgpu",
    console: Console | None = None,
) -> BatchReport:
    """Train every scene the arguments name on Ray; write ``report`` (batch.json) and
    return it. Raises BatchError for bad input (nothing is started then)."""
    console = console or Console(stderr=True)
    started = time.time()
    ray = require_ray()
    if backend not in ("wgpu", "torch"):
        raise BatchError(f"--backend must be wgpu or torch, got {backend!r}")
    if cpus_per_scene <= 0 or gpus_per_scene < 0:
        raise BatchError(
            f"--cpus-per-scene must be > 0 and --gpus-per-scene ≥ 0, got {cpus_per_scene} "
            f"and {gpus_per_scene}"
        )
    paths = collect_scenes(arguments)
    root = Path.cwd()
    rows = [SceneOutcome(str(p), scene_name(p, root)) for p in paths]
    to_run: list[int] = []
    writers: dict[Path, str] = {}
    for i, (path, row) in enumerate(zip(paths, rows, strict=True)):
        try:
            cfg = load_config(path)
        except ConfigError as error:
            row.status, row.error = "failed", one_line(error)
            continue
        row.output = str(cfg.output)
        if cfg.output in writers:
            raise BatchError(f"{writers[cfg.output]} and {path} both write to {cfg.output}")
        writers[cfg.output] = str(path)
        done = finished_metrics(cfg)
        if done is not None:
            row.status = "skipped"
            for key, value in summarise(done).items():
                setattr(row, key, value)
        else:
            to_run.append(i)

    resources: dict[str, Any] = {"address": address or "local"}
    ray_init_s = None
    try:
        if to_run:
            ray_init_s, resources = _run_on_ray(
                ray, rows, to_run, address, gpus_per_scene, cpus_per_scene, backend, console
            )
    except KeyboardInterrupt:  # what finished is recorded; a rerun picks up the rest
        partial = BatchReport(rows, time.time() - started, resources, None)
        write_json_atomic(report, partial.to_dict())
        raise
    result = BatchReport(rows, time.time() - started, resources, ray_init_s)
    write_json_atomic(report, result.to_dict())
    return result


def _run_on_ray(
    ray: Any,
    rows: list[SceneOutcome],
    to_run: list[int],
    address: str | None,
    gpus_per_scene: float,
    cpus_per_scene: float,
    backend: str,
    console: Console,
) -> tuple[float, dict[str, Any]]:
    """Start (or join) Ray, run the scenes ``to_run``, fill their rows."""
    import logging

    if address:
        _check_reachable(address)
    init_start = time.perf_counter()
    ray.init(
        address=address or "local",
        include_dashboard=False,
        log_to_driver=False,  # workers write to OUTPUT/batch.log; the driver draws alone
        logging_level=logging.ERROR,
    )
    init_s = time.perf_counter() - init_start
    try:
        gpus = _placeable(ray, cpus_per_scene, gpus_per_scene, console)
        resources = {
            "address": address or "local",
            "cluster": {k: v for k, v in ray.cluster_resources().items() if k in ("CPU", "GPU")},
            "per_scene": {"CPU": cpus_per_scene, "GPU": gpus},
        }
        board = ray.remote(num_cpus=0)(StageBoard).remote()
        # A GPU task gets a fresh worker (max_calls=1): a reused one would keep its CUDA
        # context on the GPU of its previous task, and hold that task's cached memory.
        task = ray.remote(
            num_cpus=cpus_per_scene,
            num_gpus=gpus,
            max_calls=1 if gpus > 0 else 0,
            max_retries=MAX_RETRIES,
        )(train_scene)
        _drive(ray, task, board, rows, to_run, backend, console)
    finally:
        ray.shutdown()
    return init_s, resources


def _check_reachable(address: str) -> None:
    """A HOST:PORT address that refuses connections is bad input, said at once: Ray itself
    would retry for minutes. (``auto`` and ``ray://`` addresses are left to Ray.)"""
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or "://" in address:
        return
    try:
        socket.create_connection((host, int(port)), timeout=10).close()
    except OSError as error:
        raise BatchError(
            f"--address {address}: no Ray cluster answers there ({error}); start one with "
            "`ray start --head` on that machine"
        ) from None


def _placeable(ray: Any, cpus: float, gpus: float, console: Console) -> float:
    """The GPUs to ask per scene: ``gpus``, or 0 when no node has a GPU (CPU slots). Raises
    BatchError when no live node could ever run one scene."""
    nodes = [n["Resources"] for n in ray.nodes() if n.get("Alive")]
    if gpus > 0 and not any(n.get("GPU", 0) > 0 for n in nodes):
        console.print(f"no GPU in the Ray cluster: one scene per {cpus:g} CPU(s), CPU adapter")
        gpus = 0.0
    if not any(n.get("CPU", 0) >= cpus and n.get("GPU", 0) >= gpus for n in nodes):
        sizes = sorted({f"{n.get('CPU', 0):g} CPUs + {n.get('GPU', 0):g} GPUs" for n in nodes})
        raise BatchError(
            f"no node of the Ray cluster has {cpus:g} CPU(s) and {gpus:g} GPU(s) for one scene "
            f"(its nodes: {', '.join(sizes) or 'none'}); lower --cpus-per-scene / --gpus-per-scene"
        )
    return gpus


def _drive(
    ray: Any,
    task: Any,
    board: Any,
    rows: list[SceneOutcome],
    to_run: list[int],
    backend: str,
    console: Console,
) -> None:
    """Submit the tasks, draw the progress, collect the results as they come."""
    from pano4d.progress import Bars, Task

    pending: dict[Any, int] = {}
    submitted: dict[int, float] = {}
    for i in to_run:
        submitted[i] = time.time()
        pending[task.remote(rows[i].scene, backend, board, i)] = i
    done = len(rows) - len(to_run)
    lines: dict[int, Task] = {}
    try:
        with Bars("stage", console=console, whole_run_eta=True) as bars:
            batch = bars.task("batch", total=len(rows), completed=done)
            # A tiny first advance anchors the whole-run rate at the start.
            batch.update(done + 1e-9)
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=POLL_S)
                for ref in ready:
                    i = pending.pop(ref)
                    _collect(ray, ref, rows[i], submitted[i])
                    if i in lines:
                        lines.pop(i).remove()
                    bars.print(_outcome_line(rows[i]))
                    done += 1
                    failed = sum(rows[j].status == "failed" for j in to_run)
                    batch.update(done, stage=f"{failed} failed" if failed else "")
                stages = ray.get(board.read.remote())
                _show_stages(bars, lines, stages, rows, set(pending.values()))
    except KeyboardInterrupt:
        for ref, i in pending.items():
            ray.cancel(ref, force=True)
            rows[i].status = "interrupted"
        raise


def _collect(ray: Any, ref: Any, row: SceneOutcome, submitted: float) -> None:
    try:
        result = ray.get(ref)
    except ray.exceptions.RayError as error:  # the worker or its node died, or pano4d is
        row.status = "failed"  # missing there
        row.error = one_line(getattr(error, "cause", None) or error)
        return
    row.take(result, submitted, time.time())


def _show_stages(
    bars: Any,
    lines: dict[int, Any],
    stages: dict[int, tuple[str, int]],
    rows: list[SceneOutcome],
    running: set[int],
) -> None:
    """One progress line per running scene: its stage and step (totals vary by stage)."""
    for i, (stage, step) in stages.items():
        if i not in running:
            continue
        if i not in lines:
            lines[i] = bars.task(f"  {escape(rows[i].name)}", total=None)
        lines[i].update(step, stage=escape(stage))


def _outcome_line(row: SceneOutcome) -> str:
    if row.status == "failed":
        return f"[red]✗[/] {escape(row.name)}: {escape(row.error or '')}"
    note = f" (resumed from {row.resumed_from})" if row.resumed_from else ""
    return f"[green]✓[/] {escape(row.name)} in {_seconds(row.wall_s)}{note}"


# --- the table ---------------------------------------------------------------------------
LIFT_STAGES = ("depth", "align", "static", "dynamic")  # the lifting phase, in metrics.json


def batch_table(report: BatchReport) -> Table:
    """Every scene: status, seconds per phase (from its metrics.json), the task's wall time,
    Gaussians stored, PSNR of the ground-truth views, and the error of a failed scene."""
    table = Table(
        title=f"pano4d batch: {_count(len(report.scenes), 'scene')} in {_seconds(report.wall_s)}",
        box=box.SIMPLE_HEAD,
        padding=(0, 1),
    )
    table.add_column("scene", overflow="fold")
    table.add_column("status")
    for name in ("animate", "lift", "export", "task", "Gaussians", "PSNR 1/5%"):
        table.add_column(name, justify="right")
    table.add_column("note", overflow="fold", min_width=24)
    colours = {"ok": "green", "resumed": "green", "skipped": "cyan", "failed": "red"}
    for s in report.scenes:
        t = s.timings_s
        lift = sum(t[k] for k in LIFT_STAGES if k in t) if t else None
        note = s.error or (f"from {s.resumed_from}" if s.resumed_from else "")
        if s.status == "skipped":
            note = "finished before"
        psnr = "/".join(f"{s.psnr[k]:.1f}" for k in ("1%", "5%") if k in s.psnr) or "-"
        table.add_row(
            Text(s.name),
            f"[{colours.get(s.status, 'yellow')}]{s.status}[/]",
            _seconds(t.get("animate")),
            _seconds(lift),
            _seconds(t.get("export")),
            _seconds(s.wall_s),
            f"{s.gaussians:,}" if s.gaussians is not None else "-",
            psnr,
            Text(note),
        )
    return table


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _seconds(value: float | None) -> str:
    if value is None:
        return "-"
    if value < 60:
        return f"{value:.1f}s"
    minutes, seconds = divmod(round(value), 60)
    return f"{minutes}m{seconds:02d}s" if minutes < 60 else f"{minutes // 60}h{minutes % 60:02d}m"
