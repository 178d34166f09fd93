"""``pano4d views``: the lifting phase's perspective views of one timestamp as a dataset other
3DGS trainers read (nerfstudio, gsplat's examples, OpenSplat, brush).

It runs the stages before the optimisation itself through the scene's own checkpoints
(output/checkpoints/, ``lift.checkpoints``): ``prepare`` → ``estimate_depth`` →
``align_depth`` → ``initial_sets``. After a finished or interrupted ``pano4d train`` the depth
and the alignment are read back, not recomputed; before one, they are computed and
checkpointed, so a later ``pano4d train`` starts from them. What it writes in OUT/:

- ``images/view_NN.png``  the view of frame T (what the lifting phase trains on);
- ``depth/view_NN.npy``   the aligned depth of frame T as z-depth (float32, scene units);
- ``masks/view_NN.png``   nerfstudio's mask convention: 255 where a trainer should learn,
                          0 in the moving region (the pixels our static stage leaves out);
                          trainers that read no masks (OpenSplat, brush) see whole views;
- ``points3D.ply``        the initial Gaussians' centres and colours at frame T (ours: one
                          per icosphere sample at the aligned depth), as a point cloud;
- ``transforms.json``     nerfstudio: per view ``transform_matrix`` (camera-to-world, OpenGL
                          axes: x right, y up, z backward), pinhole intrinsics in pixels,
                          ``file_path``, ``depth_file_path``, ``mask_path``; top level
                          ``ply_file_path`` and ``scene_scale`` (below);
- ``sparse/0/{cameras,images,points3D}.txt``  the COLMAP text model of the same cameras
                          (PINHOLE, world-to-camera quaternions) and points, empty tracks.

Every view shares the panorama's centre, so trainers that normalise by the cameras' spread
divide by zero. ``scene_scale`` = 1 / the median depth of frame 0 (sky left out) puts the
scene at unit size; pass it in place of the automatic scale (README, "Other trainers").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pano4d.camera import Camera
from pano4d.config import SceneConfig
from pano4d.errors import InputError
from pano4d.fsutil import atomic_path, write_json_atomic, write_text_atomic
from pano4d.gaussians import SH_C0, Gaussians
from pano4d.images import write_image
from pano4d.lift.checkpoints import Checkpoints
from pano4d.lift.pipeline import (
    align_depth,
    animation_frames,
    estimate_depth,
    initial_sets,
    prepare,
)
from pano4d.progress import Bars
from pano4d.resample import equirect_to_perspective


@dataclass(frozen=True)
class ViewsDataset:
    folder: Path
    time: int
    views: int
    points: int
    scene_scale: float
    initial: Gaussians  # frame T's initial Gaussians, whose centres are the points


def rotation_to_quaternion(R: torch.Tensor) -> list[float]:
    """(w, x, y, z) of a rotation matrix, w ≥ 0 (COLMAP's images.txt order)."""
    m = R.to(torch.float64)
    trace = float(m[0, 0] + m[1, 1] + m[2, 2])
    if trace > 0:
        s = 2.0 * (trace + 1.0) ** 0.5
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(torch.argmax(torch.diagonal(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * float(1.0 + m[i, i] - m[j, j] - m[k, k]) ** 0.5
        v = [0.0, 0.0, 0.0]
        v[i] = 0.25 * s
        v[j] = float(m[j, i] + m[i, j]) / s
        v[k] = float(m[k, i] + m[i, k]) / s
        q = [float(m[k, j] - m[j, k]) / s, *v]
    q = [float(x) for x in q]
    return q if q[0] >= 0 else [-x for x in q]


def export_views(cfg: SceneConfig, out: Path, time: int = 0, progress: bool = True) -> ViewsDataset:
    """Write the views of timestamp ``time`` of ``cfg``'s animation to ``out`` (module doc)."""
    frames = cfg.animate.frames
    if not 0 <= time < frames:
        raise InputError(f"--time {time}: the animation has frames 0..{frames - 1}")
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    checkpoints = Checkpoints.for_config(Path(cfg.output) / "checkpoints", cfg)
    with Bars("loss", enabled=progress) as bars:
        frames_dir = animation_frames(cfg, checkpoints, progress, None)
        inputs = prepare(cfg, frames_dir, "torch", "torch")
        view_depth = estimate_depth(inputs, checkpoints, bars, None)
        alignment = align_depth(inputs, view_depth.depth, checkpoints, bars, None)
        # frame T's Gaussians as initial_sets makes frame 0's: its image at its aligned depth
        at_time = dataclasses.replace(inputs, frames=inputs.frames[time : time + 1])
        initial = initial_sets(at_time, alignment.depths[time])
        points = Gaussians.cat([initial.static, initial.dynamic])
        scale = 1.0 / alignment.median_depth
        task = bars.task(f"views t={time}", len(inputs.cameras))
        frame = inputs.frames[time].permute(2, 0, 1)
        depth = alignment.depths[time][None]
        entries = []
        for i, camera in enumerate(inputs.cameras):
            name = f"view_{i:02d}"
            image = equirect_to_perspective(frame, camera).permute(1, 2, 0)
            write_image(out / "images" / f"{name}.png", image.clamp(0, 1).numpy())
            ray = equirect_to_perspective(depth, camera)[0]
            z = (ray / camera.z_to_ray_factor()).numpy().astype(np.float32)
            with atomic_path(out / "depth" / f"{name}.npy") as tmp, open(tmp, "wb") as f:
                np.save(f, z)
            static = (inputs.moving_in_view(camera) < 0.5).to(torch.float32)
            write_image(out / "masks" / f"{name}.png", static.numpy())
            entries.append(_frame_entry(camera, name))
            task.update(i + 1, loss=float("nan"))
    means = points.means.detach().cpu().to(torch.float64).numpy()
    colours = (0.5 + SH_C0 * points.sh[:, 0].detach().cpu()).clamp(0, 1).numpy()
    rgb = np.rint(colours * 255).astype(np.uint8)
    write_points_ply(out / "points3D.ply", means, rgb)
    write_colmap_text(out / "sparse" / "0", inputs.cameras, [e["file_path"] for e in entries],
                      means, rgb)  # fmt: skip
    write_json_atomic(out / "transforms.json", {
        "camera_model": "OPENCV",
        "ply_file_path": "points3D.ply",
        "frames": entries,
        "scene_scale": scale,
        "pano4d": {
            "scene": str(cfg.output), "time": time, "median_depth": alignment.median_depth,
            "depth": "z-depth in scene units (float32 .npy; nerfstudio: "
                     "--depth-unit-scale-factor 1)",
            "masks": "255 = learn, 0 = the moving region",
        },
    })  # fmt: skip
    return ViewsDataset(out, time, len(entries), len(means), scale, points.detach().to("cpu"))


def _frame_entry(camera: Camera, name: str) -> dict[str, Any]:
    return {
        "file_path": f"images/{name}.png",
        "depth_file_path": f"depth/{name}.npy",
        "mask_path": f"masks/{name}.png",
        "transform_matrix": camera.camera_to_world_gl().tolist(),
        "fl_x": camera.fx, "fl_y": camera.fy, "cx": camera.cx, "cy": camera.cy,
        "w": camera.width, "h": camera.height,
        "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
    }  # fmt: skip


def write_points_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray) -> None:
    """A binary little-endian point cloud: float x y z, uchar red green blue."""
    vertex = np.empty(len(xyz), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                       ("red", "u1"), ("green", "u1"), ("blue", "u1")])  # fmt: skip
    vertex["x"], vertex["y"], vertex["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    vertex["red"], vertex["green"], vertex["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(xyz)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(vertex.tobytes())


def write_colmap_text(
    folder: Path, cameras: list[Camera], names: list[str], xyz: np.ndarray, rgb: np.ndarray
) -> None:
    """COLMAP's text model: one PINHOLE camera per view, its pose, and the points (no tracks:
    the points come from depth, not from matched features)."""
    camera_lines = ["# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    image_lines = ["# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "# POINTS2D[]"]
    for i, (camera, name) in enumerate(zip(cameras, names, strict=True), start=1):
        camera_lines.append(
            f"{i} PINHOLE {camera.width} {camera.height} "
            f"{camera.fx!r} {camera.fy!r} {camera.cx!r} {camera.cy!r}"
        )
        q = " ".join(repr(x) for x in rotation_to_quaternion(camera.R))
        t = " ".join(repr(float(x)) for x in camera.t)
        image_lines += [f"{i} {q} {t} {i} {Path(name).name}", ""]
    point_lines = ["# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[]"]
    point_lines += [
        f"{i} {x:.6f} {y:.6f} {z:.6f} {r} {g} {b} 0"
        for i, ((x, y, z), (r, g, b)) in enumerate(zip(xyz, rgb, strict=True), start=1)
    ]
    for file, lines in (("cameras.txt", camera_lines), ("images.txt", image_lines),
                        ("points3D.txt", point_lines)):  # fmt: skip
        write_text_atomic(folder / file, "\n".join(lines) + "\n")
