"""What `pano4d train --serve` costs a training run: the same run with and without it, in pairs.

Each pair trains one synthetic scene from scratch twice (fresh copies of one `pano4d synth`
folder, so nothing resumes): plain `pano4d train`, and with `--serve` and no browser
connected, the order alternating from pair to pair so that a drift in the machine's load
falls on both alike. With ``--browser`` each pair has a third run, `--serve` with headless
Chromium (tests/browser.py: WebGL2 on SwiftShader) on the page from the moment the server
answers until training ends. Per run: the command's wall time and the static and dynamic
stages' seconds (metrics.json); per pair, each `--serve` run against its plain twin.
Issue #39's target: ≤ 1.05× the wall time with no browser connected. Prints a table and
writes bench/out/live.json.

    .venv/bin/python bench/live.py [--pairs 3] [--width 1024] [--frames 4] [--preset draft]
        [--checkpoint-every 50] [--browser] [--tiny] [--json bench/out/live.json]

``--tiny``: the tests' tiny scene (512×256, 2 frames, a few steps a stage), a smoke run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "python"))
sys.path.insert(0, str(ROOT / "tests"))

from browser import Browser  # noqa: E402
from pano4d_process import tiny_scene  # noqa: E402

from pano4d.fsutil import write_json_atomic  # noqa: E402
from pano4d.synth import run_synth  # noqa: E402
from pano4d.web import free_port  # noqa: E402

VARIANTS = ("plain", "serve", "browser")  # browser: --serve with Chromium on the page


def make_scene(folder: Path, args: argparse.Namespace) -> Path:
    """The scene every run trains a copy of; returns its folder."""
    if args.tiny:
        tiny_scene(folder, frames=2)
        return folder
    yaml = run_synth(folder, args.width, args.width // 2, args.frames, seed=0, views=2)
    text = yaml.read_text().replace("preset: draft", f"preset: {args.preset}")
    yaml.write_text(text)
    return folder


def wait_for_server(port: int, proc: subprocess.Popen[bytes]) -> bool:
    """True once something answers on ``port``; False if ``proc`` ended first."""
    while proc.poll() is None:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return True
        except OSError:
            time.sleep(0.2)
    return False


def train_once(
    pristine: Path, work: Path, variant: str, every: int, browser: Browser | None
) -> dict[str, Any]:
    """One `pano4d train` of a fresh copy of ``pristine``: wall seconds and stage seconds."""
    folder = work / variant
    if folder.exists():
        shutil.rmtree(folder)
    shutil.copytree(pristine, folder)
    command = [sys.executable, "-m", "pano4d.cli", "train", str(folder / "scene.yaml"),
               "--checkpoint-every", str(every)]  # fmt: skip
    port = free_port("127.0.0.1")
    if variant != "plain":
        command += ["--serve", "--port", str(port)]
    log = folder / "train.log"
    with log.open("wb") as out:
        start = time.perf_counter()
        proc = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
        if variant == "browser":
            assert browser is not None
            if wait_for_server(port, proc):
                browser.open(f"http://127.0.0.1:{port}/")
        returncode = proc.wait()
        wall = time.perf_counter() - start
    if returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({returncode}):\n{log.read_text()}")
    timings = json.loads((folder / "output" / "metrics.json").read_text())["timings_s"]
    if browser is not None:
        browser.open("about:blank")  # off the page before the next run
    return {"variant": variant, "wall_s": wall, "static_s": timings["static"],
            "dynamic_s": timings["dynamic"]}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--width", type=int, default=1024, help="synthetic panorama width")
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--preset", default="draft")
    parser.add_argument("--checkpoint-every", type=int, default=50)
    parser.add_argument("--browser", action="store_true", help="a third run: Chromium on it")
    parser.add_argument("--tiny", action="store_true", help="the tests' tiny scene (smoke)")
    parser.add_argument("--json", type=Path, default=ROOT / "bench" / "out" / "live.json")
    args = parser.parse_args()
    variants = VARIANTS if args.browser else VARIANTS[:2]
    runs: list[dict[str, Any]] = []
    browser = Browser(1280, 720) if args.browser else None
    try:
        with tempfile.TemporaryDirectory() as tmp:
            pristine = make_scene(Path(tmp) / "pristine", args)
            for pair in range(args.pairs):
                order = variants if pair % 2 == 0 else variants[::-1]
                for variant in order:
                    run = train_once(pristine, Path(tmp), variant, args.checkpoint_every,
                                     browser if variant == "browser" else None)  # fmt: skip
                    runs.append({"pair": pair, **run})
                    print(f"pair {pair} {variant:>8}  {run['wall_s']:8.2f} s wall  "
                          f"static {run['static_s']:.2f} s  dynamic {run['dynamic_s']:.2f} s",
                          flush=True)  # fmt: skip
    finally:
        if browser is not None:
            browser.close()

    def ratios(variant: str, key: str) -> list[float]:
        by_pair = {(r["pair"], r["variant"]): r[key] for r in runs}
        return [by_pair[p, variant] / by_pair[p, "plain"] for p in range(args.pairs)]

    summary = {
        f"{variant}_over_plain_{key}": {"median": statistics.median(r), "each": r}
        for variant in variants[1:]
        for key in ("wall_s", "static_s", "dynamic_s")
        for r in [ratios(variant, key)]
    }
    print()
    print(f"{'against the plain run':>28}  {'median':>7}  each pair")
    for name, value in summary.items():
        each = "  ".join(f"{v:.3f}" for v in value["each"])
        print(f"{name:>28}  {value['median']:7.3f}  {each}")
    scene = f"synth landscape {args.width} wide, {args.frames} frames, {args.preset}"
    row = {
        "scene": "tiny" if args.tiny else scene,
        "checkpoint_every": args.checkpoint_every,
        "runs": runs,
        **summary,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "load_1min": os.getloadavg()[0],
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.json, row)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
