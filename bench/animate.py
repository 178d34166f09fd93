"""Speed and memory of the Panoramic Denoiser (pano4d.animate, backend svd).

For moving regions worth 0.05, 1, 4 and 20 views (a cap with that many views' share of the
sphere's area; 0.05 is a click-sized region, 20 the whole sphere): active views, UNet calls
and view evaluations per scene, and per denoising step the seconds and peak memory of
project / UNet / fuse. Then tiled decoding of an L-frame equirect latent: seconds and peak
memory per panorama width. Prints tables and writes bench/out/animate.json
(bench/out/animate_full.json with --full).

Peak memory is what the phase adds above its level at entry: the CUDA allocator's peak on
a GPU; on the CPU the growth of the process's resident set (sampled every millisecond,
after malloc_trim returns freed heap), a lower bound where the allocator reuses memory.

CPU, the tiny random model of the tests (default):
    .venv/bin/python bench/animate.py
GPU, SVD's own architecture with random weights (the real model's FLOPs and memory) at
the paper's setting, 20 views, L = 14, 25 steps, 4096×2048, float16:
    .venv/bin/python bench/animate.py --full [--weights DIR]

The random model is written in diffusers format (float16 files with --full: ~4.5 GB) and
loaded by path through ``svd.load_svd``, as real weights are; ``--weights DIR`` keeps it in
DIR for the next run (or loads real SVD weights from there). Per scene the JSON records the
batching: views per step batch, the UNet's row bound from its attention calls
(unet_attention.py), the rows each UNet call took and the calls made.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import os
import platform
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))

from pano4d.animate.decode import tiled_equirect
from pano4d.animate.random_svd import save_random_svd
from pano4d.animate.svd import (
    DECODE_OVERLAP,
    DECODE_TILE,
    SVDDenoiser,
    load_svd,
    prepare_panorama,
    resolve_dtype,
)
from pano4d.config import AnimateConfig
from pano4d.device import resolve_device
from pano4d.fsutil import write_json_atomic
from pano4d.images import read_panorama
from pano4d.sphere import equirect_directions, view_directions, view_layout, views_seeing

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
PANORAMA = DATA / "pano_lake.jpg"
_LIBC = ctypes.CDLL("libc.so.6")


class PeakMemory:
    """Per named phase, the largest memory increase above the phase's starting level."""

    def __init__(self, device: torch.device) -> None:
        self.device = device
        self.peaks: dict[str, int] = {}
        self._rss_peak = 0
        self._stop = threading.Event()
        self._sampler: threading.Thread | None = None
        if device.type == "cpu":
            self._page = os.sysconf("SC_PAGE_SIZE")
            self._sampler = threading.Thread(target=self._sample, daemon=True)
            self._sampler.start()

    def _rss(self) -> int:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * self._page

    def _sample(self) -> None:
        while not self._stop.is_set():
            self._rss_peak = max(self._rss_peak, self._rss())
            time.sleep(0.001)

    def close(self) -> None:
        self._stop.set()
        if self._sampler is not None:
            self._sampler.join()

    @contextlib.contextmanager
    def phase(self, name: str) -> Iterator[None]:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
            start = torch.cuda.memory_allocated(self.device)
            torch.cuda.reset_peak_memory_stats(self.device)
        else:
            _LIBC.malloc_trim(0)  # hand freed heap back, so growth is this phase's own
            start = self._rss()
            self._rss_peak = start
        yield
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
            used = torch.cuda.max_memory_allocated(self.device) - start
        else:
            used = max(self._rss_peak, self._rss()) - start
        self.peaks[name] = max(self.peaks.get(name, 0), used)


def _mib(n: int) -> float:
    return round(n / 2**20, 1)


def load_panorama(source: str, width: int) -> torch.Tensor:
    """The panorama at ``width``: the image at ``source``, or for ``"synthetic"`` smooth
    colour waves (with random weights the UNet's cost does not depend on the content; for a
    machine without ../shared/data)."""
    if source == "synthetic":
        dirs = equirect_directions(width, width // 2, torch.float64)
        x, y, z = dirs.unbind(-1)
        waves = torch.stack([torch.sin(5 * x + z), torch.cos(4 * y), torch.sin(3 * z + x)])
        return (0.5 + 0.4 * waves).float().contiguous()
    path = Path(source)
    if not path.is_file():
        raise SystemExit(f"benchmark panorama not found: {path} (see shared/data/SOURCES.md)")
    image = torch.from_numpy(read_panorama(path)).permute(2, 0, 1)[None]
    if image.shape[-1] != width:
        image = F.interpolate(image, size=(width // 2, width), mode="area")
    return image[0].clamp(0, 1).contiguous()


def cap_mask(width: int, views: int, worth: float) -> torch.Tensor:
    """A cap whose area is ``worth`` views' share of the sphere (worth/views of it), round
    the view centre the fewest views see; ``worth`` ≥ views: the whole sphere."""
    if worth >= views:
        return torch.ones(width // 2, width, dtype=torch.bool)
    dirs = equirect_directions(width, width // 2, torch.float64)
    cameras = view_layout(views, AnimateConfig().fov_deg, 64)
    centres = view_directions(views)
    centre = centres[views_seeing(cameras, centres).sum(dim=0).argmin()]
    cos_radius = 1.0 - 2.0 * worth / views  # cap area 2π(1 − cos r) = 4π·worth/views
    return (dirs @ centre) >= cos_radius


def build_model(
    full: bool, device: torch.device, dtype: torch.dtype, settings: AnimateConfig, folder: Path
) -> SVDDenoiser:
    """The model in ``folder``, written there first (random weights) if it is not there."""
    if not (folder / "model_index.json").is_file():
        variant = "fp16" if dtype == torch.float16 else None
        print(f"writing the random {'full' if full else 'tiny'} model to {folder}")
        save_random_svd(folder, "full" if full else "tiny", variant=variant)
    return load_svd(folder, settings, device, dtype)


def bench_scene(
    model: SVDDenoiser, settings: AnimateConfig, panorama: torch.Tensor, worth: float
) -> dict[str, Any]:
    moving = cap_mask(panorama.shape[-1], settings.views, worth)
    start = time.perf_counter()
    setup = prepare_panorama(model, settings, panorama, moving, seed=0)
    prepare_s = time.perf_counter() - start
    memory = PeakMemory(model.device)
    calls_before = len(model.unet_call_rows)
    try:
        setup.denoiser.sample(
            setup.condition,
            setup.static,
            settings.frames,
            settings.steps,
            seed=0,
            phase=memory.phase,
        )
    finally:
        memory.close()
    reports = setup.denoiser.reports
    steps = len(reports)
    seconds = {
        name: sum(r.seconds.get(name, 0.0) for r in reports) / steps
        for name in ("project", "unet", "fuse")
    }
    unet_calls = model.unet_call_rows[calls_before:]
    latent = setup.side // model.scale_factor
    return {
        "region_views_worth": worth,
        "moving_fraction": round(float(moving.float().mean()), 4),
        "active_views": len(setup.active),
        "view_size": setup.side,
        "sphere_points": setup.denoiser.footprints.n_points,
        "views_per_batch": setup.denoiser.view_batch,
        "unet_rows_limit": model.unet_rows(settings.frames, latent, latent),
        "unet_batch": max(unet_calls),
        "unet_calls": len(unet_calls),
        "unet_view_evaluations": len(setup.active) * steps * model.guidance_branches,
        "prepare_s": round(prepare_s, 3),
        "step_s": {k: round(v, 4) for k, v in seconds.items()},
        "project_fuse_over_unet": round(
            (seconds["project"] + seconds["fuse"]) / seconds["unet"], 4
        ),
        "step_peak_mib": {k: _mib(memory.peaks.get(k, 0)) for k in ("project", "unet", "fuse")},
        "disagreement_first_last": [
            round(reports[0].disagreement, 4),
            round(reports[-1].disagreement, 4),
        ],
    }


def bench_decode(model: SVDDenoiser, frames: int, width: int) -> dict[str, Any]:
    s = model.scale_factor
    latent = torch.randn(frames, model.latent_channels, width // 2 // s, width // s)
    memory = PeakMemory(model.device)
    try:
        start = time.perf_counter()
        with memory.phase("decode"):
            video = tiled_equirect(
                lambda z: model.decode(z[None])[0],
                latent,
                up=s,
                tile=DECODE_TILE,
                overlap=DECODE_OVERLAP,
            )
        seconds = time.perf_counter() - start
    finally:
        memory.close()
    return {
        "width": width,
        "height": width // 2,
        "frames": frames,
        "tile_latent": DECODE_TILE,
        "overlap_latent": DECODE_OVERLAP,
        "seconds": round(seconds, 3),
        "peak_mib": _mib(memory.peaks["decode"]),
        "output_mib": _mib(video.numel() * 4),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="SVD's full architecture (GPU)")
    parser.add_argument("--width", type=int, help="panorama width (default 512; 4096 --full)")
    parser.add_argument("--frames", type=int, help="L (default 3; 14 --full)")
    parser.add_argument("--steps", type=int, help="denoising steps (default 2; 25 --full)")
    parser.add_argument("--views", type=int, default=20)
    parser.add_argument("--worth", type=float, nargs="+", default=[0.05, 1, 4, 20])
    parser.add_argument(
        "--decode-widths", type=int, nargs="+", help="default 512 1024; 4096 --full"
    )
    parser.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    parser.add_argument(
        "--weights", type=Path, help="diffusers folder to load (written first if missing)"
    )
    parser.add_argument("--json", type=Path, help="output (default bench/out/animate*.json)")
    parser.add_argument(
        "--panorama", default=str(PANORAMA), help="image path, or 'synthetic' (default the lake)"
    )
    args = parser.parse_args()
    full = args.full
    width = args.width or (4096 if full else 512)
    frames = args.frames or (14 if full else 3)
    steps = args.steps or (25 if full else 2)
    decode_widths = args.decode_widths or ([4096] if full else [512, 1024])
    device = resolve_device(args.device)
    dtype = resolve_dtype("auto", device)
    settings = AnimateConfig(frames=frames, steps=steps, views=args.views)
    torch.manual_seed(0)
    with tempfile.TemporaryDirectory(prefix="pano4d-svd-") as scratch:
        folder = args.weights or Path(scratch) / "svd"
        model = build_model(full, device, dtype, settings, folder)
    panorama = load_panorama(args.panorama, width)

    scenes = [bench_scene(model, settings, panorama, worth) for worth in args.worth]
    print(f"{'full SVD' if full else 'tiny SVD'} on {device} ({dtype}), {width}x{width // 2}, "
          f"L={frames}, {steps} steps, {args.views}-view layout")  # fmt: skip
    print(f"{'worth':>5} {'active':>6} {'views':>5} {'rows':>4} {'UNet calls':>10} "
          f"{'view evals':>10} {'project':>9} {'UNet':>9} {'fuse':>9} {'p+f/UNet':>8} "
          f"{'peak proj':>9} {'peak UNet':>9} {'peak fuse':>9}")  # fmt: skip
    for r in scenes:
        t, m = r["step_s"], r["step_peak_mib"]
        print(f"{r['region_views_worth']:>5g} {r['active_views']:>6} {r['views_per_batch']:>5} "
              f"{r['unet_batch']:>4} {r['unet_calls']:>10} {r['unet_view_evaluations']:>10} "
              f"{t['project']:>8.3f}s "
              f"{t['unet']:>8.3f}s {t['fuse']:>8.3f}s {r['project_fuse_over_unet']:>8.3f} "
              f"{m['project']:>7.0f}MB {m['unet']:>7.0f}MB {m['fuse']:>7.0f}MB")  # fmt: skip
    decodes = [bench_decode(model, frames, w) for w in decode_widths]
    print(f"{'decode':>11} {'tiles':>6} {'seconds':>8} {'peak':>9} {'output':>9}")
    for d in decodes:
        tiles = f"{d['tile_latent']}+{d['overlap_latent']}"
        print(f"{d['width']:>5}x{d['height']:<5} {tiles:>6} {d['seconds']:>7.2f}s "
              f"{d['peak_mib']:>7.0f}MB {d['output_mib']:>7.0f}MB")  # fmt: skip

    out = args.json or (
        Path(__file__).resolve().parent / "out" / ("animate_full.json" if full else "animate.json")
    )
    write_json_atomic(
        out,
        {
            "model": "svd-full-random" if full else "svd-tiny-random",
            "device": str(device),
            "gpu": torch.cuda.get_device_name(device) if device.type == "cuda" else None,
            "dtype": str(dtype),
            "panorama": f"{Path(args.panorama).name} at {width}x{width // 2}",
            "frames": frames,
            "steps": steps,
            "views": args.views,
            "memory": "CUDA allocator peak"
            if device.type == "cuda"
            else "RSS increase, sampled 1 ms",
            "torch_threads": torch.get_num_threads(),
            "cpu_count": os.cpu_count(),
            "load_average_1min_at_end": os.getloadavg()[0],
            "machine": platform.platform(),
            "scenes": scenes,
            "decode": decodes,
        },
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
