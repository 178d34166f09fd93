"""What a resident training step costs against what it renders: the context (frozen) Gaussians
rendered with the trained set, and the pixels of the view (or window) it renders.

A dynamic step renders a window of each view with the static Gaussians that can draw into
it (python/pano4d/lift/windows.py); this measures how a step's time follows each of the
two, on one synthetic cloud (context spread over the view, a small trained set), so that
bench/frames.py's stage times can be read: what is left when the context is empty is the
step's fixed cost (dispatches, loss passes, Adam, the Python loop).

    .venv/bin/python bench/step_cost.py [--steps 40] [--json bench/out/step_cost.json]
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "python"))

from pano4d.camera import Camera  # noqa: E402
from pano4d.fsutil import write_json_atomic  # noqa: E402
from pano4d.gaussians import Gaussians  # noqa: E402
from pano4d.lift.optimize import Knobs, TrainViews  # noqa: E402
from pano4d.lift.resident import ResidentTrainer  # noqa: E402

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


def seconds_per_step(context: int, side: int, steps: int) -> float:
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
        context=cloud(0, context, [5.0, 0.0, 0.0], 2.0, 0.1),
    )  # fmt: skip
    for _ in range(5):  # warm-up: pipelines, buffers
        trainer.train_step()
    trainer._session.loss()  # waits for the device
    start = time.perf_counter()
    for _ in range(steps):
        trainer.train_step()
    trainer._session.loss()
    return (time.perf_counter() - start) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--json", type=Path, default=REPO / "bench" / "out" / "step_cost.json")
    args = parser.parse_args()
    print(f"{'context':>8}{'side':>6}{'s / step':>10}")
    rows = []
    for context, side in CASES:
        s = seconds_per_step(context, side, args.steps)
        rows.append({"context": context, "trained": TRAINED, "side": side, "s_per_step": s})
        print(f"{context:>8}{side:>6}{s:>10.4f}", flush=True)
    write_json_atomic(args.json, {
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "load": os.getloadavg()},
        "date": time.strftime("%Y-%m-%d"), "steps": args.steps, "rows": rows,
    })  # fmt: skip
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
