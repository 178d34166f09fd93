"""What a resident training step costs against what it renders: the context (frozen) Gaussians
rendered with the trained set, and the pixels of the view (or window) it renders.

A dynamic step renders a window of each view with the static Gaussians that can draw into
it (python/pano4d/lift/windows.py); this measures how a step's time follows each of the
two, on one synthetic cloud (context spread over the view, a small trained set), so that
bench/frames.py's stage times can be read: what is left when the context is empty is the
step's fixed cost (dispatches, loss passes, Adam, the Python loop). Each case also times the
loss passes alone (``TrainSession.loss_gradient`` on given pixels: the passes with the
pixels' upload and the gradient's read-back), the part of a step that follows the pixels
only.

    [PANO4D_PYTHON=other/python] .venv/bin/python bench/step_cost.py [--steps 40]
        [--json bench/out/step_cost.json]

PANO4D_PYTHON runs another checkout's package (with its extension), for a before/after.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, os.environ.get("PANO4D_PYTHON", str(REPO / "python")))

from pano4d.camera import Camera  # noqa: E402
from pano4d.fsutil import write_json_atomic  # noqa: E402
from pano4d.gaussians import Gaussians  # noqa: E402
from pano4d.lift.resident import ResidentTrainer  # noqa: E402
from pano4d.lift.trainer import Knobs, TrainViews  # noqa: E402

TRAINED = 150  # the trained (dynamic) set: a small cluster in the view
# (context Gaussians, view side in pixels): the context shrinking at draft's 128-px views,
# then the window shrinking with the context it keeps, then balanced's 512.
CASES = [(5000, 128), (3000, 128), (500, 128), (0, 128), (5000, 64), (500, 64), (0, 32),
         (5000, 512)]  # fmt: skip


def cloud(seed: int, n: int, centre: list[float], spread: float, scale: float) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)
    return Gaussians(
        torch.tensor(centre) + spread * torch.randn(n, 3, generator=gen),
        math.log(scale) + 0.3 * torch.randn(n, 3, generator=gen),
        torch.randn(n, 4, generator=gen),
        torch.randn(n, generator=gen) + 1.0,
        0.5 * torch.randn(n, 1, 3, generator=gen),
    )


def seconds_per_step(context: int, side: int, steps: int) -> tuple[float, float]:
    """Seconds a step takes, and its loss passes alone, with ``context`` Gaussians at
    ``side`` pixels."""
    camera = Camera.from_fov(90.0, side, side)
    gen = torch.Generator().manual_seed(2)
    views = TrainViews(
        [camera],
        torch.rand(1, side, side, 3, generator=gen),
        torch.ones(1, side, side),
        4.0 + torch.rand(1, side, side, generator=gen),
        torch.rand(1, side, side, 3, generator=gen),
    )
    knobs = Knobs(iterations=10**6, lambda_temporal=0.1, lambda_geo=0.05)
    trainer = ResidentTrainer(
        cloud(1, TRAINED, [5.0, 0.5, 0.2], 0.5, 0.05), views, knobs,
        static=cloud(0, context, [5.0, 0.0, 0.0], 2.0, 0.1),
    )  # fmt: skip
    session = trainer._session
    pixels = torch.rand(side * side * 5, generator=gen).numpy()

    def timed(run: Callable[[], object]) -> float:
        for _ in range(5):  # warm-up: pipelines, buffers
            run()
        session.loss()  # waits for the device
        start = time.perf_counter()
        for _ in range(steps):
            run()
        session.loss()
        return (time.perf_counter() - start) / steps

    return timed(trainer.train_step), timed(lambda: session.loss_gradient(0, pixels))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--json", type=Path, default=REPO / "bench" / "out" / "step_cost.json")
    args = parser.parse_args()
    print(f"{'context':>8}{'side':>6}{'s / step':>10}{'loss s':>10}")
    rows = []
    for context, side in CASES:
        step, loss = seconds_per_step(context, side, args.steps)
        rows.append({"context": context, "trained": TRAINED, "side": side, "s_per_step": step,
                     "loss_s": loss})  # fmt: skip
        print(f"{context:>8}{side:>6}{step:>10.4f}{loss:>10.4f}", flush=True)
    write_json_atomic(args.json, {
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "load": os.getloadavg()},
        "date": time.strftime("%Y-%m-%d"), "steps": args.steps, "rows": rows,
    })  # fmt: skip
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
