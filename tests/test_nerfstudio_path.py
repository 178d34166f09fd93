"""nerfstudio's camera_path.json: read as ns-render reads it, every bad value one line."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from test_camera_paths import red_wall
from test_panorama_video import decoded
from typer.testing import CliRunner

from pano4d import camera_paths, nerfstudio_path, panorama_video, ply4d
from pano4d.camera import Camera
from pano4d.cli import app
from pano4d.gaussians import Gaussians
from pano4d.nerfstudio_path import CameraPathError, DataparserTransform
from pano4d.renderer import render
from pano4d.spacetime import SpacetimeGaussians, TimeModel

runner = CliRunner()


def rolled_camera(width: int = 64, height: int = 48) -> Camera:
    """A camera off the origin, looking down and to the side, with some roll."""
    return Camera.from_fov(70.0, width, height, (0.3, -0.2, 0.1), (1.0, 0.4, -0.3), (0.2, 0.0, 1.0))


def path_file(tmp_path: Path, entries: list[dict[str, Any]], **top: Any) -> Path:
    data = {"render_width": 64, "render_height": 48, "fps": 24, "seconds": 1.0,
            "camera_type": "perspective", "camera_path": entries, **top}  # fmt: skip
    out = tmp_path / "camera_path.json"
    out.write_text(json.dumps(data))
    return out


def entry(camera: Camera, fov: float = 50.0, **extra: Any) -> dict[str, Any]:
    flat = camera.camera_to_world_gl().reshape(-1).tolist()
    return {"camera_to_world": flat, "fov": fov, "aspect": 64 / 48, **extra}


def test_a_pose_comes_back_as_the_camera_it_was_made_from(tmp_path: Path) -> None:
    cam = rolled_camera()
    path = nerfstudio_path.read(path_file(tmp_path, [entry(cam, fov=50.0)]))
    (back,) = path.cameras()
    assert torch.allclose(back.world_to_cam, cam.world_to_cam, atol=1e-12)
    # ns-render's intrinsics: the vertical field of view over the image height, centred.
    f = 24.0 / math.tan(math.radians(25.0))
    assert back.fx == pytest.approx(f, rel=1e-12) and back.fy == pytest.approx(f, rel=1e-12)
    assert (back.cx, back.cy, back.width, back.height) == (32.0, 24.0, 64, 48)
    assert path.fps == 24.0 and path.camera_type == "perspective"


def test_nested_and_flat_matrices_read_the_same(tmp_path: Path) -> None:
    cam = rolled_camera()
    nested = {**entry(cam), "camera_to_world": cam.camera_to_world_gl().tolist()}
    a = nerfstudio_path.read(path_file(tmp_path, [entry(cam)])).cameras()[0]
    b = nerfstudio_path.read(path_file(tmp_path, [nested])).cameras()[0]
    assert torch.equal(a.world_to_cam, b.world_to_cam)


def test_render_time_spans_the_loop_only_when_every_entry_has_one(tmp_path: Path) -> None:
    cam = rolled_camera()
    timed = [entry(cam, render_time=r) for r in (0.0, 0.25, 0.5, 1.0)]
    path = nerfstudio_path.read(path_file(tmp_path, timed))
    assert path.scene_times(num_times=8, scene_fps=8.0) == [0.0, 2.0, 4.0, 8.0]
    # One entry without: the scene's own clock at the file's 24 fps (an 8 fps scene: 1/3 a frame).
    mixed = [entry(cam, render_time=0.5), entry(cam), entry(cam, render_time=0.5)]
    path = nerfstudio_path.read(path_file(tmp_path, mixed))
    assert path.scene_times(num_times=8, scene_fps=8.0) == pytest.approx([0.0, 1 / 3, 2 / 3])


def test_a_path_made_in_nerfstudios_coordinates_maps_back(tmp_path: Path) -> None:
    cam = rolled_camera()
    c2w = cam.camera_to_world_gl()
    a = math.radians(30.0)
    transform = torch.eye(4, dtype=torch.float64)
    transform[:3, :3] = torch.tensor(
        [[1.0, 0.0, 0.0], [0.0, math.cos(a), -math.sin(a)], [0.0, math.sin(a), math.cos(a)]],
        dtype=torch.float64,
    )
    transform[:3, 3] = torch.tensor([0.5, -1.0, 2.0], dtype=torch.float64)
    scale = 0.25
    # What nerfstudio's dataparser trains on: scale · (T · pose), the translation scaled.
    normalised = transform @ c2w
    normalised[:3, 3] *= scale
    parser = tmp_path / "dataparser_transforms.json"
    parser.write_text(json.dumps({"transform": transform[:3].tolist(), "scale": scale}))
    made = {**entry(cam), "camera_to_world": normalised.reshape(-1).tolist()}
    path = nerfstudio_path.read(path_file(tmp_path, [made]))
    back = path.to_scene(nerfstudio_path.read_dataparser_transform(parser)).cameras()[0]
    assert torch.allclose(back.world_to_cam, cam.world_to_cam, atol=1e-12)
    identity = DataparserTransform(torch.eye(4, dtype=torch.float64), 1.0)
    assert torch.equal(path.to_scene(identity).frames[0].camera_to_world, normalised)


def test_equirectangular_paths_need_no_fov_and_give_positions(tmp_path: Path) -> None:
    cam = rolled_camera()
    plain = {"camera_to_world": cam.camera_to_world_gl().tolist()}
    path = nerfstudio_path.read(path_file(tmp_path, [plain], camera_type="equirectangular"))
    (position,) = path.positions()
    assert torch.allclose(position, torch.tensor([0.3, -0.2, 0.1], dtype=torch.float64))


BAD_FILES: list[tuple[dict[str, Any], str]] = [
    ({"camera_type": "fisheye"}, "camera_type 'fisheye' is not supported"),
    ({"render_width": 0}, "render_width must be a whole number of pixels"),
    ({"render_height": "48"}, "render_height must be a whole number of pixels"),
    ({"fps": 0}, "fps must be a frame rate > 0"),
    ({"fps": float("nan")}, "fps must be a frame rate > 0"),
    ({"camera_path": []}, "camera_path must be a non-empty list"),
    ({"camera_path": [[1, 2]]}, "camera_path[0]: expected an object"),
    ({"camera_path": [{"camera_to_world": [1, 2, 3], "fov": 50}]},
     "camera_path[0].camera_to_world: expected 16 numbers"),
]  # fmt: skip


@pytest.mark.parametrize(("change", "message"), BAD_FILES)
def test_a_bad_file_names_the_field(tmp_path: Path, change: dict[str, Any], message: str) -> None:
    change = dict(change)
    entries = change.pop("camera_path", [entry(rolled_camera())])
    with pytest.raises(CameraPathError, match=r"camera_path\.json: ") as e:
        nerfstudio_path.read(path_file(tmp_path, entries, **change))
    assert message in str(e.value)


def bad_entry(**change: Any) -> dict[str, Any]:
    return {**entry(rolled_camera()), **change}


BAD_ENTRIES: list[tuple[dict[str, Any], str]] = [
    (bad_entry(fov=180), "camera_path[1]: fov must be degrees in (0, 180)"),
    (bad_entry(fov=None), "camera_path[1]: fov must be a number"),
    (bad_entry(render_time=1.5), "camera_path[1]: render_time must be in [0, 1]"),
    (bad_entry(render_time=-0.1), "camera_path[1]: render_time must be in [0, 1]"),
    (bad_entry(camera_to_world=[0.0] * 15 + [float("nan")]),
     "camera_path[1].camera_to_world: every value must be finite"),
    (bad_entry(camera_to_world=[2.0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]),
     "camera_path[1].camera_to_world: the 3×3 part must be a rotation"),
    (bad_entry(camera_to_world=[-1.0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]),
     "camera_path[1].camera_to_world: the 3×3 part must be a rotation"),
    (bad_entry(camera_to_world=[1.0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 1, 1]),
     "camera_path[1].camera_to_world: the last row must be [0, 0, 0, 1]"),
]  # fmt: skip


@pytest.mark.parametrize(("bad", "message"), BAD_ENTRIES)
def test_a_bad_entry_names_the_entry_and_field(
    tmp_path: Path, bad: dict[str, Any], message: str
) -> None:
    with pytest.raises(CameraPathError) as e:
        nerfstudio_path.read(path_file(tmp_path, [entry(rolled_camera()), bad]))
    assert message in str(e.value)


def test_unreadable_files_are_one_error(tmp_path: Path) -> None:
    with pytest.raises(CameraPathError, match="cannot be read"):
        nerfstudio_path.read(tmp_path / "missing.json")
    broken = tmp_path / "broken.json"
    broken.write_text("{")
    with pytest.raises(CameraPathError, match="not JSON"):
        nerfstudio_path.read(broken)
    parser = tmp_path / "dataparser_transforms.json"
    parser.write_text(json.dumps({"transform": [[1, 0, 0, 0]], "scale": 1.0}))
    with pytest.raises(CameraPathError, match="transform: expected 12 numbers"):
        nerfstudio_path.read_dataparser_transform(parser)


# --- pano4d render --path camera_path.json --------------------------------------------------


def glowing_scene(tmp_path: Path) -> Path:
    """A version-2 scene of 4 frames at 8 fps whose wall's red rises and falls in time."""
    glowing = SpacetimeGaussians.still(TimeModel(4, 1, 0), red_wall())
    glowing.canonical.sh[:, 0, 0] = 0.0
    glowing.colour_terms[:, 0, 0] = 1.5  # cos₁ of the red DC term
    path = tmp_path / "glowing.ply4d"
    ply4d.write(path, ply4d.Scene4D(Gaussians.empty(), glowing, [0.0, 0.125, 0.25, 0.375], 8.0))
    return path


def wall_cameras() -> list[Camera]:
    """Three poses that see the wall 4 m ahead along +x, one rolled."""
    return [
        Camera.from_fov(70.0, 64, 48, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0)),
        Camera.from_fov(70.0, 64, 48, (0.5, 0.3, 0.1), (1.0, -0.2, 0.05)),
        Camera.from_fov(70.0, 64, 48, (1.0, -0.4, 0.0), (1.0, 0.3, -0.1), (0.0, 0.3, 1.0)),
    ]


def test_a_camera_path_renders_what_the_equivalent_camera_json_renders(tmp_path: Path) -> None:
    """Each frame of the path is bit for bit the still `pano4d render --camera` draws from
    the same pose at the entry's render_time (0.625 of a 4-frame loop: time 2.5)."""
    scene = glowing_scene(tmp_path)
    times = (0.0, 0.3, 0.625)
    entries = [
        entry(c, fov=50.0, render_time=r) for c, r in zip(wall_cameras(), times, strict=True)
    ]
    path = nerfstudio_path.read(path_file(tmp_path, entries))
    drawn = list(camera_paths.path_frames(scene, path.cameras(), path.scene_times(4, 8.0), "wgpu"))
    source = ply4d.open(scene)
    for cam, r, frame in zip(path.cameras(), times, drawn, strict=True):
        equivalent = camera_paths.parse_camera(json.dumps(cam.to_dict()), 64, 48)
        still = camera_paths.to_image(render(source.at(r * 4), equivalent).rgb)
        assert np.array_equal(frame, still), r
    last = path.cameras()[2]
    for t in (2.0, 3.0):  # time 2.5 is neither neighbouring frame
        other = camera_paths.to_image(render(source.at(t), last).rgb)
        assert np.abs(other - drawn[2]).max() > 0.05, t


def test_render_writes_the_video_the_file_describes(tmp_path: Path) -> None:
    scene = glowing_scene(tmp_path)
    times = (0.0, 0.3, 0.625)
    entries = [
        entry(c, fov=50.0, render_time=r) for c, r in zip(wall_cameras(), times, strict=True)
    ]
    cp = path_file(tmp_path, entries, render_width=32, render_height=24, fps=8)
    out = tmp_path / "path.mp4"
    ran = runner.invoke(app, ["render", str(scene), "--path", str(cp), "--out", str(out)])
    assert ran.exit_code == 0, ran.output
    assert "3 frames, 32x24 at 8 fps" in " ".join(ran.output.split())
    frames = decoded(out)
    assert len(frames) == 3 and frames[0].shape == (24, 32, 3)
    source, cams = ply4d.open(scene), nerfstudio_path.read(cp).cameras()
    for i, (got, cam, r) in enumerate(zip(frames, cams, times, strict=True)):
        want = camera_paths.to_image(render(source.at(4 * r), cam).rgb)
        clock = camera_paths.to_image(render(source.at(float(i)), cam).rgb)  # without the times
        assert np.abs(got - want).mean() < 0.02 < np.abs(got - clock).mean() or r == 0, i


def test_an_equirectangular_path_makes_a_360_video_from_its_positions(tmp_path: Path) -> None:
    scene = glowing_scene(tmp_path)
    entries = [{"camera_to_world": c.camera_to_world_gl().tolist()} for c in wall_cameras()]
    cp = path_file(tmp_path, entries, camera_type="equirectangular", render_width=64,
                   render_height=32, fps=8)  # fmt: skip
    out = tmp_path / "pano.mp4"
    ran = runner.invoke(app, ["render", str(scene), "--path", str(cp), "--out", str(out)])
    assert ran.exit_code == 0, ran.output
    frames = decoded(out)
    assert len(frames) == 3 and frames[0].shape == (32, 64, 3)
    source, frame = ply4d.open(scene), panorama_video.Frame360(64, 32)
    for i, (got, cam) in enumerate(zip(frames, wall_cameras(), strict=True)):
        want = panorama_video.equirect_frame(source.at(float(i)), frame, cam.position)
        assert np.abs(got - want).mean() < 0.02, i
    cp.write_text(cp.read_text().replace('"render_height": 32', '"render_height": 30'))
    ran = runner.invoke(app, ["render", str(scene), "--path", str(cp), "--out", str(out)])
    assert ran.exit_code == 2
    assert "render_width × render_height 64x30: a mono equirect frame must be 2:1" in ran.output


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--width", "64"], "--width: "),
        (["--time", "1"], "--time: "),
        (["--fps", "24"], "--fps: "),
        (["--projection", "equirect"], "is a perspective camera path"),
    ],
)
def test_options_the_file_sets_are_one_error_line(
    tmp_path: Path, extra: list[str], message: str
) -> None:
    scene = glowing_scene(tmp_path)
    cp = path_file(tmp_path, [entry(wall_cameras()[0])])
    out = tmp_path / "v.mp4"
    ran = runner.invoke(app, ["render", str(scene), "--path", str(cp), "--out", str(out), *extra])
    assert ran.exit_code == 2, ran.output
    assert ran.output.startswith("error: ") and message in ran.output
    assert "Traceback" not in ran.output and not out.exists()


def test_a_bad_file_through_the_command_is_one_line(tmp_path: Path) -> None:
    scene = glowing_scene(tmp_path)
    cp = path_file(tmp_path, [entry(wall_cameras()[0]), bad_entry(fov=0)])
    out = tmp_path / "v.mp4"
    ran = runner.invoke(app, ["render", str(scene), "--path", str(cp), "--out", str(out)])
    assert ran.exit_code == 2
    lines = ran.output.strip().splitlines()
    assert len(lines) == 1 and "camera_path[1]: fov must be degrees in (0, 180)" in lines[0]
    transform = ["--path-transform", str(tmp_path / "dataparser_transforms.json")]
    ran = runner.invoke(app, ["render", str(scene), "--path", "turntable", "--out", str(out),
                              *transform])  # fmt: skip
    assert ran.exit_code == 2 and "add --path FILE.json" in ran.output
