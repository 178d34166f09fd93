"""Rasteriser speed: forward and forward+backward time per frame, wgpu vs the torch
reference, for 10^4-10^6 Gaussians at 512², 1024² and 2048×1024.

    python bench/raster.py [--quick] [--repeats 3]

Prints a table and writes bench/out/raster.json. The dense torch reference costs
O(pixels × Gaussians); where that would take minutes it is timed on a fraction of the
Gaussians and scaled linearly (marked "extrapolated"), or skipped beyond that.
Peak memory is the process's peak resident set (lavapipe's GPU memory is host memory).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import tempfile
import time
from pathlib import Path

import torch
from pano4d.camera import Camera
from pano4d.gaussians import Gaussians
from pano4d.render import adapter_info, render

OUT = Path(__file__).resolve().parent / "out" / "raster.json"
# Dense torch work (pixels × Gaussians) timed directly / by extrapolation at most.
TORCH_DIRECT_LIMIT = 5e7
TORCH_EXTRAPOLATE_LIMIT = 3e11


def scene(n: int, seed: int = 0) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=gen) * torch.tensor([2.0, 3.0, 2.0])
    means[:, 0] += 6.0
    # Scales shrink with count so that the image stays similarly covered.
    log_scale = -1.5 - 0.5 * torch.log10(torch.tensor(n / 1e4))
    return Gaussians(
        means=means,
        log_scales=log_scale + 0.5 * torch.randn(n, 3, generator=gen),
        quats=torch.randn(n, 4, generator=gen),
        opacity_logits=torch.randn(n, generator=gen),
        sh=0.3 * torch.randn(n, 16, 3, generator=gen),
    )


def time_call(fn, repeats: int) -> float:
    fn()  # warm-up: pipelines, buffer sizes
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - start) / repeats


def frame_fns(g: Gaussians, cam: Camera, backend: str):
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10^4 and 10^5 at 512² only")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    counts = [10_000, 100_000] if args.quick else [10_000, 100_000, 1_000_000]
    sizes = [(512, 512)] if args.quick else [(512, 512), (1024, 1024), (2048, 1024)]
    info = adapter_info()
    print(f"adapter: {info['name']} ({info['backend']}, {info['device_type']})")
    rows = []
    header = (f"{'N':>9} {'size':>10} {'wgpu fwd ms':>12} {'wgpu f+b ms':>12} "
              f"{'torch fwd ms':>13} {'torch f+b ms':>13} {'f+b ratio':>10} {'peak MiB':>9}  note")
    print(header)
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

            def fmt(v: float | None, width: int) -> str:
                return f"{'-':>{width}}" if v is None else f"{v:>{width}.1f}"

            print(f"{n:>9} {f'{w}x{h}':>10} {fmt(row['wgpu_forward_ms'], 12)} "
                  f"{fmt(row['wgpu_forward_backward_ms'], 12)} {fmt(row['torch_forward_ms'], 13)} "
                  f"{fmt(row['torch_forward_backward_ms'], 13)} {fmt(ratio, 10)} "
                  f"{row['peak_rss_mib']:>9.0f}  {note}", flush=True)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    payload = {"adapter": info, "torch_threads": torch.get_num_threads(), "rows": rows}
    with tempfile.NamedTemporaryFile("w", dir=OUT.parent, delete=False, suffix=".tmp") as f:
        json.dump(payload, f, indent=2)
    os.replace(f.name, OUT)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
