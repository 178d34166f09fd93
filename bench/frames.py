"""What the dynamic sets cost against the static set, per frame count, before and after a change.

For every case (a scene, a preset, a frame count) each variant of the code trains the scene
in a subprocess and the parent measures all variants the same way: the stage times
(metrics.json), the optimisation steps each stage took (losses.json), a dynamic step's cost
relative to a static one next to the moving share of the views' pixels, and — on the
synthetic kinds, where the true animation feeds the lifting (as bench/quality.py does) —
the moving region's PSNR in every frame against ground truth (``region_quality``): four
cameras, the same at every time, displaced by 1 % of the median scene depth and looking at
what moves, ray-cast by the scene's own world, PSNR over the pixels that see something
moving; the same half-way between the trained timestamps (t + 0.5), and the moving
region's temporal error and flicker beside the truth's own; and the bytes of the .ply4d's
dynamic sections. The lake (no ground
truth) is timed with the real animator; with ``--flow`` the synthetic kinds are animated by
it too (frame 0 under the kind's mask), to compare two animating paths on the same truth.
``--standin`` adds issue #38's stand-in for a large real panorama with much of it moving:
bench/working_frames.py's (the lake resampled to 6144×3072, a box over its water and sky),
timed as the lake is.

Variants: ``after`` is this tree; ``--base REV`` adds ``before``, REV's code in a git
worktree under bench/out/frames/ (its own extension built there when REV's Rust differs);
each ``--setting NAME=JSON`` adds this tree with those knobs set (a point of a knob's
speed/accuracy trade, e.g. ``later 0.2={"later_iteration_share": 0.2}``); each case is run
by every variant, one after the other, in one run. Prints a table, writes
bench/out/frames.json and bench/out/frames.png (moving-region PSNR against minutes of
lifting, a colour per variant, a point per case, a case's points joined).

    .venv/bin/python bench/frames.py [--base REV] [--kinds landscape room] [--frames 2 7 14]
        [--width 2048] [--preset draft] [--lake] [--standin] [--balanced-step 14]
        [--overrides JSON] [--setting NAME=JSON ...] [--json bench/out/frames.json] [--keep]

``--balanced-step L``: balanced at 1024 wide with L frames and ``--balanced-iterations``
steps per optimisation (the preset's step count would not fit this machine): the cost of a
step of each stage, from which a full run's time is estimated.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import platform
import shutil
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "bench" / "out"
# A child process runs one variant's code: PANO4D_PYTHON names its package folder.
sys.path.insert(0, os.environ.get("PANO4D_PYTHON", str(REPO / "python")))

import numpy as np  # noqa: E402
import torch  # noqa: E402

LAKE = Path(os.environ.get("PANO4D_SHARED", REPO.parent / "shared")) / "data" / "pano_lake.jpg"
LAKE_BOX = [1950, 1050, 4000, 1350]  # README's "A real panorama": the open water
STANDIN_WIDTH = 6144  # the stand-in's size (bench/working_frames.py makes it)
# The cases without ground truth: the real animator, timed only
REAL_KINDS = ("lake", "standin")
CAMERAS_PER_FRAME = 4
CAMERA_SIZE = 128
CAMERA_FOV_DEG = 60.0
DISPLACEMENT = 0.01  # of the median scene depth, as the 1 % novel views


# --- the child: one variant trains one case ---------------------------------------------------
def train_case(case: dict[str, Any]) -> None:
    """Train ``case`` with the code on sys.path (the variant's) and leave its files in
    ``case["output"]``."""
    from pano4d.config import load_config
    from pano4d.train import run_train

    output = Path(case["output"])
    if output.exists():
        shutil.rmtree(output)
    cfg = load_config(Path(case["scene"]))
    update: dict[str, Any] = {"preset": case["preset"], "output": output}
    if case["overrides"]:
        update["overrides"] = case["overrides"]
    animate = {"frames": case["frames"]}
    if case["kind"] not in REAL_KINDS:
        root = Path(case["scene"]).parent
        if case.get("flow"):  # the flow animator on frame 0 under the kind's mask
            animate["backend"] = "flow"
        else:  # the true animation
            frames = sorted((root / "gt" / "frames").glob("*.png"))[: case["frames"]]
            (output / "animate" / "frames").mkdir(parents=True)
            for f in frames:
                shutil.copy(f, output / "animate" / "frames" / f.name)
        update["depth"] = cfg.depth.model_copy(
            update={"backend": "file", "path": root / "depth.exr"}
        )
    update["animate"] = cfg.animate.model_copy(update=animate)
    run_train(cfg.model_copy(update=update), progress=False)


# --- the parent -------------------------------------------------------------------------------
def synth_scene(kind: str, width: int, frames: int, seed: int) -> Path:
    """A cached `pano4d synth` scene with ``frames`` true frames; its scene.yaml."""
    from pano4d import synth

    root = OUT / "frames" / "scenes" / f"{kind}_w{width}_l{frames}_s{seed}"
    if not (root / "scene.yaml").is_file():
        scene = synth.make_scene(seed, width, width // 2, frames, views=0, kind=kind)
        synth.write_scene(root, scene)
    return root / "scene.yaml"


def lake_scene(frames: int) -> Path:
    root = OUT / "frames" / "scenes" / "lake"
    root.mkdir(parents=True, exist_ok=True)
    path = root / "scene.yaml"
    path.write_text(
        f"panorama: {LAKE}\n"
        f"regions:\n  - box: {LAKE_BOX}\n    motion: {{direction_deg: 0.0, speed: 0.3}}\n"
        f"animate: {{backend: flow, frames: {frames}}}\npreset: draft\n"
    )
    return path


class Variant:
    """One version of the code: its package folder and extension."""

    def __init__(self, name: str, python: Path, overrides: dict[str, Any] | None = None) -> None:
        # overrides: knobs this variant sets on top of the case's (``--setting``)
        self.name, self.python, self.overrides = name, python, overrides or {}

    @classmethod
    def base(cls, rev: str) -> Variant:
        """REV's code in a worktree, with its own extension when REV's Rust differs."""
        tree = OUT / "frames" / f"base-{rev}"
        if not tree.exists():
            git = ["git", "-C", str(REPO)]
            subprocess.run([*git, "worktree", "add", "--detach", str(tree), rev], check=True)
        python = tree / "python"
        same_rust = subprocess.run(
            ["git", "-C", str(REPO), "diff", "--quiet", rev, "--", "crates", "Cargo.lock"]
        ).returncode == 0
        built = list((REPO / "python" / "pano4d").glob("_core*.so"))
        if not built:
            raise SystemExit("error: build the extension first (make setup)")
        target = python / "pano4d" / built[0].name
        if same_rust:
            shutil.copy(built[0], target)
        elif not target.exists():
            env = {**os.environ, "CARGO_TARGET_DIR": str(OUT / "frames" / "target-base")}
            subprocess.run(
                ["cargo", "build", "--release", "--locked", "-p", "splat-core",
                 "--features", "python", "--lib"], cwd=tree, env=env, check=True,
            )  # fmt: skip
            shutil.copy(OUT / "frames" / "target-base" / "release" / "libsplat_core.so", target)
        return cls("before", python)

    def train(self, case: dict[str, Any]) -> float:
        env = {**os.environ, "PANO4D_PYTHON": str(self.python), "PYTHONPATH": str(self.python)}
        case = {**case, "overrides": {**case["overrides"], **self.overrides}}
        start = time.perf_counter()
        subprocess.run(
            [sys.executable, __file__, "--child", json.dumps(case)], env=env, check=True
        )
        return time.perf_counter() - start


def steps_taken(output: Path) -> dict[str, int]:
    """Optimisation steps per stage, from losses.json (each optimisation's last record)."""
    data = json.loads((output / "losses.json").read_text())
    steps = {"static": 0, "dynamic": 0}
    for opt in data["optimisations"]:
        last = int(max((r["step"] for r in opt["losses"]), default=0))
        steps["static" if opt["name"] == "static" else "dynamic"] += last
    return steps


def window_share(output: Path) -> float:
    """The share of the views' pixels a dynamic step rendered (lift/windows.py), mean over
    the timestamps; 1 where whole views were rendered (code before the windows, or the knob
    ``dynamic_windows`` off)."""
    data = json.loads((output / "losses.json").read_text())
    shares = [float(opt.get("window_share", 1.0)) for opt in data["optimisations"]
              if opt["name"] != "static"]  # fmt: skip
    return float(np.mean(shares)) if shares else 1.0


def moving_share(scene_yaml: Path, output: Path) -> float:
    """Moving pixels over all pixels of the views that see motion (what a dynamic step
    renders today, against what can change)."""
    from pano4d.config import load_config
    from pano4d.images import read_mask
    from pano4d.resample import equirect_to_perspective
    from pano4d.sphere import view_layout

    metrics = json.loads((output / "metrics.json").read_text())
    cfg = load_config(scene_yaml)
    w, h = metrics["working_size"]
    mask_path = scene_yaml.parent / "mask.png"
    if mask_path.is_file():
        mask = torch.from_numpy(read_mask(mask_path, w, h)).float()
    else:  # regions are in the panorama's pixels: its size, then the working size's area
        from pano4d.images import image_size
        from pano4d.regions import moving_mask

        full = moving_mask(cfg, *image_size(cfg.panorama)).float()
        mask = torch.nn.functional.interpolate(full[None, None], size=(h, w), mode="area")[0, 0]
    size = int(metrics["knobs"]["view_size"])
    shares = []
    for cam in view_layout(cfg.lift.views, cfg.lift.fov_deg, size):
        inside = equirect_to_perspective(mask[None], cam)[0] > 0.5
        if inside.any():
            shares.append(float(inside.float().mean()))
    return float(np.mean(shares)) if shares else 0.0


def region_quality(kind: str, seed: int, frames: int, scene: Any) -> dict[str, Any]:
    """Against ground truth, through CAMERAS_PER_FRAME cameras that see what moves (the same
    cameras at every time): per frame, PSNR over the moving pixels and over the static ones;
    per frame t, the moving pixels' PSNR at t + 0.5 (between two trained timestamps: a
    version-1 scene shows t there, a spacetime one its functions at t + 0.5); and over the
    loop, the moving pixels' temporal error, mean |(R₍t+1₎ − R₍t₎) − (G₍t+1₎ − G₍t₎)|, and
    flicker, mean |R₍t+1₎ − R₍t₎|, beside the ground truth's own, mean |G₍t+1₎ − G₍t₎|.
    ``scene``: a ``ply4d.Scene4D``, read at any real time (``Scene4D.at``)."""
    from pano4d.camera import Camera
    from pano4d.metrics import psnr
    from pano4d.renderer import render
    from pano4d.sphere import equirect_directions
    from pano4d.synth.scene import SCENE_KINDS
    from pano4d.synth.views import median_scene_depth, render_view

    world = SCENE_KINDS[kind](seed, frames)
    median = median_scene_depth(world)
    gen = torch.Generator().manual_seed(seed + 4242)
    # Directions that see what moves: the moving pixels of a small panorama.
    dirs = equirect_directions(256, 128).view(-1, 3)
    moving_dirs = dirs[world.moves(world.cast(torch.zeros(3), dirs).label)]
    cameras, moving = [], []
    for _ in range(CAMERAS_PER_FRAME):
        forward = moving_dirs[int(torch.randint(len(moving_dirs), (), generator=gen))]
        offset = torch.nn.functional.normalize(torch.randn(3, generator=gen), dim=0)
        position = (offset * DISPLACEMENT * median).tolist()
        cam = Camera.from_fov(CAMERA_FOV_DEG, CAMERA_SIZE, CAMERA_SIZE, position, forward.tolist())
        hits = world.cast(cam.position.to(torch.float32), cam.world_directions().reshape(-1, 3))
        cameras.append(cam)
        moving.append(world.moves(hits.label).view(CAMERA_SIZE, CAMERA_SIZE))

    def pair(t: float) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """(render, truth) per camera at time t."""
        with torch.no_grad():
            g = scene.at(t)
            return [
                (render(g, cam, antialiased=scene.antialiased).rgb.clamp(0, 1).cpu(),
                 render_view(world, cam, t)[0])
                for cam in cameras
            ]  # fmt: skip

    def mean_psnr(images: list[tuple[torch.Tensor, torch.Tensor]], inside: bool) -> float:
        values = [
            psnr(rgb[m if inside else ~m], truth[m if inside else ~m])
            for (rgb, truth), m in zip(images, moving, strict=True)
            if (m.any() if inside else not m.all())
        ]
        return float(np.mean(values)) if values else math.nan

    at_frames = [pair(float(t)) for t in range(frames)]
    halfway = [mean_psnr(pair(t + 0.5), True) for t in range(frames)]
    temporal, flicker, truth_flicker = [], [], []
    for t in range(frames):
        now, later = at_frames[t], at_frames[(t + 1) % frames]
        for (r0, g0), (r1, g1), m in zip(now, later, moving, strict=True):
            if m.any():
                temporal.append(float(((r1 - r0) - (g1 - g0))[m].abs().mean()))
                flicker.append(float((r1 - r0)[m].abs().mean()))
                truth_flicker.append(float((g1 - g0)[m].abs().mean()))
    return {
        "moving_psnr": [mean_psnr(images, True) for images in at_frames],
        "static_psnr": [mean_psnr(images, False) for images in at_frames],
        "halfway_psnr": halfway,
        "temporal_error": float(np.mean(temporal)) if temporal else math.nan,
        "flicker": float(np.mean(flicker)) if flicker else math.nan,
        "truth_flicker": float(np.mean(truth_flicker)) if truth_flicker else math.nan,
    }


def dynamic_bytes(path: Path) -> int:
    """Bytes of a .ply4d's dynamic sections, from its section table (docs/ply4d.md)."""
    with path.open("rb") as f:
        preamble = f.read(32)
        header_len, sections = struct.unpack_from("<II", preamble, 12)
        f.seek(32 + header_len)
        table = f.read(40 * sections)
    entries = [struct.unpack_from("<IIQQ", table, 40 * i) for i in range(sections)]
    return sum(length for kind, _, _, length in entries if kind == 1)


def measure(variant: Variant, case: dict[str, Any], keep: bool) -> dict[str, Any]:
    output = Path(case["output"])
    # --keep: a finished run of this variant and case is measured again, not retrained
    # (its wall time is then the sum of its stages).
    if keep and (output / "metrics.json").is_file():
        wall = float(sum(json.loads((output / "metrics.json").read_text())["timings_s"].values()))
    else:
        wall = variant.train(case)
    metrics = json.loads((output / "metrics.json").read_text())
    timings = metrics["timings_s"]
    steps = steps_taken(output)
    per_step = {
        stage: timings[stage] / steps[stage] if steps[stage] else None
        for stage in ("static", "dynamic")
    }
    row = {
        "variant": variant.name,
        "case": case["name"],
        "wall_s": wall,
        "timings_s": timings,
        "steps": steps,
        "per_step_s": per_step,
        "dynamic_over_static": timings["dynamic"] / max(timings["static"], 1e-9),
        "step_ratio": (per_step["dynamic"] / per_step["static"])
        if per_step["dynamic"] and per_step["static"] else None,
        "moving_share": moving_share(Path(case["scene"]), output),
        "window_share": window_share(output),
        "gaussians": metrics["gaussians"],
    }
    row["dynamic_bytes"] = dynamic_bytes(output / "scene.ply4d")
    if case["kind"] not in REAL_KINDS:
        from pano4d import ply4d

        scene = ply4d.read(output / "scene.ply4d")
        row.update(region_quality(case["kind"], case["seed"], case["frames"], scene))
    return row


def plot(path: Path, rows: list[dict[str, Any]]) -> None:
    """Moving-region PSNR (mean over frames) against minutes of lifting (static + dynamic),
    one colour per variant, a point per case; a case's points joined by a line in order of
    minutes: the speed/accuracy trade of the variants (settings of a knob) on one scene."""
    import OpenImageIO as oiio

    from pano4d.images import write_image

    points = [(r["variant"], (r["timings_s"]["static"] + r["timings_s"]["dynamic"]) / 60,
               float(np.nanmean(r["moving_psnr"])), r["case"])
              for r in rows if r.get("moving_psnr")]  # fmt: skip
    if not points:
        return
    w, h, m = 960, 480, 70
    buf = oiio.ImageBuf(oiio.ImageSpec(w, h, 3, "float"))
    oiio.ImageBufAlgo.fill(buf, [0.08, 0.08, 0.09])
    xs, ys = [p[1] for p in points], [p[2] for p in points]
    x_hi = max(xs) * 1.1
    y_lo, y_hi = math.floor(min(ys)) - 1, math.ceil(max(ys)) + 1
    palette = [[1.0, 0.6, 0.3], [0.4, 0.8, 1.0], [0.5, 0.9, 0.4], [0.9, 0.5, 0.9],
               [1.0, 0.9, 0.3], [0.6, 0.6, 1.0]]  # fmt: skip
    names = list(dict.fromkeys(p[0] for p in points))
    colours = {name: palette[i % len(palette)] for i, name in enumerate(names)}
    grey = [0.6, 0.6, 0.6]

    def at(x: float, y: float) -> tuple[int, int]:
        fy = (y - y_lo) / (y_hi - y_lo)
        return round(m + (w - 2 * m) * x / x_hi), round(h - m - (h - 2 * m) * fy)

    oiio.ImageBufAlgo.render_box(buf, m, m, w - m, h - m, grey)
    oiio.ImageBufAlgo.render_text(buf, m, 30, "moving-region PSNR (dB) against lifting minutes",
                                  16, "", grey)  # fmt: skip
    for tick in range(5):
        x = x_hi * tick / 4
        px = at(x, y_lo)[0] - 10
        oiio.ImageBufAlgo.render_text(buf, px, h - m + 22, f"{x:.1f}", 14, "", grey)
    for y in range(y_lo, y_hi + 1, max(1, (y_hi - y_lo) // 5)):
        oiio.ImageBufAlgo.render_text(buf, 10, at(0, y)[1] + 5, f"{y}", 14, "", grey)
    for case in dict.fromkeys(p[3] for p in points):  # the case's name above its first point
        line = sorted((x, y) for _, x, y, c in points if c == case)
        for (x0, y0), (x1, y1) in itertools.pairwise(line):
            oiio.ImageBufAlgo.render_line(buf, *at(x0, y0), *at(x1, y1), grey)
        px, py = at(*line[0])
        oiio.ImageBufAlgo.render_text(buf, px - 20, py - 12, case, 12, "", grey)
    for variant, x, y, _ in points:
        px, py = at(x, y)
        colour = colours[variant]
        oiio.ImageBufAlgo.render_box(buf, px - 4, py - 4, px + 4, py + 4, colour, fill=True)
    legend = m
    for variant, colour in colours.items():
        oiio.ImageBufAlgo.render_text(buf, legend, h - 12, variant, 14, "", colour)
        legend += 12 + 9 * len(variant)
    pixels = buf.get_pixels(oiio.FLOAT).reshape(h, w, 3)
    write_image(path, np.ascontiguousarray(pixels))


def cases(args: argparse.Namespace) -> list[dict[str, Any]]:
    overrides = json.loads(args.overrides) if args.overrides else {}
    out = []
    for kind in args.kinds:
        for frames in args.frames:
            scene = synth_scene(kind, args.width, max(args.frames), args.seed)
            name = f"{kind} {args.preset} w{args.width} L{frames}{' flow' if args.flow else ''}"
            out.append({"name": name, "kind": kind, "flow": args.flow,
                        "scene": str(scene), "preset": args.preset, "frames": frames,
                        "seed": args.seed, "overrides": overrides})  # fmt: skip
    if args.balanced_step:
        frames = args.balanced_step
        scene = synth_scene("landscape", 1024, frames, args.seed)
        steps = {"gaussian_iterations": args.balanced_iterations, **overrides}
        name = f"landscape balanced w1024 L{frames} ({args.balanced_iterations} steps)"
        out.append({"name": name,
                    "kind": "landscape", "scene": str(scene), "preset": "balanced",
                    "frames": frames, "seed": args.seed, "overrides": steps})  # fmt: skip
    if args.lake:
        for frames in args.frames:
            out.append({"name": f"lake draft L{frames}", "kind": "lake",
                        "scene": str(lake_scene(frames)), "preset": "draft", "frames": frames,
                        "seed": 0, "overrides": overrides})  # fmt: skip
    if args.standin:
        from working_frames import scene as stand_in_scene

        for frames in args.frames:
            folder = OUT / "frames" / "scenes" / f"standin_l{frames}"
            scene = stand_in_scene(folder, STANDIN_WIDTH, frames)
            out.append({"name": f"standin draft L{frames}", "kind": "standin",
                        "scene": str(scene), "preset": "draft", "frames": frames,
                        "seed": 0, "overrides": overrides})  # fmt: skip
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--base", help="also run REV's code (the 'before' variant)")
    parser.add_argument("--kinds", nargs="*", default=["landscape", "room"])
    parser.add_argument("--frames", nargs="+", type=int, default=[2, 7, 14])
    parser.add_argument("--width", type=int, default=2048)
    parser.add_argument("--preset", default="draft")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--lake", action="store_true", help="also the lake (real animator)")
    parser.add_argument("--standin", action="store_true",
                        help="also the lake at 6144x3072, its water and sky moving")
    parser.add_argument("--flow", action="store_true",
                        help="synthetic kinds animated by flow from frame 0 under their mask "
                        "(moving-region PSNR then against a truth flow does not make)")  # fmt: skip
    parser.add_argument("--balanced-step", type=int, default=0, metavar="L")
    parser.add_argument("--balanced-iterations", type=int, default=100)
    parser.add_argument("--overrides", default="", help="JSON object of preset knobs")
    parser.add_argument("--setting", action="append", default=[], metavar="NAME=JSON",
                        help="also run this tree with these knobs, as variant NAME")
    parser.add_argument("--json", type=Path, default=OUT / "frames.json")
    parser.add_argument("--keep", action="store_true",
                        help="measure finished runs again instead of retraining them")
    args = parser.parse_args()
    if args.child:
        train_case(json.loads(args.child))
        return

    variants = [Variant("after", REPO / "python")]
    for setting in args.setting:
        name, _, knobs = setting.partition("=")
        variants.append(Variant(name, REPO / "python", json.loads(knobs)))
    if args.base:
        variants.insert(0, Variant.base(args.base))
    rows = []
    print(HEADER)
    for case in cases(args):
        for variant in variants:
            name = f"{case['name']} {variant.name}".replace("(", "").replace(")", "")
            run = {**case, "output": str(OUT / "frames" / "runs" / "_".join(name.split()))}
            rows.append(measure(variant, run, args.keep))
            print_row(rows[-1])
    write_json(args, rows)
    plot(args.json.with_suffix(".png"), rows)
    print(f"wrote {args.json} and {args.json.with_suffix('.png')}")


HEADER = (f"{'case':<40}{'variant':>8}{'static s':>9}{'dyn s':>8}{'dyn/st':>7}"
          f"{'steps st':>9}{'steps dyn':>10}{'step x':>7}{'moving':>7}{'window':>7}"
          f"{'PSNR mv':>8}{'min mv':>7}{'t+.5':>7}{'PSNR st':>8}{'temp err':>9}"
          f"{'flicker':>8}{'truth':>7}{'dyn MB':>7}")  # fmt: skip


def print_row(r: dict[str, Any]) -> None:
    def mean(key: str) -> float:
        return float(np.nanmean(r[key])) if r.get(key) else math.nan

    lowest = float(np.nanmin(r["moving_psnr"])) if r.get("moving_psnr") else math.nan
    print(f"{r['case']:<40}{r['variant']:>8}{r['timings_s']['static']:>9.1f}"
          f"{r['timings_s']['dynamic']:>8.1f}{r['dynamic_over_static']:>7.2f}"
          f"{r['steps']['static']:>9}{r['steps']['dynamic']:>10}"
          f"{r['step_ratio'] or math.nan:>7.2f}{r['moving_share']:>7.2f}"
          f"{r.get('window_share', 1.0):>7.2f}{mean('moving_psnr'):>8.2f}{lowest:>7.2f}"
          f"{mean('halfway_psnr'):>7.2f}{mean('static_psnr'):>8.2f}"
          f"{r.get('temporal_error', math.nan):>9.4f}{r.get('flicker', math.nan):>8.4f}"
          f"{r.get('truth_flicker', math.nan):>7.4f}{r['dynamic_bytes'] / 2**20:>7.2f}",
          flush=True)  # fmt: skip



def write_json(args: argparse.Namespace, rows: list[dict[str, Any]]) -> None:
    from pano4d.fsutil import write_json_atomic

    write_json_atomic(args.json, {
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "torch": torch.__version__, "load": os.getloadavg()},
        "date": time.strftime("%Y-%m-%d"),
        "base": args.base,
        "settings": args.setting,
        "rows": rows,
    })  # fmt: skip


if __name__ == "__main__":
    main()
