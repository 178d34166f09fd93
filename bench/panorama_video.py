"""360° frames and the share formats on a trained scene (issue #37's targets).

Measures, on one machine, in one run:
- mono fidelity: the 360° frame at t = 0 from the viewpoint at the working panorama's size
  against the working panorama (frame 0 of the animation, area-downsampled as the lifting
  does): PSNR of the whole frame, of the 1 % of columns each side of the seam and of the top
  and bottom 5 % of rows, beside metrics.json's `training_fit.fit_psnr` (targets: the whole
  within 1 dB of fit_psnr; seam and poles within 1 dB of the whole);
- ODS geometry: single points at a known distance, at several longitudes (the seam too) and
  latitudes, in a 4096-wide top-bottom frame: each eye's centroid against the column ODS
  predicts (longitude φ + ±asin(r / (D cos θ)), r = ipd / 2), error in pixels (target < 1);
- cost: a 4096×2048 mono frame of the scene against a 1920×1080 perspective frame (seconds,
  best of --repeats); a 14-frame 4096×4096 top-bottom stereo video through the command
  line: wall time and peak memory (the child's max RSS);
- exports of t = 0: bytes of SOG, SPZ, compressed ply and .splat against the .ply, each
  read back by a reader that is not its writer (tests/test_share_formats.py) and rendered
  at test cameras against the .ply4d (target ≥ 30 dB; the .ply bit-equal).
Prints a table and writes bench/out/panorama_video.json, and the stereo video's first frame
(1024×1024) as bench/out/lake_stereo_frame.png for the README.

    .venv/bin/python bench/panorama_video.py [--scene DIR/scene.yaml] [--skip-video]
        [--repeats 2] [--json bench/out/panorama_video.json]

Without --scene it trains the README's lake scene (../shared/data/pano_lake.jpg, draft,
≈ 10 min here) into bench/out/lake/ once and reuses it after.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "python"))
sys.path.insert(0, str(ROOT / "tests"))

from test_share_formats import READERS, SUFFIX  # noqa: E402

from pano4d import panorama_video, ply4d, sphere  # noqa: E402
from pano4d.animate.frames import frame_suffix, open_frames  # noqa: E402
from pano4d.camera import Camera  # noqa: E402
from pano4d.config import load_config  # noqa: E402
from pano4d.fsutil import write_json_atomic  # noqa: E402
from pano4d.gaussians import Gaussians  # noqa: E402
from pano4d.metrics import psnr  # noqa: E402
from pano4d.renderer import adapter_info, render  # noqa: E402
from pano4d.resample import equirect_to_perspective  # noqa: E402

LAKE_YAML = """panorama: {panorama}
regions:
  - box: [1950, 1050, 4000, 1350]   # the open water
    motion: {{direction_deg: 0.0, speed: 0.3}}
animate: {{backend: flow, frames: 6}}
preset: draft
"""


def lake(folder: Path) -> Path:
    """The README's lake scene, trained once into ``folder``."""
    yaml = folder / "scene.yaml"
    if not (folder / "output" / "scene.ply4d").is_file():
        folder.mkdir(parents=True, exist_ok=True)
        panorama = ROOT.parent / "shared" / "data" / "pano_lake.jpg"
        yaml.write_text(LAKE_YAML.format(panorama=panorama))
        subprocess.run([sys.executable, "-m", "pano4d.cli", "train", str(yaml)], check=True)
    return yaml


def working_frame0(cfg: Any, size: tuple[int, int]) -> torch.Tensor:
    """Frame 0 of the animation at the working size (W, H), as the lifting read it."""
    boxes = sorted((Path(cfg.output) / "animate").rglob("box.json"))
    frames = open_frames(boxes[0].parent, cfg.animate.frames, frame_suffix(cfg.panorama))
    return frames.area_downsampled(size)[0]


def cube_round_trip(image: torch.Tensor) -> torch.Tensor:
    """``image`` (H, W, 3) through the six cube faces and back, as a mono frame is drawn (each
    face taken from the image by the trainer's own bilinear sampler): the loss of the 360°
    path's one resampling, with no Gaussians in it."""
    height, width = image.shape[:2]
    cams = panorama_video.face_cameras(width, torch.zeros(3))
    faces = [equirect_to_perspective(image.permute(2, 0, 1), cam) for cam in cams]
    return panorama_video.faces_to_equirect(faces, cams, width, height)


def mono_fidelity(
    g: Gaussians, frame0: torch.Tensor, fit_psnr: float, cameras: list[Camera]
) -> dict[str, Any]:
    """The target's figures, and what splits the frame's distance from fit_psnr: the frame
    and the panorama both sampled into the training views (``cameras``: fit_psnr's own
    comparison, made on the 360° frame), the panorama's own loss through the cube faces and
    back (the resampling's ceiling), and the frame against that round trip."""
    height, width = frame0.shape[:2]
    pano = panorama_video.equirect_frame(g, panorama_video.Frame360(width, height), torch.zeros(3))
    got, want = torch.from_numpy(pano), frame0.clamp(0, 1)
    seam = max(1, round(0.01 * width))
    pole = max(1, round(0.05 * height))
    cols = torch.cat([torch.arange(seam), torch.arange(width - seam, width)])
    rows = torch.cat([torch.arange(pole), torch.arange(height - pole, height)])
    whole = psnr(got, want)
    in_views = [
        psnr(equirect_to_perspective(got.permute(2, 0, 1), cam),
             equirect_to_perspective(want.permute(2, 0, 1), cam))
        for cam in cameras
    ]  # fmt: skip
    trip = cube_round_trip(want)
    row = {
        "size": [width, height],
        "psnr_whole": whole,
        "psnr_seam": psnr(got[:, cols], want[:, cols]),
        "psnr_poles": psnr(got[rows], want[rows]),
        "fit_psnr": fit_psnr,
        "psnr_in_training_views": sum(in_views) / len(in_views),
        "round_trip_whole": psnr(trip, want),
        "round_trip_poles": psnr(trip[rows], want[rows]),
        "psnr_against_round_trip": psnr(got, trip),
        "psnr_poles_against_round_trip": psnr(got[rows], trip[rows]),
    }
    row["whole_within_1db_of_fit"] = abs(whole - fit_psnr) <= 1.0
    row["seam_poles_within_1db"] = min(row["psnr_seam"], row["psnr_poles"]) >= whole - 1.0
    return row


def ods_geometry(width: int = 4096, distance: float = 2.0, ipd: float = 0.064) -> dict[str, Any]:
    """Small points at ``distance``; each eye's centroid near where ODS puts it."""
    points = [(lon, lat) for lon in (0.0, 90.0, 179.0, -135.0) for lat in (0.0, 30.0, -40.0)]
    means = torch.tensor([
        [distance * math.cos(math.radians(b)) * math.cos(math.radians(a)),
         -distance * math.cos(math.radians(b)) * math.sin(math.radians(a)),
         distance * math.sin(math.radians(b))] for a, b in points
    ])  # fmt: skip
    n = len(points)
    g = Gaussians(means, torch.full((n, 3), math.log(0.004)),
                  torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1), torch.full((n,), 8.0),
                  torch.full((n, 1, 3), 3.0))  # fmt: skip
    frame = panorama_video.Frame360(width, width, stereo=True, ipd=ipd)
    start = time.perf_counter()
    both = panorama_video.equirect_frame(g, frame, torch.zeros(3))
    seconds = time.perf_counter() - start
    half = width // 2
    errors = []
    for lon, lat in points:
        r = ipd / 2 * float(panorama_video.ipd_fade(math.radians(lat)))
        for eye, side in ((both[:half], +1), (both[half:], -1)):
            phi = math.radians(lon) + side * math.asin(r / (distance * math.cos(math.radians(lat))))
            u0 = (width * (phi / (2 * math.pi) + 0.5)) % width
            v0 = half * (0.5 - math.radians(lat) / math.pi)
            cols = (np.arange(int(u0) - 20, int(u0) + 21)) % width
            rows = np.arange(max(0, int(v0) - 20), min(half, int(v0) + 21))
            light = eye[np.ix_(rows, cols)].sum(-1)
            du = np.arange(int(u0) - 20, int(u0) + 21) + 0.5 - u0
            u_error = float((light * du[None]).sum() / light.sum())
            errors.append(abs(u_error))
    return {"width": width, "distance": distance, "ipd": ipd, "points": n,
            "max_error_px": max(errors), "seconds": seconds,
            "within_a_pixel": max(errors) < 1.0}  # fmt: skip


def best_of(repeats: int, fn: Any) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def cost(g: Gaussians, repeats: int) -> dict[str, Any]:
    frame = panorama_video.Frame360(4096, 2048)
    mono = best_of(repeats, lambda: panorama_video.equirect_frame(g, frame, torch.zeros(3)))
    cam = Camera.from_fov(90, 1920, 1080)
    perspective = best_of(repeats, lambda: render(g, cam))
    return {"mono_4096x2048_s": mono, "perspective_1920x1080_s": perspective,
            "ratio": mono / perspective}  # fmt: skip


def stereo_video(scene: Path, out: Path) -> dict[str, Any]:
    start = time.perf_counter()
    child = subprocess.Popen(
        [sys.executable, "-m", "pano4d.cli", "render", str(scene), "-o", str(out),
         "--projection", "equirect", "--stereo", "top-bottom", "--width", "4096",
         "--height", "4096", "--frames", "14"],
    )  # fmt: skip
    # wait4: this child's own peak memory (RUSAGE_CHILDREN would include the lake's training).
    _, status, usage = os.wait4(child.pid, 0)
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        raise SystemExit(f"the stereo video failed (exit {child.returncode})")
    seconds = time.perf_counter() - start
    peak_kib = usage.ru_maxrss
    # Its first frame, 1024×1024, for the README (docs/lake_stereo.png).
    subprocess.run(
        ["ffmpeg", "-v", "error", "-y", "-i", str(out), "-frames:v", "1", "-vf",
         "scale=1024:1024:flags=area", str(ROOT / "bench" / "out" / "lake_stereo_frame.png")],
        check=True,
    )  # fmt: skip
    return {"frames": 14, "size": [4096, 4096], "seconds": seconds,
            "seconds_per_frame": seconds / 14, "peak_rss_gib": peak_kib / 2**20,
            "bytes": out.stat().st_size}  # fmt: skip


def exports(scene: Path, folder: Path) -> list[dict[str, Any]]:
    source = ply4d.open(scene)
    truth = source.at(0)
    cams = sphere.view_layout(8, 70.0, 512)
    # Ours in the scene's mode; the exports as other viewers draw them, classic.
    wanted = [render(truth, cam, antialiased=source.antialiased).rgb for cam in cams]
    rows = []
    for fmt in ("ply", "compressed-ply", "spz", "sog", "splat"):
        out = folder / f"t0{SUFFIX[fmt]}"
        subprocess.run([sys.executable, "-m", "pano4d.cli", "export", str(scene), str(out),
                        "--format", fmt], check=True)  # fmt: skip
        decoded = READERS[fmt](out)
        got = [psnr(render(decoded, cam).rgb, want) for cam, want in zip(cams, wanted, strict=True)]
        rows.append(
            {
                "format": fmt,
                "bytes": out.stat().st_size,
                "psnr_min": min(got),
                "bit_equal": fmt == "ply"
                and all(torch.equal(decoded.tensors()[k], v) for k, v in truth.tensors().items()),
            }
        )
    ply_bytes = rows[0]["bytes"]
    for row in rows:
        row["of_ply"] = row["bytes"] / ply_bytes
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, help="a trained scene.yaml (default: the lake)")
    parser.add_argument("--skip-video", action="store_true", help="no 14-frame stereo video")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--json", type=Path, default=ROOT / "bench" / "out" / "panorama_video.json")
    args = parser.parse_args()
    yaml = args.scene or lake(ROOT / "bench" / "out" / "lake")
    cfg = load_config(yaml)
    output = Path(cfg.output)
    scene = output / "scene.ply4d"
    metrics = json.loads((output / "metrics.json").read_text())
    fit = metrics["training_fit"]
    g = ply4d.open(scene).at(0)
    row: dict[str, Any] = {"machine": platform.node(), "adapter": adapter_info(),
                           "date": time.strftime("%Y-%m-%d"), "scene": str(yaml),
                           "gaussians_t0": len(g)}  # fmt: skip
    frame0 = working_frame0(cfg, tuple(fit["working_size"]))
    cameras = sphere.view_layout(cfg.lift.views, cfg.lift.fov_deg, metrics["knobs"]["view_size"])
    row["mono"] = mono_fidelity(g, frame0, fit["fit_psnr"], cameras)
    row["ods"] = ods_geometry()
    row["cost"] = cost(g, args.repeats)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=args.json.parent) as tmp:
        row["exports"] = exports(scene, Path(tmp))
        if not args.skip_video:
            row["stereo_video"] = stereo_video(scene, Path(tmp) / "stereo.mp4")
    write_json_atomic(args.json, row)

    m, o, c = row["mono"], row["ods"], row["cost"]
    print(f"pano4d 360° frames and exports — {row['scene']} ({len(g):,} Gaussians at t = 0)")
    print(
        f"  mono {m['size'][0]}x{m['size'][1]}: PSNR {m['psnr_whole']:.2f} dB whole, "
        f"{m['psnr_seam']:.2f} seam, {m['psnr_poles']:.2f} poles; fit_psnr {m['fit_psnr']:.2f}"
        f" (whole within 1 dB: {m['whole_within_1db_of_fit']}, seam/poles: "
        f"{m['seam_poles_within_1db']})"
    )
    print(
        f"    in the training views {m['psnr_in_training_views']:.2f} dB; the panorama through "
        f"the cube faces and back {m['round_trip_whole']:.2f} dB ({m['round_trip_poles']:.2f} "
        f"poles); the frame against that round trip {m['psnr_against_round_trip']:.2f} dB "
        f"({m['psnr_poles_against_round_trip']:.2f} poles)"
    )
    print(
        f"  ODS {o['width']} wide: {o['points']} points at {o['distance']}, max error "
        f"{o['max_error_px']:.3f} px ({o['seconds']:.0f} s)"
    )
    print(
        f"  cost: mono 4096x2048 {c['mono_4096x2048_s']:.2f} s, perspective 1920x1080 "
        f"{c['perspective_1920x1080_s']:.2f} s: {c['ratio']:.1f}x"
    )
    if "stereo_video" in row:
        v = row["stereo_video"]
        print(
            f"  stereo video 14 frames 4096x4096: {v['seconds']:.0f} s "
            f"({v['seconds_per_frame']:.1f} s a frame), peak {v['peak_rss_gib']:.2f} GiB"
        )
    print(f"  {'format':<15}{'bytes':>12}{'of .ply':>9}{'min PSNR':>10}")
    for e in row["exports"]:
        exact = " bit-equal" if e["bit_equal"] else ""
        print(
            f"  {e['format']:<15}{e['bytes']:>12,}{e['of_ply']:>9.3f}{e['psnr_min']:>10.2f}{exact}"
        )
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
