"""A 4D scene in headless Chromium (WebGL2 on SwiftShader): `pano4d serve` and `pano4d web`.

Measures, at 1280×720:
- serve: seconds from starting `pano4d serve` to the first frame that shows the scene, and to
  the frame where viser's splat sort has settled; per time change (the time slider moved
  one step with the keyboard): seconds until the canvas changes and until it settles;
- web: seconds `pano4d web` takes, seconds from opening index.html (served by python's
  http.server on loopback) to the first frame (no settled time: the recording plays); the
  folder's size against the .ply4d plus viser's client (goal ≤ 1.5×).
A frame is a screenshot (about 1 s each on SwiftShader with two loaded cores), so times are
good to about a second. Prints a table and writes bench/out/web.json.

    .venv/bin/python bench/web.py [--scene lake.ply4d | --static N --dynamic N] [--size-only]
        [--json bench/out/web.json]

Without --scene, a synthetic scene is made, by default the size of the trained lake (85,000
static Gaussians, 6 timestamps of 13,000; random colours, so it compresses less than a real
scene). ``--size-only`` skips the browser.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "python"))
sys.path.insert(0, str(ROOT / "tests"))

from browser import Browser  # noqa: E402
from test_web import file_server  # noqa: E402

from pano4d import ply4d, web  # noqa: E402
from pano4d.fsutil import write_json_atomic  # noqa: E402
from pano4d.gaussians import Gaussians, rgb_to_sh_dc  # noqa: E402

WIDTH, HEIGHT = 1280, 720


def synthetic(path: Path, static: int = 85_000, dynamic: int = 13_000, times: int = 6) -> None:
    """Random Gaussians on a sphere of radius 10 around the viewpoint (static) and in a band
    in front of it that changes colour at every timestamp (dynamic)."""
    gen = torch.Generator().manual_seed(0)

    def sphere(n: int, lat_max: float) -> Gaussians:
        d = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen), dim=-1)
        d[:, 2] = d[:, 2].clamp(-lat_max, lat_max)
        d = torch.nn.functional.normalize(d, dim=-1)
        return Gaussians(
            means=10 * d,
            log_scales=torch.full((n, 3), math.log(0.08)),
            quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
            opacity_logits=torch.full((n,), 4.0),
            sh=rgb_to_sh_dc(torch.rand(n, 3, generator=gen))[:, None, :],
        )

    scene = ply4d.Scene4D(
        static=sphere(static, 1.0),
        dynamic=[sphere(dynamic, 0.2) for _ in range(times)],
        timestamps=[t / 6 for t in range(times)],
        fps=6.0,
    )
    ply4d.write(path, scene)


def textured(frame: np.ndarray) -> bool:
    return frame.size > 0 and float(frame.std()) > 0.05


def first_frame(b: Browser, start: float, timeout: float = 600.0) -> float:
    """Seconds from ``start`` to the first frame showing the scene."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if textured(b.frame()):
            return time.monotonic() - start
    raise TimeoutError("the scene did not appear")


def time_change(b: Browser, before: np.ndarray) -> tuple[float, float]:
    """Move the time slider one step; seconds until the canvas changes and until it settles."""
    from selenium.webdriver.common.keys import Keys

    start = time.monotonic()
    b.driver.find_element("css selector", "[role=slider]").send_keys(Keys.ARROW_RIGHT)
    while True:
        frame = b.frame()
        if frame.shape == before.shape and float(np.abs(frame - before).mean()) > 1e-3:
            changed = time.monotonic() - start
            break
    b.wait_for_scene(textured)
    return changed, time.monotonic() - start


def bench_serve(b: Browser, scene: Path, changes: int) -> dict[str, float]:
    port = web.free_port("127.0.0.1")
    start = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", "pano4d.cli", "serve", str(scene), "--port", str(port)],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if "http://127.0.0.1:" in line:
                break
        ready = time.monotonic() - start
        b.open(f"http://127.0.0.1:{port}/")
        shown = first_frame(b, start)
        b.wait_for_scene(textured)
        settled = time.monotonic() - start
        frame = b.frame()
        per_change = []
        for _ in range(changes):
            per_change.append(time_change(b, frame))
            frame = b.frame()
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    return {
        "serve_ready_s": ready,
        "serve_first_frame_s": shown,
        "serve_settled_s": settled,
        "time_change_s": float(np.mean([c for c, _ in per_change])),
        "time_change_settled_s": float(np.mean([s for _, s in per_change])),
    }


def bench_web(b: Browser | None, scene: Path, out: Path) -> dict[str, float]:
    start = time.monotonic()
    result = subprocess.run(
        [sys.executable, "-m", "pano4d.cli", "web", str(scene), str(out)],
        capture_output=True,
        text=True,
    )
    if result.returncode != 0:
        raise RuntimeError(result.stderr)
    written = time.monotonic() - start
    folder = sum(p.stat().st_size for p in out.iterdir())
    client = web.client_html_path().stat().st_size
    frames = {}
    if b is not None:
        with file_server(out) as url:
            start = time.monotonic()
            b.open(f"{url}/index.html")
            # No settled time: the recording plays, so the canvas changes at the scene's fps.
            frames = {"web_first_frame_s": first_frame(b, start)}
    return {
        "web_write_s": written,
        **frames,
        "ply4d_mb": scene.stat().st_size / 1e6,
        "client_mb": client / 1e6,
        "recording_mb": (out / web.RECORDING_NAME).stat().st_size / 1e6,
        "folder_mb": folder / 1e6,
        "folder_ratio": folder / (scene.stat().st_size + client),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", type=Path, help="a .ply4d (default: a synthetic one)")
    parser.add_argument("--changes", type=int, default=3, help="time changes to average")
    parser.add_argument("--static", type=int, default=85_000, help="synthetic static set")
    parser.add_argument("--dynamic", type=int, default=13_000, help="synthetic dynamic sets")
    parser.add_argument(
        "--size-only", action="store_true", help="`pano4d web` time and folder size, no browser"
    )
    parser.add_argument("--json", type=Path, default=ROOT / "bench" / "out" / "web.json")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        scene = args.scene
        if scene is None:
            scene = Path(tmp) / "synthetic.ply4d"
            synthetic(scene, args.static, args.dynamic)
        header = ply4d.open(scene)
        counts = {
            "static": len(header.static()),
            "dynamic": len(header.dynamic(0)),
            "times": header.num_times,
        }
        row: dict[str, object] = {"scene": str(args.scene or "synthetic"), **counts}
        if args.size_only:
            row |= bench_web(None, scene, Path(tmp) / "site")
        else:
            start = time.monotonic()
            b = Browser(WIDTH, HEIGHT)
            row["browser_start_s"] = time.monotonic() - start
            try:
                row |= bench_serve(b, scene, args.changes)
                row |= bench_web(b, scene, Path(tmp) / "site")
            finally:
                b.close()
    row |= {
        "size": f"{WIDTH}x{HEIGHT}",
        "renderer": "headless Chromium, WebGL2 on SwiftShader",
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "load_1min": os.getloadavg()[0],
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
    }
    for key, value in row.items():
        shown = f"{value:.2f}" if isinstance(value, float) else str(value)
        print(f"{key:>24}  {shown}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.json, row)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
