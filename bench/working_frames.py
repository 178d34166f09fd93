"""The animating phase makes what the lifting reads: `pano4d train` and `pano4d animate` on
large panoramas, this tree against a base commit, side by side in one run.

Cases: the lake (``shared/data/pano_lake.jpg``) resampled to 6144×3072 and 8192×4096
(bicubic, made once into bench/out/stand-ins/), a box over its water and sky (≈ 40 % of the
sphere moving with the 3° margin), draft, 14 frames, the ``flow`` animator. Variants:
``base`` and ``after``, two commits' python/ exported with this checkout's compiled
extension (the issue's code touches no Rust; edits made while the bench runs do not leak
in); each command runs in its own process, one variant after the other, nothing else
running.

Per case and variant:
* ``pano4d train``: wall time, peak memory (``/usr/bin/time``'s maximum resident set),
  the stage seconds of metrics.json and the wall time outside them;
* with ``--animate``, ``pano4d animate`` alone (the full-resolution store): wall time and
  peak memory.
Then the frames, as the issue's targets read them:
* working-size frames (``after``'s store at the working size) against ``base``'s
  full-resolution frames area-downsampled with ``prepare``'s filter: pixels one working
  pixel or more from the blend bit-identical, PSNR of the moving region in every frame;
* with ``--animate``, ``after``'s full-resolution frames against ``base``'s: bit-identical
  outside the blend, PSNR of the moving region in every frame.
Prints a table and writes bench/out/working_frames.json.

    .venv/bin/python bench/working_frames.py [--base fbdcae1] [--after HEAD] [--widths 6144 8192]
        [--frames 14] [--animate]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "python"))

# A commit's python/ with this checkout's extension (bench/animate_frames.py's helper).
from animate_frames import commit_sources  # noqa: E402

from pano4d.animate.frames import FrameStore  # noqa: E402
from pano4d.animate.pipeline import animation_input  # noqa: E402
from pano4d.config import load_config  # noqa: E402
from pano4d.images import read_panorama, write_image  # noqa: E402
from pano4d.lift.pipeline import working_panorama  # noqa: E402
from pano4d.metrics import psnr_of_mse  # noqa: E402

SHARED = Path(os.environ.get("PANO4D_SHARED", ROOT.parent / "shared"))
LAKE = SHARED / "data" / "pano_lake.jpg"
STAND_INS = ROOT / "bench" / "out" / "stand-ins"
# The water and the sky of the lake, as fractions of the width and height.
BOX = (0.464, 0.0, 0.999, 0.684)


def stand_in(width: int) -> Path:
    """The lake resampled to width × width/2 (JPEG, quality 95), made once."""
    path = STAND_INS / f"lake{width}.jpg"
    if not path.is_file():
        lake = torch.from_numpy(read_panorama(LAKE)).permute(2, 0, 1)[None]
        resized = F.interpolate(lake, size=(width // 2, width), mode="bicubic", align_corners=False)
        write_image(path, resized.clamp(0, 1)[0].permute(1, 2, 0).numpy())
    return path


def scene(folder: Path, width: int, frames: int) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    u0, v0, u1, v1 = (round(f * n) for f, n in zip(BOX, (width, width // 2) * 2, strict=True))
    path = folder / "scene.yaml"
    path.write_text(
        f"panorama: {stand_in(width)}\n"
        f"regions:\n  - box: [{u0}, {v0}, {u1}, {v1}]   # the water and the sky\n"
        "    motion: {direction_deg: 0.0, speed: 0.3}\n"
        f"animate: {{backend: flow, frames: {frames}}}\npreset: draft\noutput: out\n"
    )
    return path


def timed(sources: Path, folder: Path, *args: str) -> dict[str, Any]:
    """``pano4d ARGS`` in ``folder`` with ``sources`` first on the path: wall seconds and
    peak resident memory."""
    env = {**os.environ, "PYTHONPATH": str(sources)}
    report = folder / "time.txt"
    start = time.perf_counter()
    done = subprocess.run(
        ["/usr/bin/time", "-f", "%M", "-o", str(report), sys.executable, "-m", "pano4d.cli", *args],
        cwd=folder,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{sources}: pano4d {' '.join(args)} failed:\n{done.stderr[-3000:]}")
    peak_kb = int(report.read_text().split()[-1])
    return {"wall_s": wall, "peak_gb": peak_kb / 1e6, "load_1min": round(os.getloadavg()[0], 2)}


def moving_psnr(a: torch.Tensor, b: torch.Tensor, moving: torch.Tensor) -> list[float]:
    """PSNR of a against b (L, H, W, 3) over the pixels of ``moving`` (H, W), per frame."""
    return [
        psnr_of_mse(float(((x[moving] - y[moving]) ** 2).mean())) for x, y in zip(a, b, strict=True)
    ]


def working_against_full(base_out: Path, after_out: Path, cfg_yaml: Path) -> dict[str, Any]:
    """The target's comparison at the working size (module docstring)."""
    cfg = load_config(cfg_yaml)
    size = working_panorama(cfg)[1]
    frames = cfg.animate.frames
    full = FrameStore(base_out / "animate" / "moving", frames, ".png").area_downsampled(size)
    working = FrameStore(
        after_out / "animate" / f"{size[0]}x{size[1]}" / "moving", frames, ".exr"
    ).area_downsampled(size)
    blend = animation_input(cfg, size).regions.blend > 0
    near = F.max_pool2d(blend[None, None].float(), 3, stride=1, padding=1)[0, 0] > 0
    # Columns wrap: a blend pixel at u = 0 has a neighbour at u = W − 1.
    near |= torch.roll(near, 1, dims=1) | torch.roll(near, -1, dims=1)
    far = ~near
    differing = int((working[:, far] != full[:, far]).any(dim=-1).sum())
    return {
        "working_size": list(size),
        "far_static_pixels": int(far.sum()) * frames,
        "far_static_differing": differing,
        "moving_psnr_db": moving_psnr(working, full, blend),
    }


def full_against_full(base_out: Path, after_out: Path, cfg_yaml: Path) -> dict[str, Any]:
    """``after``'s full-resolution frames against ``base``'s (module docstring)."""
    cfg = load_config(cfg_yaml)
    base = FrameStore(base_out / "animate" / "moving", cfg.animate.frames, ".png")
    after = FrameStore(after_out / "animate" / "moving", cfg.animate.frames, ".png")
    blend = animation_input(cfg).regions.blend > 0
    differing, psnrs = 0, []
    for old, new in zip(base.frames(), after.frames(), strict=True):
        x, y = torch.from_numpy(old), torch.from_numpy(new)
        differing += int((x[~blend] != y[~blend]).any(dim=-1).sum())
        psnrs.append(psnr_of_mse(float(((x[blend] - y[blend]) ** 2).mean())))
    return {"static_differing": differing, "moving_psnr_db": psnrs}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--base", default="fbdcae1")
    parser.add_argument("--after", default="HEAD")
    parser.add_argument("--widths", type=int, nargs="+", default=[6144, 8192])
    parser.add_argument("--frames", type=int, default=14)
    parser.add_argument("--animate", action="store_true", help="also `pano4d animate` alone")
    parser.add_argument("--json", type=Path, default=ROOT / "bench" / "out" / "working_frames.json")
    args = parser.parse_args()

    work = Path(tempfile.mkdtemp(prefix="working-frames-", dir=ROOT / "bench" / "out"))
    after = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", args.after],
        check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip
    variants = {"base": commit_sources(args.base, work), "after": commit_sources(after, work)}
    rows: list[dict[str, Any]] = []
    print(
        f"{'case':>10} {'variant':>7} {'command':>8} {'wall s':>7} {'peak GB':>8} "
        f"{'animate':>8} {'depth+al':>8} {'static':>7} {'dynamic':>8} {'export':>7} "
        f"{'outside':>8} {'load':>5}",
        flush=True,
    )
    comparisons: dict[str, Any] = {}
    for width in args.widths:
        case = f"lake{width}"
        outputs: dict[str, Path] = {}
        for variant, sources in variants.items():
            folder = work / case / variant
            yaml = scene(folder, width, args.frames)
            row = {"case": case, "variant": variant, "command": "train"}
            row.update(timed(sources, folder, "train", str(yaml)))
            metrics = json.loads((folder / "out" / "metrics.json").read_text())
            stages = metrics["timings_s"]
            row["stages_s"] = stages
            row["outside_stages_s"] = row["wall_s"] - sum(stages.values())
            rows.append(row)
            outputs[variant] = folder / "out"
            print(
                f"{case:>10} {variant:>7} {'train':>8} {row['wall_s']:7.1f} "
                f"{row['peak_gb']:8.2f} {stages['animate']:8.1f} "
                f"{stages['depth'] + stages['align']:8.1f} {stages['static']:7.1f} "
                f"{stages['dynamic']:8.1f} {stages['export']:7.1f} "
                f"{row['outside_stages_s']:8.1f} {row['load_1min']:5.1f}",
                flush=True,
            )
        yaml = work / case / "base" / "scene.yaml"
        comparison = working_against_full(outputs["base"], outputs["after"], yaml)
        if args.animate:
            animated: dict[str, Path] = {}
            for variant, sources in variants.items():
                folder = work / case / f"{variant}-animate"
                yaml = scene(folder, width, args.frames)
                row = {"case": case, "variant": variant, "command": "animate"}
                row.update(timed(sources, folder, "animate", str(yaml)))
                rows.append(row)
                animated[variant] = folder / "out"
                print(
                    f"{case:>10} {variant:>7} {'animate':>8} {row['wall_s']:7.1f} "
                    f"{row['peak_gb']:8.2f} {'':>48} {row['load_1min']:5.1f}",
                    flush=True,
                )
            comparison["full_resolution"] = full_against_full(
                animated["base"], animated["after"], yaml
            )
        comparisons[case] = comparison
        worst = min(comparison["moving_psnr_db"])
        print(
            f"{case}: working-size frames against the base's downsampled: "
            f"{comparison['far_static_differing']} of {comparison['far_static_pixels']} "
            f"far static pixels differ, moving region ≥ {worst:.1f} dB",
            flush=True,
        )
        if "full_resolution" in comparison:
            whole = comparison["full_resolution"]
            print(
                f"{case}: full resolution against the base: {whole['static_differing']} "
                f"static pixels differ, moving region ≥ {min(whole['moving_psnr_db']):.1f} dB"
            )
        for command in ("train", "animate"):
            pair = {r["variant"]: r for r in rows if r["case"] == case and r["command"] == command}
            if len(pair) == 2:
                ratio = pair["after"]["wall_s"] / pair["base"]["wall_s"]
                line = f"{case} {command}: after / base wall {ratio:.3f}"
                if command == "train":
                    animate_ratio = (
                        pair["after"]["stages_s"]["animate"] / pair["base"]["stages_s"]["animate"]
                    )
                    line += f", animating phase {animate_ratio:.3f}"
                line += f", peak memory {pair['after']['peak_gb'] / pair['base']['peak_gb']:.2f}"
                print(line, flush=True)
    record = {
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "base": args.base,
        "after": after,
        "frames": args.frames,
        "rows": rows,
        "frames_compared": comparisons,
        "torch_threads": torch.get_num_threads(),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(record, indent=2))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
