"""Headless test views: camera specs, `pano4d render` stills and camera-path videos."""

from __future__ import annotations

import itertools
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from pano4d import camera_paths, images, panorama_video, ply4d
from pano4d.camera import Camera
from pano4d.cli import app
from pano4d.extension import spacetime_from
from pano4d.gaussians import Gaussians
from pano4d.renderer import render
from pano4d.spacetime import SpacetimeGaussians, TimeModel
from pano4d.sphere import dir_to_equirect

runner = CliRunner()


def red_wall(n: int = 64) -> Gaussians:
    """Opaque red Gaussians on a plane 4 m ahead of the origin (+x)."""
    yz = torch.stack(
        torch.meshgrid(torch.linspace(-3, 3, 8), torch.linspace(-3, 3, 8), indexing="ij"), -1
    ).reshape(-1, 2)[:n]
    means = torch.cat([torch.full((len(yz), 1), 4.0), yz], dim=1)
    sh = torch.zeros(len(yz), 1, 3)
    sh[:, 0, 0] = (1.0 - 0.5) / 0.28209479177387814
    sh[:, 0, 1:] = (0.0 - 0.5) / 0.28209479177387814
    return Gaussians(
        means,
        torch.full((len(yz), 3), -0.3),
        torch.tensor([[1.0, 0, 0, 0]] * len(yz)),
        torch.full((len(yz),), 8.0),
        sh,
    )


def test_parse_camera_shapes_and_errors(tmp_path: Path) -> None:
    default = camera_paths.parse_camera(None, 64, 48)
    assert default.position.tolist() == [0, 0, 0]
    assert default.forward.tolist() == pytest.approx([1, 0, 0])
    pose = camera_paths.parse_camera(
        '{"position": [1, 2, 3], "forward": [0, 1, 0], "fov_deg": 60}', 64, 48
    )
    assert pose.position.tolist() == pytest.approx([1, 2, 3])
    assert pose.fov_deg()[0] == pytest.approx(60)
    f = tmp_path / "cam.json"
    f.write_text(json.dumps(Camera.from_fov(70, 32, 24, (0, 1, 0), (1, 1, 0)).to_dict()))
    from_file = camera_paths.parse_camera(str(f), 32, 24)
    assert from_file.position.tolist() == pytest.approx([0, 1, 0])
    with pytest.raises(ValueError, match="forward"):
        camera_paths.parse_camera('{"position": [0, 0, 0]}', 64, 48)
    with pytest.raises(ValueError, match="JSON"):
        camera_paths.parse_camera("{not json", 64, 48)


def test_render_still_from_the_panorama_viewpoint_sees_the_wall(tmp_path: Path) -> None:
    scene = tmp_path / "wall.ply"
    ply4d.write_ply(scene, red_wall())
    out = tmp_path / "view.png"
    result = runner.invoke(
        app, ["render", str(scene), "--out", str(out), "--width", "64", "--height", "48"]
    )
    assert result.exit_code == 0, result.output
    img = images.read_image(out)
    assert img.shape == (48, 64, 3)
    centre = img[20:28, 28:36]
    assert centre[..., 0].mean() > 0.9 and centre[..., 1:].mean() < 0.1
    # Looking the other way there is nothing: black.
    back = runner.invoke(
        app,
        [
            "render",
            str(scene),
            "--out",
            str(out),
            "--width",
            "64",
            "--height",
            "48",
            "--camera",
            '{"position": [0, 0, 0], "forward": [-1, 0, 0]}',
        ],
    )
    assert back.exit_code == 0, back.output
    assert images.read_image(out).max() == 0.0


def test_render_errors_are_clear(tmp_path: Path) -> None:
    missing = runner.invoke(
        app, ["render", str(tmp_path / "nope.ply"), "--out", str(tmp_path / "x.png")]
    )
    assert missing.exit_code == 2 and "nope.ply" in missing.output
    scene = tmp_path / "wall.ply"
    ply4d.write_ply(scene, red_wall())
    bad_time = runner.invoke(
        app, ["render", str(scene), "--out", str(tmp_path / "x.png"), "--time", "3"]
    )
    assert bad_time.exit_code == 2 and "--time" in bad_time.output


def test_render_of_a_version_2_scene_draws_it_at_the_time(tmp_path: Path) -> None:
    """The wall as one spacetime set (format version 2) looping over 4 frames: in view at
    frame 0, carried 100 m aside by its position harmonic at frame 2."""
    wall = red_wall()
    wall.means[:, 1] += 50.0
    moving = SpacetimeGaussians.still(TimeModel(4, 0, 1), wall)
    moving.position_terms[:, 0, 1] = -50.0  # cos₁ of y: y − 50·cos(2π·t / 4)
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, ply4d.Scene4D(Gaussians.empty(), moving, [0.0, 0.25, 0.5, 0.75], 4.0))

    def centre_at(t: int) -> np.ndarray:
        out = tmp_path / f"t{t}.png"
        args = ["render", str(path), "--out", str(out), "--width", "64", "--height", "48"]
        result = runner.invoke(app, [*args, "--time", str(t)])
        assert result.exit_code == 0, result.output
        return images.read_image(out)[20:28, 28:36]

    assert centre_at(0)[..., 0].mean() > 0.9
    assert centre_at(2).max() == 0.0
    assert centre_at(4)[..., 0].mean() > 0.9  # one loop on: frame 0 again


def glowing_wall() -> tuple[SpacetimeGaussians, ply4d.Scene4D]:
    """The wall as a spacetime set looping over 4 frames at 8 fps, its red rising and
    falling with cos(2π·t / 4): at 2.5 it is neither frame 2's nor frame 3's."""
    glowing = SpacetimeGaussians.still(TimeModel(4, 1, 0), red_wall())
    glowing.canonical.sh[:, 0, 0] = 0.0
    glowing.colour_terms[:, 0, 0] = 1.5  # cos₁ of the red DC term
    return glowing, ply4d.Scene4D(Gaussians.empty(), glowing, [0.0, 0.125, 0.25, 0.375], 8.0)


def test_render_of_a_version_2_scene_between_its_frames(tmp_path: Path) -> None:
    """`pano4d render --time 2.5`, perspective and 360° (written as .exr, nothing
    quantised), draws the spacetime set evaluated at 2.5."""
    glowing, scene = glowing_wall()
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, scene)
    cam = Camera.from_fov(90.0, 64, 48)
    still = tmp_path / "still.exr"
    result = runner.invoke(app, ["render", str(path), "--out", str(still), "--width", "64",
                                 "--height", "48", "--time", "2.5"])  # fmt: skip
    assert result.exit_code == 0, result.output
    drawn = {t: render(glowing.at(t), cam).rgb.clamp(0, 1).numpy() for t in (2.0, 2.5, 3.0)}
    assert np.abs(images.read_image(still) - drawn[2.5]).max() <= 1e-6
    for frame in (2.0, 3.0):
        assert np.abs(drawn[frame] - drawn[2.5]).max() > 0.05, frame
    pano = tmp_path / "pano.exr"
    result = runner.invoke(app, ["render", str(path), "--out", str(pano), "--projection",
                                 "equirect", "--width", "64", "--time", "6.5"])  # fmt: skip
    assert result.exit_code == 0, result.output
    expected = panorama_video.equirect_frame(glowing.at(2.5), panorama_video.Frame360(64, 32),
                                             torch.zeros(3))  # fmt: skip
    assert np.abs(images.read_image(pano) - expected).max() <= 1e-6


def assert_same(a: Gaussians, b: Gaussians) -> None:
    for name, tensor in a.tensors().items():
        assert torch.equal(tensor, b.tensors()[name]), name


def test_a_video_shows_a_version_2_scene_between_its_frames(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A 30 fps video of an 8 fps scene: a version-2 scene evaluated at each frame's own
    time (8/30 of a frame apart), its spacetime set decoded once for the whole video; a
    version-1 scene holding each timestamp for the frames that show it, each read once."""
    glowing, scene = glowing_wall()
    path = tmp_path / "v2.ply4d"
    ply4d.write(path, scene)
    decoded = []
    monkeypatch.setattr(ply4d, "spacetime_from", lambda a: decoded.append(a) or spacetime_from(a))
    shown = list(camera_paths.gaussians_at(path, camera_paths.video_times(path, 16, 30.0)))
    assert len(decoded) == 1
    for i, g in enumerate(shown):
        assert_same(g, glowing.at(i * 8 / 30 % 4))
    assert all(not torch.equal(a.sh, b.sh) for a, b in itertools.pairwise(shown[:7]))

    stored = [glowing.at(t) for t in range(4)]
    path = tmp_path / "v1.ply4d"
    ply4d.write(path, ply4d.Scene4D(Gaussians.empty(), stored, scene.timestamps, 8.0))
    shown = list(camera_paths.gaussians_at(path, camera_paths.video_times(path, 16, 30.0)))
    held = [0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 0]  # ⌊i · 8 / 30⌋ mod 4
    for g, timestamp in zip(shown, held, strict=True):
        assert_same(g, stored[timestamp])
    pairs = itertools.pairwise(zip(shown, held, strict=True))
    assert all((a is b) == (s == t) for (a, s), (b, t) in pairs)  # each set read once


def test_turntable_video_has_the_frames_and_time_advances(tmp_path: Path) -> None:
    wall = red_wall()
    moved = red_wall()
    moved.means[:, 1] += 100.0  # out of view at t = 1
    empty = Gaussians.empty()
    scene = ply4d.Scene4D(empty, [wall, moved], [0.0, 1.0], 1.0)
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, scene)
    out = tmp_path / "turn.mp4"
    result = runner.invoke(
        app,
        [
            "render",
            str(path),
            "--out",
            str(out),
            "--path",
            "turntable",
            "--frames",
            "4",
            "--width",
            "32",
            "--height",
            "24",
        ],
    )
    assert result.exit_code == 0, result.output
    probe = subprocess.run(
        [
            "ffprobe",
            "-v",
            "error",
            "-count_frames",
            "-select_streams",
            "v:0",
            "-show_entries",
            "stream=nb_read_frames",
            "-of",
            "csv=p=0",
            str(out),
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    assert int(probe.stdout.strip()) == 4
    cams = list(camera_paths.path_cameras("fly-through", 8, 8, 4, radius=2.0))
    assert cams[0].position.tolist() == pytest.approx([0, 0, 0])
    assert float(torch.linalg.norm(cams[2].position)) == pytest.approx(4.0)
    with pytest.raises(ValueError, match="turntable"):
        list(camera_paths.path_cameras("orbit", 8, 8, 4, radius=1.0))


def test_turntable_turns_right_and_its_orbit_stands_to_the_left() -> None:
    """One turntable for `pano4d render --path turntable` and train's preview: the view's
    centre sweeps the panorama left to right (increasing u: the image's right is the
    viewer's right), and on an orbit each camera stands to the left of where it looks."""
    cams = camera_paths.turntable(32, 24, 8)
    forwards = torch.stack([c.forward for c in cams])
    assert torch.allclose(forwards[:, 2], torch.zeros(8, dtype=forwards.dtype), atol=1e-12)
    u, _ = dir_to_equirect(forwards, 360, 180)
    assert torch.allclose(torch.diff(u) % 360, torch.full((7,), 45.0, dtype=u.dtype))
    # Turning right: each camera's right (its x axis) leans towards where the next one looks.
    for cam, after in itertools.pairwise(cams):
        assert float(cam.R[0] @ after.forward) > 0.5
    orbit = camera_paths.turntable(32, 24, 8, orbit=2.0)
    for cam, still in zip(orbit, cams, strict=True):
        assert torch.allclose(cam.forward, still.forward)
        assert float(torch.linalg.norm(cam.position)) == pytest.approx(2.0)
        assert float(cam.R[0] @ cam.position) == pytest.approx(-2.0)  # left of its view


def test_a_scene_is_drawn_in_the_mode_its_file_records(tmp_path: Path) -> None:
    """`pano4d render` (a perspective still and a 360° one, written as .exr so nothing is
    quantised) draws an antialiased .ply4d through the antialiased filter, and the same sets
    in a classic file classic: far, sub-pixel Gaussians, where the two modes differ most."""
    gen = torch.Generator().manual_seed(3)
    n = 400
    dots = Gaussians(
        torch.cat([torch.full((n, 1), 40.0), 16 * torch.rand(n, 2, generator=gen) - 8], dim=1),
        torch.full((n, 3), -4.0), torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        torch.full((n,), 2.0), torch.rand(n, 1, 3, generator=gen),
    )  # fmt: skip
    cam = Camera.from_fov(60.0, 64, 48)
    drawn = {}
    for antialiased in (False, True):
        scene = tmp_path / f"dots_{antialiased}.ply4d"
        ply4d.write(scene, ply4d.Scene4D(Gaussians.empty(0), [dots], [0.0], fps=8.0,
                                         antialiased=antialiased))  # fmt: skip
        out = tmp_path / f"still_{antialiased}.exr"
        camera = '{"position": [0, 0, 0], "forward": [1, 0, 0], "fov_deg": 60}'
        result = runner.invoke(app, ["render", str(scene), "--out", str(out), "--width", "64",
                                     "--height", "48", "--camera", camera])  # fmt: skip
        assert result.exit_code == 0, result.output
        want = render(dots, cam, antialiased=antialiased).rgb.clamp(0, 1).numpy()
        assert np.abs(images.read_image(out) - want).max() <= 1e-6, antialiased
        drawn[antialiased] = want
        pano = tmp_path / f"pano_{antialiased}.exr"
        result = runner.invoke(app, ["render", str(scene), "--out", str(pano), "--projection",
                                     "equirect", "--width", "128"])  # fmt: skip
        assert result.exit_code == 0, result.output
        frame = panorama_video.Frame360(128, 64)
        expected = panorama_video.equirect_frame(dots, frame, torch.zeros(3),
                                                 antialiased=antialiased)  # fmt: skip
        assert np.abs(images.read_image(pano) - expected).max() <= 1e-6, antialiased
    assert np.abs(drawn[True] - drawn[False]).max() > 0.1  # the modes differ here
