"""360° stills and videos (`pano4d render --projection equirect [--stereo top-bottom]`):
the mono equirect against perspective renders of the same directions, ODS disparity
against its geometry, pieces that join without a seam, time at the scene's own rate, and
the spherical metadata as ffprobe reads it back."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
from pano4d_process import pano4d

from pano4d import images, panorama_video, ply4d, sphere
from pano4d.camera import Camera
from pano4d.gaussians import SH_C0, Gaussians, rgb_to_sh_dc
from pano4d.metrics import psnr
from pano4d.renderer import render
from pano4d.resample import equirect_to_perspective
from pano4d.spacetime import SpacetimeGaussians, TimeModel


def shell(n: int = 4000, radius: float = 5.0, shift: float = 0.0) -> Gaussians:
    """Gaussians on a sphere round the origin, coloured by direction (``shift`` adds to red):
    every direction of a 360° frame sees a different colour."""
    d = sphere.fibonacci_directions(n).float()
    rgb = 0.5 + 0.4 * torch.stack(
        [torch.sin(3 * d[:, 0] + 1), torch.cos(4 * d[:, 1]), torch.sin(5 * d[:, 2] + 0.3)], -1
    )
    rgb[:, 0] = (rgb[:, 0] + shift).clamp(0, 1)
    size = 0.7 * radius * math.sqrt(4 * math.pi / n)
    return Gaussians(
        d * radius, torch.full((n, 3), math.log(size)), torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        torch.full((n,), 4.0), rgb_to_sh_dc(rgb)[:, None, :],
    )  # fmt: skip


def dot(position: tuple[float, float, float], size: float = 0.01) -> Gaussians:
    """One small, opaque, white Gaussian."""
    return Gaussians(
        torch.tensor([position]), torch.full((1, 3), math.log(size)),
        torch.tensor([[1.0, 0, 0, 0]]), torch.tensor([8.0]), torch.full((1, 1, 3), 3.0),
    )  # fmt: skip


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two timestamps at 2 fps (half a second each): red is brighter at t = 1."""
    path = tmp_path_factory.mktemp("pano") / "scene.ply4d"
    ply4d.write(path, ply4d.Scene4D(Gaussians.empty(), [shell(), shell(shift=0.4)], [0, 0.5], 2))
    return path


@pytest.fixture(scope="module")
def blue_then_red(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two timestamps at 2 fps, all blue, then all red: the colour says the time."""
    path = tmp_path_factory.mktemp("pano") / "blue_then_red.ply4d"
    blue, red = shell(1000), shell(1000)
    blue.sh[:, 0] = rgb_to_sh_dc(torch.tensor([0.2, 0.2, 0.8]))
    red.sh[:, 0] = rgb_to_sh_dc(torch.tensor([0.8, 0.2, 0.2]))
    ply4d.write(path, ply4d.Scene4D(Gaussians.empty(), [blue, red], [0, 0.5], 2))
    return path


@pytest.fixture(scope="module")
def blue_to_red(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``blue_then_red`` as one spacetime set (format version 2): blue at frame 0, red at
    frame 1, and between them (and back) red and blue follow ∓0.3·cos(π·t)."""
    path = tmp_path_factory.mktemp("pano") / "blue_to_red.ply4d"
    g = shell(1000)
    g.sh[:, 0] = rgb_to_sh_dc(torch.tensor([0.5, 0.2, 0.5]))
    fading = SpacetimeGaussians.still(TimeModel(2, 1, 0), g)
    fading.colour_terms[:, 0] = torch.tensor([-0.3, 0.0, 0.3]) / SH_C0  # cos₁ of each channel
    ply4d.write(path, ply4d.Scene4D(Gaussians.empty(), fading, [0, 0.5], 2))
    return path


def test_mono_equirect_shows_what_perspective_views_of_each_direction_show() -> None:
    """Up to splatting's own difference between two cameras seeing a Gaussian at different
    angles (a cube corner is 55° off each face's axis): small Gaussians, ≥ 30 dB."""
    g = shell(16000)
    pano = panorama_video.equirect_frame(g, panorama_video.Frame360(256, 128), torch.zeros(3))
    assert pano.shape == (128, 256, 3)
    as_image = torch.from_numpy(pano).permute(2, 0, 1)
    # Ahead, across the 0°/360° seam (behind), straight up and down, and between cube faces.
    for forward in [(1, 0, 0), (-1, 0.01, 0), (0, 0, 1), (0, 0, -1), (1, 1, 1), (-1, 1, -0.6)]:
        cam = Camera.from_fov(60, 64, 48, (0, 0, 0), forward)
        direct = render(g, cam).rgb.clamp(0, 1).permute(2, 0, 1)
        assert psnr(equirect_to_perspective(as_image, cam), direct) >= 30.0, forward


def test_ods_disparity_is_what_its_geometry_predicts() -> None:
    """A point at distance D ahead on the horizon: the left eye's column whose eye (ipd/2 to
    its left) looks through it is at longitude asin(ipd / 2D), to the right; the right eye's
    at the same angle to the left. Within a tenth of a pixel at 512 wide."""
    D, ipd, width = 2.0, 0.4, 512
    frame = panorama_video.Frame360(width, width, stereo=True, ipd=ipd)
    both = panorama_video.equirect_frame(dot((D, 0.0, 0.0)), frame, torch.zeros(3))
    half = width // 2
    expected = width * (math.asin(ipd / (2 * D)) / (2 * math.pi))
    for eye, sign in ((both[:half], +1), (both[half:], -1)):
        light = eye.sum(-1)
        u = (light * (np.arange(width) + 0.5)).sum() / light.sum()
        v = (light * (np.arange(half) + 0.5)[:, None]).sum() / light.sum()
        assert u == pytest.approx(width / 2 + sign * expected, abs=0.1)
        assert v == pytest.approx(half / 2, abs=0.1)


def test_the_ipd_fades_to_nothing_at_the_poles() -> None:
    fade = panorama_video.ipd_fade(torch.tensor([0.0, 59.0, 75.0, 89.0, 90.0, -90.0]).deg2rad())
    assert fade[:2].tolist() == [1.0, 1.0] and fade[2] == pytest.approx(0.5)
    assert fade[3] < 0.01 and fade[4:].tolist() == [0.0, 0.0]
    # Both eyes see a point near the zenith where they see it: its disparity is a small
    # part of the same point's at the horizon.
    frame = panorama_video.Frame360(128, 128, stereo=True, ipd=0.4)
    dirs = sphere.equirect_directions(128, 64, torch.float64).numpy()
    weight = sphere.equirect_pixel_solid_angle(128, 64).numpy()[:, None]

    def disparity(position: tuple[float, float, float]) -> float:
        both = panorama_video.equirect_frame(dot(position, 0.03), frame, torch.zeros(3))
        left, right = (((eye.sum(-1) * weight)[..., None] * dirs).sum((0, 1))
                       for eye in (both[:64], both[64:]))  # fmt: skip
        cos = left @ right / np.linalg.norm(left) / np.linalg.norm(right)
        return math.acos(min(1.0, cos))

    horizon = disparity((2.0, 0.0, 0.0))
    assert horizon == pytest.approx(2 * math.asin(0.1), rel=0.05)
    assert disparity((0.05, 0.0, 2.0)) < 0.05 * horizon
    bands = panorama_video.ods_bands(2048)  # one eye of a 4096×4096 frame
    assert [r.start for r in bands[1:]] == [r.stop for r in bands[:-1]]
    assert bands[0].start == 0 and bands[-1].stop == 2048
    assert max(len(r) for r in bands if min(r.start, 2048 - r.stop) < 341) <= 16


def test_pieces_join_without_a_seam_and_stay_within_a_piece(monkeypatch) -> None:
    """A camera larger than a piece is drawn in windows of at most PIECE_SIDE² that give
    the pixels one render gives, from only the Gaussians that reach each window. Those give
    the same pixels but where a Gaussian outside the whole view splats in through the
    rasteriser's clamped Jacobian (docs/rasterizer.md, "Project"), a few border pixels."""
    g = shell(2000, radius=3.0)
    cam = Camera.from_fov(100, 300, 280)
    monkeypatch.setattr(panorama_video, "PIECE_SIDE", 160)
    whole = render(g, cam).rgb.permute(2, 0, 1)
    sizes: list[tuple[int, int, int]] = []

    def recording(gs: Gaussians, camera: Camera, **kw: str):  # type: ignore[no-untyped-def]
        sizes.append((camera.width, camera.height, len(gs)))
        return render(gs, camera, **kw)

    monkeypatch.setattr(panorama_video, "render", recording)
    spheres = panorama_video.GaussianSpheres(g)
    pieces = panorama_video.draw(spheres, cam, "wgpu")
    assert len(sizes) == 4 and all(w * h <= panorama_video.PIECE_SIDE**2 for w, h, _ in sizes)
    assert all(n < len(g) for _, _, n in sizes)  # each window drew only what reaches it
    assert psnr(pieces, whole) >= 50.0
    monkeypatch.setattr(panorama_video.GaussianSpheres, "reaching", lambda self, camera: self.g)
    assert (panorama_video.draw(spheres, cam, "wgpu") - whole).abs().max() < 1e-5


@pytest.mark.parametrize("start", [None, "1"])
def test_time_follows_the_scene_rate_in_every_video(
    blue_then_red: Path, tmp_path: Path, start: str | None
) -> None:
    """A 2 fps scene in 8 fps videos: four frames a timestamp (before the fix, one), from
    timestamp 0 (blue), or with `--time 1` from timestamp 1 (red), the loop bringing the
    other after it."""
    turn, pano = tmp_path / "turn.mp4", tmp_path / "pano.mp4"
    args = ("--fps", "8", "--width", "64", "--height", "32", *(("--time", start) if start else ()))
    ran = pano4d("render", blue_then_red, "-o", turn, "--path", "turntable", "--frames", "8", *args)
    assert ran.returncode == 0, ran.stderr
    ran = pano4d("render", blue_then_red, "-o", pano, "--projection", "equirect", *args)
    assert ran.returncode == 0, ran.stderr
    for video in (turn, pano):
        red = [frame[..., 0].mean() - frame[..., 2].mean() for frame in decoded(video)]
        assert len(red) == 8  # the 360° video is one loop of the scene: 2 × 0.5 s at 8 fps
        blue_half, red_half = (red[:4], red[4:]) if start is None else (red[4:], red[:4])
        assert max(blue_half) < -0.3 and min(red_half) > 0.3, (video.name, start, red)


def test_a_version_2_video_moves_between_the_scene_frames(
    blue_to_red: Path, blue_then_red: Path, tmp_path: Path
) -> None:
    """An 8 fps 360° video of a 2 fps scene: a version-2 scene shows every video frame at
    its own time (t = i / 4: four different frames a timestamp), a version-1 scene holds
    each timestamp for four frames."""
    args = ("--projection", "equirect", "--fps", "8", "--width", "64")
    frame = panorama_video.Frame360(64, 32)
    for scene, times in ((blue_to_red, [i / 4 for i in range(8)]),
                         (blue_then_red, [i // 4 for i in range(8)])):  # fmt: skip
        video = tmp_path / f"{scene.stem}.mp4"
        ran = pano4d("render", scene, "-o", video, *args)
        assert ran.returncode == 0, ran.stderr
        source = ply4d.open(scene)
        expected = [panorama_video.equirect_frame(source.at(t), frame, torch.zeros(3))
                    for t in times]  # fmt: skip
        frames = decoded(video)
        assert len(frames) == 8
        for i, (got, want) in enumerate(zip(frames, expected, strict=True)):
            assert np.abs(got - want).mean() < 0.02, (scene.stem, i)
        for i, t in enumerate(times[1:], start=1):
            step = np.abs(frames[i] - frames[i - 1]).mean()
            assert (step > 0.05) == (t != times[i - 1]), (scene.stem, i, step)


def decoded(video: Path) -> list[np.ndarray]:
    probe = ffprobe(video)["streams"][0]
    w, h = probe["width"], probe["height"]
    raw = subprocess.run(
        ["ffmpeg", "-v", "error", "-i", str(video), "-f", "rawvideo", "-pix_fmt", "rgb24", "-"],
        capture_output=True, check=True,
    ).stdout  # fmt: skip
    return list(np.frombuffer(raw, np.uint8).reshape(-1, h, w, 3) / 255.0)


def ffprobe(video: Path) -> dict:  # type: ignore[type-arg]
    out = subprocess.run(
        ["ffprobe", "-v", "error", "-show_streams", "-of", "json", str(video)],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    return json.loads(out)


def test_360_videos_carry_the_spherical_metadata_ffprobe_reads(
    scene_file: Path, tmp_path: Path
) -> None:
    mono, stereo = tmp_path / "mono.mp4", tmp_path / "stereo.mp4"
    ran = pano4d("render", scene_file, "-o", mono, "--projection", "equirect", "--width", "128")
    assert ran.returncode == 0, ran.stderr
    ran = pano4d("render", scene_file, "-o", stereo, "--projection", "equirect", "--stereo",
                 "top-bottom", "--width", "64", "--fps", "2", "--ipd", "0.3")  # fmt: skip
    assert ran.returncode == 0, ran.stderr
    for video, stereo_type in ((mono, "2D"), (stereo, "top and bottom")):
        stream = ffprobe(video)["streams"][0]
        side = {d["side_data_type"]: d for d in stream.get("side_data_list", [])}
        assert side["Spherical Mapping"]["projection"] == "equirectangular", stream
        assert side.get("Stereo 3D", {}).get("type") == stereo_type, stream
    assert (ffprobe(mono)["streams"][0]["width"], ffprobe(mono)["streams"][0]["height"]) == (
        128, 64)  # fmt: skip
    assert ffprobe(stereo)["streams"][0]["height"] == 64  # the whole frame: two 64×32 eyes
    # Beyond H.264's common levels (4096×2304) the video is H.265, tagged as players want it.
    assert panorama_video.video_codec(4096, 2048) == "h264"
    assert panorama_video.video_codec(4096, 4096) == "h265"
    hevc = tmp_path / "hevc.mp4"
    images.write_video(hevc, [np.zeros((32, 64, 3))] * 2, 8.0, codec="h265")
    panorama_video.write_spherical_metadata(hevc, stereo=False)
    stream = ffprobe(hevc)["streams"][0]
    assert stream["codec_name"] == "hevc" and stream["codec_tag_string"] == "hvc1"
    side = {d["side_data_type"]: d for d in stream["side_data_list"]}
    assert side["Spherical Mapping"]["projection"] == "equirectangular"


def test_a_360_still_and_the_default_ipd(scene_file: Path, tmp_path: Path) -> None:
    """The default IPD is 0.064 / 1.6 of the eye's height above the ground."""
    ground = Gaussians(
        torch.cat([torch.rand(200, 2) * 20 - 10, torch.full((200, 1), -3.2)], dim=1),
        torch.zeros(200, 3), torch.tensor([[1.0, 0, 0, 0]]).repeat(200, 1), torch.zeros(200),
        torch.zeros(200, 1, 3),
    )  # fmt: skip
    assert panorama_video.default_ipd(ground, torch.zeros(3)) == pytest.approx(0.128)
    assert panorama_video.default_ipd(ground, torch.tensor([0, 0, 1.6])) == pytest.approx(0.192)
    out = tmp_path / "still.png"
    ran = pano4d("render", scene_file, "-o", out, "--projection", "equirect", "--width", "128",
                 "--time", "1")  # fmt: skip
    assert ran.returncode == 0, ran.stderr
    expected = panorama_video.equirect_frame(
        shell(shift=0.4), panorama_video.Frame360(128, 64), torch.zeros(3)
    )
    assert np.abs(images.read_image(out) - expected).max() <= 0.5 / 255 + 1e-6
