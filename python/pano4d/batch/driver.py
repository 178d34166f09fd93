"""The driver side of a batch (``run_batch``): reads every scene.yaml, skips the scenes
whose run finished for this very config, hands each other scene to Ray as one task
(``batch.worker.train_scene``), draws the progress, and records a row per scene
(``SceneOutcome``) in batch.json."""

from __future__ import annotations

import socket
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape

from pano4d.batch.scenes import BatchError, collect_scenes, scene_name
from pano4d.batch.worker import StageBoard, one_line, train_scene
from pano4d.config import ConfigError, load_config
from pano4d.fsutil import write_json_atomic
from pano4d.summary import duration, summarise

INSTALL_HINT = "pano4d batch needs Ray: pip install 'pano4d[cluster]' (or: pip install 'ray>=2.60')"
POLL_S = 0.5  # how often the driver reads the stage board and checks for finished tasks
# A task whose worker or node dies is tried once more; it resumes from its checkpoints.
MAX_RETRIES = 1


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
    from pano4d.train import finished_metrics  # the training stack: once the input is known

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
    return f"[green]✓[/] {escape(row.name)} in {duration(row.wall_s)}{note}"
