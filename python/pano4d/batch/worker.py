"""The worker side of a batch: one Ray task per scene (``train_scene``), which runs
``run_train`` silently (its output and tracebacks go to OUTPUT/batch.log) and posts its stage
to the driver's ``StageBoard`` through a ``StagePoster``."""

from __future__ import annotations

import contextlib
import math
import os
import socket
import time
import traceback
from pathlib import Path
from typing import Any

from pano4d.batch.gpu import pin_adapter
from pano4d.config import ConfigError, load_config
from pano4d.summary import summarise

REPORT_EVERY_S = 0.5  # a worker posts its step at most this often (stage changes at once)
LOG_NAME = "batch.log"  # in each scene's output folder: the worker's output and tracebacks


def one_line(error: BaseException) -> str:
    """An error as one line: pano4d's own errors already say what to fix; anything else
    keeps its type name. A multi-line message (a ConfigError) is joined with '; '."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    text = "; ".join(lines) or "(no message)"
    if type(error).__module__.split(".")[0] == "pano4d":
        return text
    return f"{type(error).__name__}: {text}"


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
    record["adapter"] = pin_adapter()
    from pano4d.train import resume_point, run_train

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
