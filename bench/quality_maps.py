"""Where a lifted synthetic scene loses quality (bench/quality.py --maps).

The synthetic world is rebuilt from gt/views.json and ray-cast at any camera, so beyond the
scene's 8 ground-truth views this measures:

- per ground-truth view: PSNR over all pixels and over those the panorama's camera sees
  (``seen``: a pixel whose surface point is hidden from the origin was never in the input,
  no lifting can know it), the disoccluded share, and the **resampling ceiling**: the
  working-resolution panorama resampled into the view's orientation from the origin against
  the world cast there — what the training data can hold at all at that view's resolution;
- per layout direction (the 20 lifting views, cast at the ground-truth views' pixel size),
  PSNR from the origin (the fit) and moved sideways by 1 % of the median depth (novel);
- PSNR by surface part (sky, ground, walls, furniture …) in those novel views;
- an equirect map of the novel-view error (maps/novel_error.png) and the worst views beside
  their ground truth (maps/worst.png).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pano4d import ply4d
from pano4d.camera import Camera
from pano4d.images import read_image, write_contact_sheet, write_image
from pano4d.lift.losses import moved_camera
from pano4d.metrics import psnr
from pano4d.resample import equirect_to_perspective, perspective_to_equirect
from pano4d.sphere import view_layout
from pano4d.synth import landscape
from pano4d.synth import room_geometry as room
from pano4d.synth.scene import SCENE_KINDS
from pano4d.synth.views import render_view
from pano4d.synth.world import LABEL_SKY, World

ANALYSIS_FOV = 80.0  # the lifting views' field of view
ANALYSIS_SIZE = 273  # at ANALYSIS_FOV, the ground-truth views' pixel (75° over 256)
NOVEL_SHIFT = 0.01  # sideways, as a fraction of the median scene depth
MAP_WIDTH = 512


def load_world(root: Path) -> tuple[World, dict[str, Any]]:
    """The synthetic world a scene folder was written from, and its gt/views.json."""
    data = json.loads((root / "gt" / "views.json").read_text())
    meta = data["scene"]
    world = SCENE_KINDS[data["kind"]](data["seed"], data["frames"], meta["camera_height"])
    return world, data


def parts(kind: str, labels: torch.Tensor) -> dict[str, torch.Tensor]:
    """Masks of the surface parts PSNR is broken down by, named for the report."""
    if kind == "landscape":
        return {
            "sky": labels == LABEL_SKY,
            "terrain": labels == landscape.LABEL_TERRAIN,
            "water": labels == landscape.LABEL_WATER,
            "objects": labels >= landscape.LABEL_OBJECT,
        }
    return {
        "sky": labels == LABEL_SKY,
        "floor": labels == room.LABEL_FLOOR,
        "ceiling": labels == room.LABEL_CEILING,
        "walls": labels == room.LABEL_WALL,
        "screen": labels == room.LABEL_SCREEN,
        "furniture": (labels >= room.LABEL_FURNITURE) & (labels < room.LABEL_OUTSIDE),
        "outside": (labels == room.LABEL_GROUND) | (labels >= room.LABEL_OUTSIDE),
    }


def seen_from_origin(world: World, camera: Camera, depth: torch.Tensor) -> torch.Tensor:
    """(h, w) bool: the surface point of each pixel of ``camera`` (its z-depth ``depth``) is
    the first thing the panorama's camera meets in that direction."""
    uv = camera.pixel_grid().view(-1, 2).double()
    points = camera.unproject(uv, depth.view(-1).double()).float()
    distance = torch.linalg.norm(points, dim=-1)
    hits = world.cast(torch.zeros(3), points / distance[:, None])
    seen = hits.depth >= distance * (1 - 2e-3) - 2e-3
    return seen.view(camera.height, camera.width)


def masked_psnr(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor) -> float | None:
    if int(mask.sum()) == 0:
        return None
    mse = float(((a - b) ** 2)[mask].mean())
    return 10 * math.log10(1.0 / max(mse, 1e-12))


def analyse(
    root: Path, output: Path, working_width: int, render: Any, time: int = 0
) -> dict[str, Any]:
    """Every figure of the module docstring for the scene trained into ``output``; writes
    the maps into output/maps/. ``render(gaussians, camera)`` draws the lifted scene."""
    world, data = load_world(root)
    scene = ply4d.read(output / "scene.ply4d")
    panorama = torch.from_numpy(np.ascontiguousarray(read_image(root / "panorama.png")[..., :3]))
    median = float(scene.extra.get("median_depth", 1.0))

    gt_rows = []
    for entry in data["views"]:
        camera = Camera.from_dict(entry)
        t = min(int(entry["time"]), scene.num_times - 1)
        truth = torch.from_numpy(
            np.ascontiguousarray(read_image(root / "gt" / entry["image"])[..., :3])
        )
        with torch.no_grad():
            rgb = render(scene.at(t), camera).rgb.clamp(0, 1).cpu()
        _, depth = render_view(world, camera, t)
        seen = seen_from_origin(world, camera, depth)
        centred = Camera(camera.K, _at_origin(camera), camera.width, camera.height)
        truth_centre, _ = render_view(world, centred, t)
        frame_t = _downsample(_frame(root, t, panorama), working_width)
        resampled = equirect_to_perspective(frame_t.permute(2, 0, 1), centred).permute(1, 2, 0)
        gt_rows.append({
            "image": entry["image"],
            "displacement_fraction": entry["displacement_fraction"],
            "psnr": psnr(rgb, truth),
            "psnr_seen": masked_psnr(rgb, truth, seen),
            "disoccluded": float(1 - seen.float().mean()),
            "ceiling_resample": psnr(resampled.clamp(0, 1), truth_centre),
        })  # fmt: skip

    layout = view_layout(20, ANALYSIS_FOV, ANALYSIS_SIZE)
    error_sum = torch.zeros(MAP_WIDTH // 2, MAP_WIDTH)
    error_count = torch.zeros(MAP_WIDTH // 2, MAP_WIDTH)
    by_part: dict[str, list[torch.Tensor]] = {}
    layout_rows, tiles = [], []
    for i, base in enumerate(layout):
        row: dict[str, Any] = {"view": i, "forward": base.forward.tolist()}
        for name, camera in (("fit", base), ("novel", _sideways(base, NOVEL_SHIFT * median))):
            truth, _ = render_view(world, camera, time)
            with torch.no_grad():
                rgb = render(scene.at(time), camera).rgb.clamp(0, 1).cpu()
            row[name] = psnr(rgb, truth)
            if name == "novel":
                err = (rgb - truth).abs().mean(-1)
                eq, covered = perspective_to_equirect(err, camera, MAP_WIDTH, MAP_WIDTH // 2)
                error_sum += torch.where(covered, eq, 0.0)
                error_count += covered.float()
                hits = world.cast(camera.position.float(), camera.world_directions().view(-1, 3))
                sq = ((rgb - truth) ** 2).mean(-1).view(-1)
                for part, mask in parts(data["kind"], hits.label).items():
                    by_part.setdefault(part, []).append(sq[mask])
                tiles.append((row[name], truth.numpy(), rgb.numpy(), i))
        layout_rows.append(row)
    part_psnr = {}
    for part, chunks in by_part.items():
        sq = torch.cat(chunks)
        if len(sq):
            part_psnr[part] = {
                "psnr": 10 * math.log10(1.0 / max(float(sq.mean()), 1e-12)),
                "pixel_share": 0.0,
                "pixels": len(sq),
            }
    total = sum(p["pixels"] for p in part_psnr.values())
    for p in part_psnr.values():
        p["pixel_share"] = p["pixels"] / max(total, 1)

    def at(fraction: float) -> list[dict[str, Any]]:
        return [r for r in gt_rows if r["displacement_fraction"] == fraction]

    maps = output / "maps"
    error_map = error_sum / error_count.clamp_min(1)
    write_image(maps / "novel_error.png", _heat(error_map, scale=0.15).numpy())
    worst = sorted(tiles, key=lambda tile: tile[0])[:4]
    images = [img for _, truth, rgb, _ in worst for img in (truth, rgb)]
    labels = [f"{lab} view {i} ({p:.1f} dB)" for p, _, _, i in worst for lab in ("gt", "render")]
    write_contact_sheet(maps / "worst.png", images, 4, labels)
    return {
        "gt_views": gt_rows,
        "layout_views": layout_rows,
        "parts_novel": part_psnr,
        "mean": {
            "psnr_seen_1pct": _mean(r["psnr_seen"] for r in at(0.01)),
            "psnr_seen_5pct": _mean(r["psnr_seen"] for r in at(0.05)),
            "disoccluded_5pct": _mean(r["disoccluded"] for r in at(0.05)),
            "ceiling_resample": _mean(r["ceiling_resample"] for r in gt_rows),
            "layout_fit": _mean(r["fit"] for r in layout_rows),
            "layout_novel": _mean(r["novel"] for r in layout_rows),
        },
    }  # fmt: skip


# --- helpers ---------------------------------------------------------------------------------
def _mean(values: Any) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else None


def _at_origin(camera: Camera) -> torch.Tensor:
    w2c = camera.world_to_cam.clone()
    w2c[:3, 3] = 0.0
    return w2c


def _sideways(camera: Camera, distance: float) -> Camera:
    return moved_camera(camera, camera.R[0] * distance)  # along the camera's x axis


def _frame(root: Path, t: int, panorama: torch.Tensor) -> torch.Tensor:
    path = root / "gt" / "frames" / f"{t:04d}.png"
    if not path.is_file():
        return panorama
    return torch.from_numpy(np.ascontiguousarray(read_image(path)[..., :3]))


def _downsample(image: torch.Tensor, width: int) -> torch.Tensor:
    import torch.nn.functional as F

    if image.shape[1] == width:
        return image
    x = image.permute(2, 0, 1)[None]
    return F.interpolate(x, size=(width // 2, width), mode="area")[0].permute(1, 2, 0)


def _heat(values: torch.Tensor, scale: float) -> torch.Tensor:
    """Black → red → yellow → white as ``values`` go from 0 to ``scale``."""
    v = (values / scale).clamp(0, 1)[..., None]
    stops = torch.tensor([[0.0, 0.0, 0.0], [0.8, 0.1, 0.05], [1.0, 0.85, 0.1], [1.0, 1.0, 1.0]])
    position = v * (len(stops) - 1)
    lower = position.floor().long().clamp(max=len(stops) - 2)
    share = position - lower
    return torch.lerp(stops[lower[..., 0]], stops[lower[..., 0] + 1], share)
