"""360° stills and videos of a scene for headsets: equirectangular mono and omnidirectional
stereo (ODS), drawn by the public ``render()`` in perspective pieces and resampled onto the
equirect (``pano4d render --projection equirect [--stereo top-bottom]``).

Mono: the six faces of a cube at the eye; each equirect pixel samples the face its
direction falls on (bilinear, ``resample.perspective_sampler``). Faces carry a margin of
``FACE_MARGIN`` pixels, so the taps of a direction on a face's edge lie inside it.

Stereo (ODS, top-bottom, left eye on top): each column of an eye's equirect has its own eye,
on the circle of diameter ``ipd`` round the viewpoint, to the left (left eye) or the right
of the column's horizontal direction: what a head turned towards that column sees. A piece
one strip of columns wide (``ods_strips``) and one band of latitude high (``ods_bands``) is
drawn by one perspective camera at the eye of the strip's centre column (``ods_pieces``).
For a column δ from the centre that eye is off by r·δ (r = ipd / 2) along the centre
column's horizontal direction: along the ray at the horizon (no shift), across it by
r·δ·sin(latitude) above and below. Strips of ``STRIP_COLUMNS`` columns keep that under a
pixel for points beyond the eye height at the default IPD, at any width, where it is largest
(at ``FADE_FROM_DEG``); other bands take strips as much wider as their stray is smaller
(``band_shift_share``): 3,832 pieces a 4096×4096 frame instead of 6,144. The IPD fades to 0
between ``FADE_FROM_DEG`` and the poles (``ipd_fade``): near a pole every column looks the same
way, and eyes circling under one direction would swap sides as the head turns. A piece's
eye takes the IPD at its band's centre, so bands are ``FADE_BAND_ROWS`` rows where it fades.

Every ``render()`` draws at most ``PIECE_SIDE``² pixels (``Camera.window``) and only the
Gaussians that can reach its piece (``GaussianSpheres.reaching``), so no buffer comes near
lavapipe's 128 MiB storage binding at any frame size up to ``MAX_SIZE``, and a narrow ODS
piece costs what its own Gaussians cost.

Videos carry Google's Spherical Video (V1) metadata, written by ExifTool
(``write_spherical_metadata``), and switch to H.265 where H.264's common levels end
(``video_codec``).
"""

from __future__ import annotations

import itertools
import math
import shutil
import subprocess
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from pano4d import camera_paths, images, ply4d
from pano4d.camera import Camera, look_rotation
from pano4d.errors import InputError
from pano4d.fsutil import atomic_path
from pano4d.gaussians import Gaussians
from pano4d.nerfstudio_path import CameraPath
from pano4d.progress import Bars
from pano4d.renderer import render
from pano4d.resample import perspective_sampler
from pano4d.smoothstep import smoothstep
from pano4d.sphere import equirect_to_dir

MAX_SIZE = 8192  # the largest side of a 360° frame (8K equirect, 8192×8192 stereo)
# 1024² pixels a render: 4096 tiles, so lavapipe's 128 MiB binding (33M tile intersections)
# holds 8000 Gaussians a tile on average; the frame's own buffers take 20 MiB.
PIECE_SIDE = 1024
FACE_MARGIN = 2  # pixels round a cube face beyond its 90°
STRIP_COLUMNS = 64  # ODS strip width (columns; 5.6° at 4096 wide)
MIN_STRIPS = 16  # ...and at least this many strips round the turn (22.5° each at most)
FADE_FROM_DEG = 60.0  # latitude where the stereo IPD starts fading to 0 at the pole
# ODS band height where the IPD fades: at 4096×4096 (22 bands a side) a step between bands
# moves a point at the eye height's distance by under a pixel (6.8 % of the IPD at most).
FADE_BAND_ROWS = 16
MIN_FADE_BANDS = 4  # ...and at least this many bands in each fade zone
MIDDLE_BANDS = 4  # ODS bands between the fade zones (30° each)
BAND_PIXELS = 1 << 20  # equirect pixels resampled at once (bounds the sampler tables)
# A camera's eye height, read as 1.6 m (the layout depth prior's `camera_height`), and the
# average adult IPD: the default IPD is 0.064 / 1.6 of the eye height (``default_ipd``).
EYE_HEIGHT_M, IPD_M = 1.6, 0.064
# H.264 level 5.2's largest frame (MaxFS, in 16×16 macroblocks: 4096×2304); larger frames
# are written as H.265, which headsets decode up to 8K.
H264_MAX_MACROBLOCKS = 36864

CUBE_AXES = torch.tensor(
    [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=torch.float64
)


class PanoramaArgumentError(InputError, ValueError):
    """A size, stereo mode or IPD that a 360° render cannot use."""


@dataclass(frozen=True)
class Frame360:
    """A 360° frame: its whole size, and with ``stereo`` the two eyes top-bottom (left on
    top), each ``width`` × ``height / 2``, their eyes ``ipd`` apart (scene units)."""

    width: int
    height: int
    stereo: bool = False
    ipd: float | None = None  # stereo: None until ``render_360`` picks ``default_ipd``

    def __post_init__(self) -> None:
        w, h = self.width, self.height
        if not (0 < w <= MAX_SIZE and 0 < h <= MAX_SIZE):
            raise PanoramaArgumentError(
                f"--width/--height {w}x{h}: a 360° frame's sides must be 1 to {MAX_SIZE}"
            )
        if not self.stereo and w != 2 * h:
            raise PanoramaArgumentError(
                f"--width/--height {w}x{h}: a mono equirect frame must be 2:1 (e.g. 4096x2048)"
            )
        if self.stereo and h % 2:
            raise PanoramaArgumentError(
                f"--height {h}: a top-bottom stereo frame holds two eyes, so its height is even"
            )
        if self.ipd is not None and not (self.ipd > 0 and math.isfinite(self.ipd)):
            raise PanoramaArgumentError(
                f"--ipd {self.ipd}: the distance between the eyes must be positive (scene units)"
            )

    @property
    def eye_height(self) -> int:
        return self.height // 2 if self.stereo else self.height

    @property
    def pieces(self) -> int:
        """How many pieces a frame is drawn in (a progress bar's unit): cube faces, or ODS
        strips of a band."""
        if not self.stereo:
            return 6
        return 2 * sum(len(strips) for _, strips in ods_pieces(self.width, self.eye_height))


# --- drawing ---------------------------------------------------------------------------------
class GaussianSpheres:
    """A set of Gaussians with the bound of each one's reach (its 3σ sphere), worked
    out once for the many pieces of a frame, and the rasteriser mode they are drawn in (the
    scene's, ``ply4d.Scene4D.antialiased``)."""

    def __init__(self, g: Gaussians, antialiased: bool = False) -> None:
        self.g = g.detach().to("cpu")
        self.antialiased = antialiased
        self.means = self.g.means.to(torch.float64)
        self.reach = 3.0 * self.g.log_scales.to(torch.float64).exp().amax(dim=-1)

    def reaching(self, camera: Camera) -> Gaussians:
        """The Gaussians whose 3σ sphere reaches the camera's frustum widened by two pixels
        (the rasteriser's low-pass and rounding). The camera draws the same pixels from them
        as from the whole set, but where the rasteriser's clamped Jacobian (docs/rasterizer.md,
        "Project") splats a Gaussian from outside the whole view into its border pixels."""
        pc = self.means @ camera.R.T + camera.t
        keep = pc[:, 2] > -self.reach
        for axis, (focal, centre, size) in enumerate(
            ((camera.fx, camera.cx, camera.width), (camera.fy, camera.cy, camera.height))
        ):
            lo, hi = (-2.0 - centre) / focal, (size + 2.0 - centre) / focal
            # Signed distances to the two side planes through the centre (x = lo·z, x = hi·z).
            keep &= (pc[:, axis] - hi * pc[:, 2]) <= self.reach * math.hypot(1.0, hi)
            keep &= (lo * pc[:, 2] - pc[:, axis]) <= self.reach * math.hypot(1.0, lo)
        return self.g[keep]


def draw(spheres: GaussianSpheres, camera: Camera, backend: str) -> torch.Tensor:
    """The camera's image (3, H, W), drawn in windows of at most ``PIECE_SIDE``²."""
    image = torch.zeros(3, camera.height, camera.width)
    for y0 in range(0, camera.height, PIECE_SIDE):
        for x0 in range(0, camera.width, PIECE_SIDE):
            h, w = min(PIECE_SIDE, camera.height - y0), min(PIECE_SIDE, camera.width - x0)
            window = camera.window(x0, y0, w, h)
            seen = spheres.reaching(window)
            rgb = render(seen, window, backend=backend, antialiased=spheres.antialiased).rgb
            image[:, y0 : y0 + h, x0 : x0 + w] = rgb.detach().cpu().permute(2, 0, 1)
    return image


def band_directions(width: int, height: int, rows: range, cols: range) -> torch.Tensor:
    """Unit directions (len(rows), len(cols), 3), float64, of those equirect pixel centres."""
    v = torch.arange(rows.start, rows.stop, dtype=torch.float64) + 0.5
    u = torch.arange(cols.start, cols.stop, dtype=torch.float64) + 0.5
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    return equirect_to_dir(uu, vv, width, height)


# --- mono: cube faces ---------------------------------------------------------------------
def face_size(width: int) -> int:
    """A cube face's side (without margin) whose central pixel spans an equirect pixel of a
    ``width``-wide panorama (2 / side = 2π / width)."""
    return math.ceil(width / math.pi)


def face_cameras(width: int, eye: torch.Tensor) -> list[Camera]:
    """The six cube-face cameras at ``eye`` (order of ``CUBE_AXES``), each 90° plus its
    margin of ``FACE_MARGIN`` pixels."""
    n = face_size(width)
    side = n + 2 * FACE_MARGIN
    fov = math.degrees(2 * math.atan(side / n))
    return [Camera.from_fov(fov, side, side, eye, axis) for axis in CUBE_AXES]


def mono_equirect(
    spheres: GaussianSpheres,
    width: int,
    height: int,
    eye: torch.Tensor,
    backend: str = "wgpu",
    on_piece: Callable[[], None] = lambda: None,
) -> torch.Tensor:
    """The equirect (H, W, 3) seen from ``eye``, resampled from the six cube faces."""
    cams = face_cameras(width, eye)
    faces = []
    for cam in cams:
        faces.append(draw(spheres, cam, backend))
        on_piece()
    return faces_to_equirect(faces, cams, width, height)


def faces_to_equirect(
    faces: list[torch.Tensor], cams: list[Camera], width: int, height: int
) -> torch.Tensor:
    """The equirect (H, W, 3) from the images (3, h, w) of ``face_cameras``' six cameras:
    each pixel sampled from the face its direction falls on."""
    out = torch.zeros(3, height, width)
    rows_per_band = max(1, BAND_PIXELS // width)
    for r0 in range(0, height, rows_per_band):
        rows = range(r0, min(height, r0 + rows_per_band))
        dirs = band_directions(width, height, rows, range(width)).reshape(-1, 3)
        face = torch.argmax(dirs @ CUBE_AXES.T, dim=-1)
        band = out[:, rows.start : rows.stop].reshape(3, -1)
        for f, (cam, image) in enumerate(zip(cams, faces, strict=True)):
            on_face = face == f
            if on_face.any():
                band[:, on_face] = perspective_sampler(dirs[on_face], cam).apply(image)
        out[:, rows.start : rows.stop] = band.reshape(3, len(rows), width)
    return out.permute(1, 2, 0)


# --- stereo: omnidirectional stereo --------------------------------------------------------
def ipd_fade(latitude: torch.Tensor | float) -> torch.Tensor:
    """The share of the IPD used at a latitude (radians): 1 up to ``FADE_FROM_DEG``, 0 at
    the poles, a smooth ramp between."""
    lat = torch.as_tensor(latitude, dtype=torch.float64).abs()
    return 1.0 - smoothstep(math.radians(FADE_FROM_DEG), math.pi / 2, lat)


def ods_strips(width: int, shift_share: float = 1.0) -> list[range]:
    """The columns of an eye's equirect in the strips one ODS camera draws each, in a band
    whose eyes stray from the strip's centre eye by ``shift_share`` of the most any band's do
    (``band_shift_share``): a smaller stray allows wider strips for the same error."""
    wanted = math.ceil(shift_share * width / STRIP_COLUMNS)
    count = min(width, max(MIN_STRIPS, wanted))
    edges = [round(k * width / count) for k in range(count + 1)]
    return [range(a, b) for a, b in itertools.pairwise(edges)]


def band_shift_share(rows: range, height: int) -> float:
    """How far a column's eye strays across its ray from the strip centre's, in this band of
    rows, as a share of the most in any band: r·δ·sin(latitude) with r faded by ``ipd_fade``,
    so ∝ fade·|sin latitude|, largest at ``FADE_FROM_DEG``. Small near the horizon (the
    stray runs along the ray there) and near the poles (the IPD fades)."""
    v = torch.arange(rows.start, rows.stop + 1, dtype=torch.float64)
    latitude = math.pi * (0.5 - v / height)
    stray = ipd_fade(latitude) * latitude.sin().abs()
    return float(stray.max()) / math.sin(math.radians(FADE_FROM_DEG))


def ods_pieces(width: int, height: int) -> list[tuple[range, list[range]]]:
    """Every band of an eye's equirect (``ods_bands``) with its strips (``ods_strips``)."""
    return [(rows, ods_strips(width, band_shift_share(rows, height))) for rows in ods_bands(height)]


def ods_bands(height: int) -> list[range]:
    """The rows of an eye's equirect in the bands one ODS camera draws each:
    ``MIDDLE_BANDS`` between ±``FADE_FROM_DEG``, ``FADE_BAND_ROWS`` rows (at least
    ``MIN_FADE_BANDS`` bands) in each zone where the IPD fades."""
    fade = 90.0 - FADE_FROM_DEG
    n = max(MIN_FADE_BANDS, math.ceil(height * fade / 180.0 / FADE_BAND_ROWS))
    lats = [90.0 - fade * i / n for i in range(n)]
    lats += [FADE_FROM_DEG - 2 * FADE_FROM_DEG * i / MIDDLE_BANDS for i in range(MIDDLE_BANDS)]
    lats += [-FADE_FROM_DEG - fade * i / n for i in range(n + 1)]
    edges = sorted({round(height * (0.5 - lat / 180.0)) for lat in lats})
    return [range(a, b) for a, b in itertools.pairwise(edges)]


def piece_camera(dirs: torch.Tensor, eye: torch.Tensor, pixels_per_radian: float) -> Camera:
    """A camera at ``eye`` looking at the middle of ``dirs`` (h, w, 3) whose image holds
    all of them with ``FACE_MARGIN`` pixels to spare, its principal point centred (the
    rasteriser's EWA clamp assumes it), its pixels as fine as the equirect's."""
    forward = dirs.reshape(-1, 3).mean(dim=0)
    R = look_rotation(forward)
    local = dirs.reshape(-1, 3) @ R.T
    tan_x = (local[:, 0] / local[:, 2]).abs().max().item()
    tan_y = (local[:, 1] / local[:, 2]).abs().max().item()
    width = 2 * (math.ceil(tan_x * pixels_per_radian) + FACE_MARGIN)
    height = 2 * (math.ceil(tan_y * pixels_per_radian) + FACE_MARGIN)
    K = torch.tensor(
        [[pixels_per_radian, 0, width / 2], [0, pixels_per_radian, height / 2], [0, 0, 1]],
        dtype=torch.float64,
    )
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3], w2c[:3, 3] = R, -R @ eye
    return Camera(K, w2c, width, height)


def ods_eye(
    spheres: GaussianSpheres,
    width: int,
    height: int,
    centre: torch.Tensor,
    ipd: float,
    side: int,
    backend: str = "wgpu",
    on_piece: Callable[[], None] = lambda: None,
) -> torch.Tensor:
    """One eye's ODS equirect (H, W, 3) round ``centre``: ``side`` +1 the left eye, −1 the
    right. Each column's eye stands ipd/2 to that side of its horizontal direction."""
    out = torch.zeros(3, height, width)
    pixels_per_radian = 1.0 / min(2 * math.pi / width, math.pi / height)
    for rows, strips in ods_pieces(width, height):
        latitude = math.pi * (0.5 - (rows.start + rows.stop) / (2 * height))
        radius = 0.5 * ipd * float(ipd_fade(latitude))
        for cols in strips:
            phi = 2 * math.pi * ((cols.start + cols.stop) / (2 * width) - 0.5)
            # The viewer's left of the horizontal direction (cos φ, −sin φ, 0) is up × it.
            left = torch.tensor([math.sin(phi), math.cos(phi), 0.0], dtype=torch.float64)
            dirs = band_directions(width, height, rows, cols)
            cam = piece_camera(dirs, centre + side * radius * left, pixels_per_radian)
            image = draw(spheres, cam, backend)
            values = perspective_sampler(dirs, cam).apply(image)
            out[:, rows.start : rows.stop, cols.start : cols.stop] = values
            on_piece()
    return out.permute(1, 2, 0)


def equirect_frame(
    g: Gaussians,
    frame: Frame360,
    eye: torch.Tensor,
    backend: str = "wgpu",
    on_piece: Callable[[], None] = lambda: None,
    antialiased: bool = False,
) -> np.ndarray:
    """One 360° frame (H, W, 3) in [0, 1] seen from ``eye``: mono, or both eyes top-bottom
    (left on top), drawn in the rasteriser mode ``antialiased`` says (the scene's)."""
    eye = torch.as_tensor(eye, dtype=torch.float64)
    spheres = GaussianSpheres(g, antialiased)
    if not frame.stereo:
        rgb = mono_equirect(spheres, frame.width, frame.height, eye, backend, on_piece)
    else:
        h = frame.eye_height
        ipd = default_ipd(g, eye) if frame.ipd is None else frame.ipd
        rgb = torch.cat([
            ods_eye(spheres, frame.width, h, eye, ipd, +1, backend, on_piece),
            ods_eye(spheres, frame.width, h, eye, ipd, -1, backend, on_piece),
        ])  # fmt: skip
    return camera_paths.to_image(rgb)


def default_ipd(g: Gaussians, eye: torch.Tensor) -> float:
    """0.064 / 1.6 of the eye's height above the ground: the median height below ``eye`` of
    the Gaussians more than 30° below the horizon (the floor or the ground, 1.6 scene units
    for the layout depth prior's default ``camera_height``). With none there, the scene's
    units are read as metres (0.064)."""
    rel = g.means.detach().to(torch.float64) - eye
    below = rel[:, 2] < -math.tan(math.radians(30.0)) * torch.linalg.norm(rel[:, :2], dim=-1)
    if int(below.sum()) < 16:
        return IPD_M
    return IPD_M / EYE_HEIGHT_M * float((-rel[below, 2]).median())


# --- files ---------------------------------------------------------------------------------
def video_codec(width: int, height: int) -> str:
    """'h264' where H.264's common levels hold the frame, else 'h265'."""
    macroblocks = math.ceil(width / 16) * math.ceil(height / 16)
    return "h264" if macroblocks <= H264_MAX_MACROBLOCKS else "h265"


def write_spherical_metadata(path: Path, stereo: bool) -> None:
    """Tag an MP4 as an equirectangular 360° video (stereo: top-bottom) with Google's
    Spherical Video V1 XMP, which YouTube, headset players and ffprobe read. ExifTool writes
    it; ffmpeg reads the tags only when all of Spherical, Stitched, ProjectionType and
    StitchingSoftware are there."""
    exiftool = shutil.which("exiftool")
    if exiftool is None:
        raise InputError(
            f"{path}: exiftool is not on PATH; install it (apt-get install "
            "libimage-exiftool-perl, as `make setup` does) to tag 360° videos"
        )
    tags = {
        "Spherical": "true",
        "Stitched": "true",
        "ProjectionType": "equirectangular",
        "StitchingSoftware": "pano4d",
        "StereoMode": "top-bottom" if stereo else "mono",
    }
    args = [f"-XMP-GSpherical:{key}={value}" for key, value in tags.items()]
    done = subprocess.run(
        [exiftool, "-q", "-overwrite_original", *args, str(path)], capture_output=True, text=True
    )
    if done.returncode != 0:
        raise InputError(f"{path}: exiftool failed: {' '.join(done.stderr.split())}")


def eye_path(scene: Path, path: str | None, frames: int) -> list[torch.Tensor]:
    """Where the eye stands in each frame: the panorama's viewpoint, or along ``--path
    fly-through`` from it. A turntable turns a view that a 360° frame holds all round."""
    start = viewpoint(scene)
    if path is None:
        return [start] * frames
    if path != "fly-through":
        raise PanoramaArgumentError(
            f"--path {path!r} with --projection equirect: a 360° frame already looks every "
            "way; use --path fly-through (or no --path for the panorama's viewpoint)"
        )
    cams = camera_paths.fly_through(2, 2, frames, camera_paths.path_radius(scene))
    return [start + cam.position for cam in cams]


def viewpoint(scene: Path) -> torch.Tensor:
    """The panorama's camera position of a .ply4d (the origin for a plain .ply)."""
    if scene.suffix == ".ply4d":
        position = ply4d.open(scene).header["camera"]["position"]
        return torch.tensor(position, dtype=torch.float64)
    return torch.zeros(3, dtype=torch.float64)


def loop_frames(scene: Path, fps: float) -> int:
    """Frames of one loop of the scene's time at ``fps`` (at least one)."""
    num_times, scene_fps = camera_paths.scene_clock(scene)
    return max(1, ply4d.loop_samples(num_times, scene_fps, fps))


def render_360(
    scene: Path,
    out: Path,
    frame: Frame360,
    time: float = 0.0,
    path: str | None = None,
    frames: int | None = None,
    fps: float = 30.0,
    backend: str = "wgpu",
    bars: Bars | None = None,
) -> Frame360:
    """Write ``out``: a 360° still (.png, .jpg or .exr; the scene at ``time``, in frames) or
    an MP4 of ``frames`` frames at ``fps`` (default: one loop of the scene's time), whose
    time starts at ``time`` and follows the scene's own rate (``camera_paths.video_times``),
    tagged as spherical. Progress goes to ``bars``, one step a piece.
    Returns the frame as drawn (a stereo frame with its IPD resolved)."""
    video = out.suffix.lower() == ".mp4"
    if path is not None and not video:
        raise PanoramaArgumentError(f"--path makes a video: --out {out} must be an .mp4")
    count = (loop_frames(scene, fps) if frames is None else frames) if video else 1
    antialiased = camera_paths.scene_antialiased(scene)
    eyes = eye_path(scene, path, count) if video else [viewpoint(scene)]
    if frame.stereo and frame.ipd is None:
        frame = replace(frame, ipd=default_ipd(camera_paths.load_gaussians(scene, 0.0), eyes[0]))
    task = (bars or Bars(enabled=False)).task("360° video" if video else "360° still",
                                              count * frame.pieces)  # fmt: skip
    if not video:
        g = camera_paths.load_gaussians(scene, time)
        still = equirect_frame(g, frame, eyes[0], backend, task.advance, antialiased)
        images.write_image(out, still)
        return frame

    times = camera_paths.video_times(scene, count, fps, start=time)
    write_360_video(scene, out, frame, eyes, times, fps, backend, task.advance)
    return frame


def render_360_path(
    scene: Path,
    path: CameraPath,
    out: Path,
    stereo: bool,
    ipd: float | None,
    backend: str = "wgpu",
    bars: Bars | None = None,
) -> Frame360:
    """Write ``out``: the 360° video of an equirectangular ``camera_path.json`` at its size
    and fps, the eye at each entry's position, the scene at each entry's time
    (``CameraPath.scene_times``); world-aligned, as every 360° frame here."""
    if out.suffix.lower() != ".mp4":
        raise PanoramaArgumentError(f"a camera path makes a video: --out {out} must be an .mp4")
    try:
        frame = Frame360(path.width, path.height, stereo, ipd)
    except PanoramaArgumentError as e:  # its message names the options, not the file's keys
        size = f"render_width × render_height {path.width}x{path.height}"
        raise PanoramaArgumentError(f"{path.source}: {size}: {str(e).split(': ', 1)[1]}") from e
    eyes = path.positions()
    if frame.stereo and frame.ipd is None:
        frame = replace(frame, ipd=default_ipd(camera_paths.load_gaussians(scene, 0.0), eyes[0]))
    num_times, scene_fps = camera_paths.scene_clock(scene)
    times = path.scene_times(num_times, scene_fps)
    task = (bars or Bars(enabled=False)).task("360° video", len(eyes) * frame.pieces)
    write_360_video(scene, out, frame, eyes, times, path.fps, backend, task.advance)
    return frame


def write_360_video(
    scene: Path,
    out: Path,
    frame: Frame360,
    eyes: list[torch.Tensor],
    times: list[float],
    fps: float,
    backend: str,
    advance: Callable[[], None],
) -> None:
    """The 360° video of the eye at each of ``eyes`` and the scene at each of ``times``,
    tagged as spherical before it takes its name: no reader sees an untagged 360° video."""
    antialiased = camera_paths.scene_antialiased(scene)

    def rendered() -> Iterator[np.ndarray]:
        shown = camera_paths.gaussians_at(scene, times)
        for g, eye in zip(shown, eyes, strict=True):
            yield equirect_frame(g, frame, eye, backend, advance, antialiased)

    with atomic_path(out) as tmp:
        images.write_video(tmp, rendered(), fps, codec=video_codec(frame.width, frame.height))
        write_spherical_metadata(tmp, frame.stereo)
