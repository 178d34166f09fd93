"""`pano4d views`: the lifting phase's views as a dataset other trainers read.

The cameras round-trip (a point projected through our Camera and through the written
intrinsics and extrinsics lands on the same pixel, in nerfstudio's OpenGL camera-to-world
convention and through COLMAP's own projection), the files parse with readers that are not
ours (pycolmap for the COLMAP text model, plyfile for the points), the depth maps agree with
the points, the masks mark the moving region, and bad input is one `error:` line.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pycolmap
import pytest
import torch
from pano4d_process import error_line, pano4d, tiny_scene
from plyfile import PlyData

from pano4d.camera import Camera
from pano4d.config import load_config
from pano4d.images import read_image
from pano4d.sphere import view_layout


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny synthetic scene whose true animation stands in for the animating phase, with
    its views at t = 0 and t = 1 written."""
    folder = tmp_path_factory.mktemp("views") / "scene"
    yaml = tiny_scene(folder, frames=2)
    shutil.copytree(folder / "gt" / "frames", folder / "output" / "animate" / "frames")
    for t in (0, 1):
        done = pano4d("views", yaml, folder / f"views_t{t}", "--time", str(t))
        assert done.returncode == 0, done.stderr
    return folder


def our_cameras(scene: Path) -> list[Camera]:
    cfg = load_config(scene / "scene.yaml")
    knobs = cfg.resolved_preset(512)
    return view_layout(cfg.lift.views, cfg.lift.fov_deg, knobs.view_size)


def transforms(scene: Path, t: int = 0) -> dict[str, Any]:
    return dict(json.loads((scene / f"views_t{t}" / "transforms.json").read_text()))


def points_in_front(camera: Camera, count: int = 50, seed: int = 0) -> torch.Tensor:
    """World points inside ``camera``'s view at depths 0.5..40."""
    g = torch.Generator().manual_seed(seed)
    uv = torch.rand(count, 2, generator=g, dtype=torch.float64)
    uv = uv * torch.tensor([camera.width, camera.height], dtype=torch.float64)
    z = 0.5 + 40 * torch.rand(count, generator=g, dtype=torch.float64)
    return camera.unproject(uv, z)


def project_nerfstudio(frame: dict[str, Any], points: np.ndarray) -> np.ndarray:
    """Pixels of world points through a transforms.json frame, nerfstudio's way: the camera
    looks down its −z, y up; pixel centres at +0.5 (written here, not with our Camera)."""
    c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)
    w2c = np.linalg.inv(c2w)
    p = points @ w2c[:3, :3].T + w2c[:3, 3]
    x = frame["fl_x"] * p[:, 0] / -p[:, 2] + frame["cx"]
    y = frame["fl_y"] * -p[:, 1] / -p[:, 2] + frame["cy"]
    return np.stack([x, y], axis=-1)


def test_nerfstudio_cameras_round_trip(scene: Path) -> None:
    frames = transforms(scene)["frames"]
    cameras = our_cameras(scene)
    assert len(frames) == len(cameras)
    for i, (frame, camera) in enumerate(zip(frames, cameras, strict=True)):
        assert (frame["w"], frame["h"]) == (camera.width, camera.height)
        points = points_in_front(camera, seed=i)
        ours, _ = camera.project(points)
        theirs = project_nerfstudio(frame, points.numpy())
        np.testing.assert_allclose(theirs, ours.numpy(), atol=1e-6)


def test_colmap_model_parses_and_projects_like_ours(scene: Path) -> None:
    model = pycolmap.Reconstruction()
    model.read_text(str(scene / "views_t0" / "sparse" / "0"))
    cameras = our_cameras(scene)
    assert model.num_images() == len(cameras)
    for image_id, image in model.images.items():
        camera = cameras[image_id - 1]
        assert image.name == f"view_{image_id - 1:02d}.png"
        points = points_in_front(camera, seed=image_id)
        ours, _ = camera.project(points)
        for point, pixel in zip(points.numpy(), ours.numpy(), strict=True):
            np.testing.assert_allclose(image.project_point(point), pixel, atol=1e-5)
    ply = PlyData.read(str(scene / "views_t0" / "points3D.ply"))["vertex"]
    assert model.num_points3D() == ply.count > 0
    first = model.points3D[1]
    np.testing.assert_allclose(first.xyz, [ply["x"][0], ply["y"][0], ply["z"][0]], atol=1e-5)
    assert list(first.color) == [ply["red"][0], ply["green"][0], ply["blue"][0]]


def test_points_lie_at_the_written_depth(scene: Path) -> None:
    """The .ply's points (read by plyfile) seen from each view sit at that view's z-depth map."""
    data = transforms(scene)
    ply = PlyData.read(str(scene / "views_t0" / data["ply_file_path"]))["vertex"]
    xyz = torch.from_numpy(np.stack([ply["x"], ply["y"], ply["z"]], axis=-1).astype(np.float64))
    assert torch.isfinite(xyz).all()
    for frame, camera in zip(data["frames"], our_cameras(scene), strict=True):
        depth = np.load(scene / "views_t0" / frame["depth_file_path"])
        assert depth.shape == (camera.height, camera.width) and depth.dtype == np.float32
        uv, z = camera.project(xyz)
        inside = (z > 0) & (uv[:, 0] >= 1) & (uv[:, 1] >= 1)
        inside &= (uv[:, 0] < camera.width - 1) & (uv[:, 1] < camera.height - 1)
        u, v = uv[inside].long().T
        relative = np.abs(depth[v, u] / z[inside].numpy() - 1)
        assert np.median(relative) < 0.05


def test_scene_scale_is_the_inverse_median_depth(scene: Path) -> None:
    data = transforms(scene)
    median = data["pano4d"]["median_depth"]
    assert median > 0 and data["scene_scale"] == pytest.approx(1 / median)
    ply = PlyData.read(str(scene / "views_t0" / "points3D.ply"))["vertex"]
    radius = np.sqrt(ply["x"] ** 2 + ply["y"] ** 2 + ply["z"] ** 2)
    assert np.percentile(radius, 10) < median < np.percentile(radius, 99.9)


def test_time_and_masks(scene: Path) -> None:
    """t = 1's views change in the moving region only, which the masks mark with 0."""
    moved, still = [], []
    data = transforms(scene, 1)
    assert data["pano4d"]["time"] == 1
    for frame in data["frames"]:
        a = read_image(scene / "views_t0" / frame["file_path"])[..., :3]
        b = read_image(scene / "views_t1" / frame["file_path"])[..., :3]
        learn = read_image(scene / "views_t1" / frame["mask_path"])[..., 0] > 0.5
        change = np.abs(a - b).mean(-1)
        still.append(change[learn])
        moved.append(change[~learn])
    moving, kept = np.concatenate(moved), np.concatenate(still)
    assert moving.size > 0 and kept.size > 0
    # the mask is the region at the working resolution resampled into the view: at its edge
    # a few pixels it keeps change by a level of 8 bits
    assert np.mean(kept > 1.5 / 255) < 0.001
    assert moving.mean() > 50 * kept.mean()


def test_no_temporary_files_left(scene: Path) -> None:
    left = [p for p in (scene / "views_t0").rglob("*") if ".tmp" in p.name]
    assert left == []


def test_bad_input_is_one_line(scene: Path, tmp_path: Path) -> None:
    yaml = scene / "scene.yaml"
    line = error_line(pano4d("views", yaml, tmp_path / "out", "--time", "5"))
    assert "--time 5" in line and "0..1" in line
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    line = error_line(pano4d("views", yaml, blocker))
    assert str(blocker) in line and "not a folder" in line
    line = error_line(pano4d("views", tmp_path / "missing.yaml", tmp_path / "out"))
    assert "missing.yaml" in line
