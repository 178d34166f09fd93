"""Rasteriser speed and reach.

    python bench/raster.py [--quick] [--repeats 3]
        forward and forward+backward time per frame, wgpu vs the torch reference, for
        10^4-10^6 Gaussians at 512², 1024² and 2048×1024 (bench/out/raster.json). The
        dense torch reference costs O(pixels × Gaussians); where that would take minutes
        it is timed on a fraction of the Gaussians and scaled linearly (marked
        "extrapolated"), or skipped beyond that.
    python bench/raster.py --presets [--baseline DIR] [--repeats 2] [--rounds 1]
        [--only draft balanced]
        forward+backward time per training step (through pano4d.render, as the torch
        training path runs it) at the draft, balanced and max presets' view sizes and SH
        degrees, each round alternating this checkout and the baseline
        (bench/out/raster_presets.json).
    python bench/raster.py --limits [--baseline DIR]
        the largest scenes whose forward+backward runs within the adapter's binding limits
        at 1024² (the max preset's views) and 1920×1080 (bench/out/raster_limits.json).

--baseline DIR measures another checkout side by side in the same run: DIR/python must hold
its pano4d package with its extension built (e.g. `git archive main | tar -x -C DIR`, then
`cargo build --release -p splat-core --features python` there and copy
libsplat_core.so to DIR/python/pano4d/_core.abi3.so). Each measurement of either runs in a
fresh worker process, so neither inherits the other's buffers. Peak memory is the worker's
peak resident set (lavapipe's GPU memory is host memory).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

OUT = Path(__file__).resolve().parent / "out"
HERE = Path(__file__).resolve().parents[1] / "python"
# Dense torch work (pixels × Gaussians) timed directly / by extrapolation at most.
TORCH_DIRECT_LIMIT = 5e7
TORCH_EXTRAPOLATE_LIMIT = 3e11
# Gaussians per preset: draft, the real lake panorama's static set at draft (85k, RESULTS);
# balanced at its start (98k) and near its cap (1M, less on an adapter whose binding does
# not hold that many at SH 2); max at its start (388k).
PRESET_SCENES = {"draft": [85_000], "balanced": [98_000, 800_000], "max": [388_000]}
# Counts around the previous path's limit (3.3·10⁶ intersections on lavapipe) and the
# current one's (33.5·10⁶) for this scene generator, per image size.
LIMIT_COUNTS = {(1024, 1024): [25_000, 50_000, 500_000, 1_000_000, 1_200_000],
                (1920, 1080): [10_000, 20_000, 200_000, 300_000]}


def scene(n: int, sh_degree: int = 3, seed: int = 0):
    """``n`` Gaussians in front of a camera at the origin looking along +x; their scales
    shrink with the count, so the image stays similarly covered."""
    import torch

    from pano4d.gaussians import Gaussians

    gen = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=gen) * torch.tensor([2.0, 3.0, 2.0])
    means[:, 0] += 6.0
    log_scale = -1.5 - 0.5 * torch.log10(torch.tensor(n / 1e4))
    return Gaussians(
        means=means,
        log_scales=log_scale + 0.5 * torch.randn(n, 3, generator=gen),
        quats=torch.randn(n, 4, generator=gen),
        opacity_logits=torch.randn(n, generator=gen),
        sh=0.3 * torch.randn(n, (sh_degree + 1) ** 2, 3, generator=gen),
    )


def time_call(fn, repeats: int, warm_up: bool = True) -> float:
    if warm_up:
        fn()  # pipelines, buffer sizes
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - start) / repeats


def frame_fns(g, cam, backend: str):
    import torch

    from pano4d.renderer import render

    def forward() -> None:
        with torch.no_grad():
            render(g, cam, backend=backend)

    def forward_backward() -> None:
        gg = g.map(lambda t: t.detach().requires_grad_(True))
        out = render(gg, cam, backend=backend)
        (out.rgb.sum() + out.alpha.sum()).backward()

    return forward, forward_backward


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def worker(job: dict) -> dict:
    """One measurement in this process, with the pano4d package under ``job["python"]``."""
    sys.path.insert(0, job["python"])
    from pano4d.camera import Camera
    from pano4d.extension import core, gaussian_arrays, view
    from pano4d.renderer import adapter_info

    g = scene(job["n"], job["sh_degree"])
    cam = Camera.from_fov(90.0, job["width"], job["height"], (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    info = adapter_info()
    result = {"adapter": info["name"], "paths": {k: info.get(k) for k in ("subgroups",
                                                                          "float_atomics")}}
    try:
        # The intersection count, through the extension (pano4d.render does not show it).
        result["intersections"] = core.render_forward(
            gaussian_arrays(g), view(cam), background=(0.0, 0.0, 0.0), antialiased=False
        ).intersections
        _, fb = frame_fns(g, cam, "wgpu")
        result["forward_backward_ms"] = 1e3 * time_call(fb, job["repeats"], job["warm_up"])
    except (RuntimeError, ValueError) as e:
        result["error"] = str(e).splitlines()[0]
    result["peak_rss_mib"] = peak_rss_mib()
    return result


def run_worker(job: dict, python_dir: Path) -> dict:
    """``worker(job)`` in a fresh process on the package in ``python_dir``."""
    job = {**job, "python": str(python_dir)}
    with tempfile.NamedTemporaryFile("r", suffix=".json") as out:
        proc = subprocess.run([sys.executable, __file__, "--worker", json.dumps(job), out.name],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:]
            return {"error": f"worker exited with {proc.returncode}: {' '.join(tail)}"}
        return json.loads(Path(out.name).read_text())


def write_json(name: str, payload: dict) -> Path:
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / name
    with tempfile.NamedTemporaryFile("w", dir=OUT, delete=False, suffix=".tmp") as f:
        json.dump(payload, f, indent=2)
    os.replace(f.name, path)
    return path


def fmt(v: float | None, width: int, digits: int = 1) -> str:
    return f"{'-':>{width}}" if v is None else f"{v:>{width}.{digits}f}"


def side_by_side(jobs: list[dict], baseline: Path | None, label: str) -> list[dict]:
    """Runs each job on this checkout and, if given, on ``baseline``; prints a row each."""
    print(f"{'':>12} {'N':>9} {'SH':>2} {'size':>10} {'intersections':>13} "
          f"{'f+b ms':>9} {'baseline ms':>11} {'ratio':>6} {'peak MiB':>9}  note", flush=True)
    rows = []
    for job in jobs:
        row = {**job, "current": run_worker(job, HERE)}
        if baseline is not None:
            row["baseline"] = run_worker(job, baseline / "python")
        cur, base = row["current"], row.get("baseline", {})
        ratio = (base["forward_backward_ms"] / cur["forward_backward_ms"]
                 if "forward_backward_ms" in base and "forward_backward_ms" in cur else None)
        row["baseline_over_current"] = ratio
        notes = [f"{who}: {r['error']}" for who, r in (("current", cur), ("baseline", base))
                 if "error" in r]
        print(f"{job.get(label, ''):>12} {job['n']:>9} {job['sh_degree']:>2} "
              f"{job['width']}x{job['height']:<5} {cur.get('intersections', 0):>13} "
              f"{fmt(cur.get('forward_backward_ms'), 9)} "
              f"{fmt(base.get('forward_backward_ms'), 11)} {fmt(ratio, 6, 2)} "
              f"{fmt(max(cur.get('peak_rss_mib', 0), base.get('peak_rss_mib', 0)), 9, 0)}  "
              f"{'; '.join(notes)}", flush=True)
        rows.append(row)
    return rows


def presets(args: argparse.Namespace) -> None:
    from pano4d.config import PRESETS

    jobs = [
        {"preset": name, "n": n, "sh_degree": int(PRESETS[name]["sh_degree"]),
         "width": int(PRESETS[name]["view_size"]), "height": int(PRESETS[name]["view_size"]),
         "repeats": args.repeats, "warm_up": True}
        for name, counts in PRESET_SCENES.items() if name in args.only for n in counts
    ]
    rows = []
    for round_ in range(args.rounds):
        rows += [{**row, "round": round_} for row in side_by_side(jobs, args.baseline, "preset")]
    print(f"wrote {write_json('raster_presets.json', {'rows': rows})}")


def limits(args: argparse.Namespace) -> None:
    # One timed call each (no warm-up): these scenes are about what fits, not speed.
    jobs = [{"size": f"{w}x{h}", "n": n, "sh_degree": 0, "width": w, "height": h,
             "repeats": 1, "warm_up": False}
            for (w, h), counts in LIMIT_COUNTS.items() for n in counts]
    rows = side_by_side(jobs, args.baseline, "size")
    print(f"wrote {write_json('raster_limits.json', {'rows': rows})}")


def wgpu_vs_torch(args: argparse.Namespace) -> None:
    import torch

    from pano4d.camera import Camera
    from pano4d.renderer import adapter_info

    counts = [10_000, 100_000] if args.quick else [10_000, 100_000, 1_000_000]
    sizes = [(512, 512)] if args.quick else [(512, 512), (1024, 1024), (2048, 1024)]
    info = adapter_info()
    print(f"adapter: {info['name']} ({info['backend']}, {info['device_type']})")
    rows = []
    print(f"{'N':>9} {'size':>10} {'wgpu fwd ms':>12} {'wgpu f+b ms':>12} "
          f"{'torch fwd ms':>13} {'torch f+b ms':>13} {'f+b ratio':>10} {'peak MiB':>9}  note")
    for n in counts:
        g = scene(n)
        for w, h in sizes:
            cam = Camera.from_fov(90.0, w, h, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
            fwd, fb = frame_fns(g, cam, "wgpu")
            try:
                wgpu_fwd = time_call(fwd, args.repeats)
                wgpu_fb = time_call(fb, args.repeats)
            except (RuntimeError, ValueError) as e:
                # e.g. a buffer beyond the adapter's storage binding limit
                print(f"{n:>9} {f'{w}x{h}':>10}  wgpu failed: {e}", flush=True)
                rows.append({"n": n, "width": w, "height": h, "error": str(e)})
                continue
            work = float(n) * w * h
            torch_fwd = torch_fb = None
            note = ""
            if work <= TORCH_DIRECT_LIMIT:
                tf, tfb = frame_fns(g, cam, "torch")
                torch_fwd, torch_fb = time_call(tf, 1), time_call(tfb, 1)
            elif work <= TORCH_EXTRAPOLATE_LIMIT:
                factor = max(1, round(work / TORCH_DIRECT_LIMIT))
                sub = g[torch.arange(0, n, factor)]
                tf, tfb = frame_fns(sub, cam, "torch")
                torch_fwd = time_call(tf, 1) * n / len(sub)
                torch_fb = time_call(tfb, 1) * n / len(sub)
                note = f"torch extrapolated from N/{factor}"
            else:
                note = "torch skipped (would take hours)"
            ratio = torch_fb / wgpu_fb if torch_fb else None
            row = {
                "n": n, "width": w, "height": h,
                "wgpu_forward_ms": 1e3 * wgpu_fwd, "wgpu_forward_backward_ms": 1e3 * wgpu_fb,
                "torch_forward_ms": None if torch_fwd is None else 1e3 * torch_fwd,
                "torch_forward_backward_ms": None if torch_fb is None else 1e3 * torch_fb,
                "forward_backward_speedup": ratio, "peak_rss_mib": peak_rss_mib(), "note": note,
            }
            rows.append(row)
            print(f"{n:>9} {f'{w}x{h}':>10} {fmt(row['wgpu_forward_ms'], 12)} "
                  f"{fmt(row['wgpu_forward_backward_ms'], 12)} {fmt(row['torch_forward_ms'], 13)} "
                  f"{fmt(row['torch_forward_backward_ms'], 13)} {fmt(ratio, 10)} "
                  f"{row['peak_rss_mib']:>9.0f}  {note}", flush=True)
    payload = {"adapter": info, "torch_threads": torch.get_num_threads(), "rows": rows}
    print(f"wrote {write_json('raster.json', payload)}")


def main() -> None:
    if len(sys.argv) == 4 and sys.argv[1] == "--worker":
        Path(sys.argv[3]).write_text(json.dumps(worker(json.loads(sys.argv[2]))))
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--presets", action="store_true",
                      help="fwd+bwd per step at the presets' sizes")
    mode.add_argument("--limits", action="store_true",
                      help="the largest scenes that fit the binding limits")
    parser.add_argument("--quick", action="store_true", help="10^4 and 10^5 at 512² only")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--rounds", type=int, default=1, help="--presets: times to run each")
    parser.add_argument("--only", nargs="+", choices=list(PRESET_SCENES),
                        default=list(PRESET_SCENES), help="--presets: these presets only")
    parser.add_argument("--baseline", type=Path, default=None,
                        help="a checkout (with its extension built) to measure side by side")
    args = parser.parse_args()
    if args.baseline is not None and not (args.baseline / "python" / "pano4d").is_dir():
        parser.error(f"--baseline {args.baseline}: expected a checkout with python/pano4d")
    if args.presets:
        presets(args)
    elif args.limits:
        limits(args)
    else:
        wgpu_vs_torch(args)


if __name__ == "__main__":
    main()
