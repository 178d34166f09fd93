"""A 4D scene in the browser, on viser (https://viser.studio): ``pano4d serve`` and ``pano4d web``.

Both hand the scene to viser's own Gaussian-splat renderer (``scene.add_gaussian_splats``) and
play it in viser's prebuilt web client, which ships inside the viser wheel (no Node, no npm):

Both play one loop of the scene's time in samples, ``rate`` a second of scene time (the
scene's own fps unless the user gives one: ``Playback``). A version-2 scene sends its
spacetime set evaluated at each sample's time; a version-1 scene sends each stored set the
samples show once, and each sample shows the timestamp it holds.

- ``serve``: a live viewer. The static set is sent once, each dynamic set once (hidden),
  and the time slider (in frames, one step a sample) and playback only switch which dynamic
  set is visible, so a time change costs the browser a re-sort, not a download.
- ``web``: the same scene as a static folder: a viser recording (``scene.viser``, viser's
  scene serialisation) in which the samples take turns, 1/rate seconds each, the client
  copied verbatim (``viser-client.html``) and an ``index.html`` that opens the client on the
  recording with the start camera as the URL parameters the client reads
  (``playbackPath``, ``initialCameraPosition``/``LookAt``/``Up``/``Fov``).

viser's splats carry one colour per Gaussian, so both show the view-independent colour: the
SH degree-0 term (``0.5 + C0 · dc``, clamped to [0, 1]); higher SH bands are dropped. viser
draws classic (the 0.3 px² low-pass, no compensation): an antialiased scene's sets are sent
baked for it (``share_formats.for_classic_viewers``).
"""

from __future__ import annotations

import contextlib
import html
import io
import json
import math
import shutil
import socket
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

import numpy as np
import torch

from pano4d import ply4d
from pano4d.camera_paths import DEFAULT_FOV_DEG, turntable
from pano4d.errors import InputError
from pano4d.gaussians import SH_C0, Gaussians
from pano4d.raster_torch import quat_to_rotation
from pano4d.share_formats import for_classic_viewers

# The start view: the panorama's viewpoint looking along +x (as `pano4d render` without
# --camera), a 90° horizontal field of view at this aspect (viser's fov is vertical).
START_ASPECT = 16 / 9
# Frames of the turntable preset (one full turn, in place at the viewpoint).
TURNTABLE_FRAMES = 120
TURNTABLE_SECONDS = 12.0
RECORDING_NAME = "scene.viser"
CLIENT_NAME = "viser-client.html"


def viser_module() -> Any:
    """The viser package, or an InputError saying how to install it."""
    try:
        import viser
    except ImportError as e:
        raise InputError(
            "viser is not installed: pip install 'viser>=1.1,<1.2' (or `make setup`)"
        ) from e
    return viser


@dataclass(frozen=True)
class SplatArrays:
    """A set of Gaussians as ``add_gaussian_splats`` takes them (float32 numpy)."""

    centers: np.ndarray  # (N, 3)
    covariances: np.ndarray  # (N, 3, 3)
    rgbs: np.ndarray  # (N, 3) SH degree-0 colour in [0, 1]
    opacities: np.ndarray  # (N, 1)


def splat_arrays(g: Gaussians) -> SplatArrays:
    """World covariance R·diag(s²)·Rᵀ, SH-0 colour and sigmoid opacity of each Gaussian."""
    # The rasteriser's own rotation of raw quaternions (a zero quaternion is the identity).
    rot = quat_to_rotation(g.quats.double())
    scale_sq = torch.exp(2 * g.log_scales.double())
    cov = rot @ torch.diag_embed(scale_sq) @ rot.transpose(1, 2)
    rgb = (0.5 + SH_C0 * g.sh[:, 0, :].double()).clamp(0, 1)
    opacity = torch.sigmoid(g.opacity_logits.double())[:, None]
    return SplatArrays(
        centers=g.means.detach().cpu().numpy().astype(np.float32),
        covariances=cov.cpu().numpy().astype(np.float32),
        rgbs=rgb.cpu().numpy().astype(np.float32),
        opacities=opacity.cpu().numpy().astype(np.float32),
    )


@dataclass(frozen=True)
class StartCamera:
    """A viser camera: position, look-at point, up, vertical fov in radians."""

    position: tuple[float, float, float]
    look_at: tuple[float, float, float]
    up: tuple[float, float, float]
    fov: float

    def url_params(self) -> dict[str, str]:
        """The URL parameters viser's client reads for its start view."""

        def vec(v: tuple[float, float, float]) -> str:
            return ",".join(f"{c:.6g}" for c in v)

        return {
            "initialCameraPosition": vec(self.position),
            "initialCameraLookAt": vec(self.look_at),
            "initialCameraUp": vec(self.up),
            "initialCameraFov": f"{self.fov:.6g}",
        }


def vertical_fov(horizontal_fov_deg: float, aspect: float) -> float:
    """Vertical fov (radians) of a centred pinhole camera with that horizontal fov."""
    return 2 * math.atan(math.tan(math.radians(horizontal_fov_deg) / 2) / aspect)


def start_camera(header: dict[str, Any], aspect: float = START_ASPECT) -> StartCamera:
    """The panorama's viewpoint (the header's camera position), looking along +x, z up."""
    position = tuple(float(v) for v in header.get("camera", {}).get("position", [0, 0, 0]))
    px, py, pz = position
    return StartCamera(
        position=(px, py, pz),
        look_at=(px + 1.0, py, pz),
        up=(0.0, 0.0, 1.0),
        fov=vertical_fov(DEFAULT_FOV_DEG, aspect),
    )


def open_checked(path: Path) -> ply4d.Ply4dFile:
    """Open a ``.ply4d`` and verify every section's checksum: a damaged or truncated file is
    refused (FormatError naming it) before anything is sent or written."""
    scene = ply4d.open(path)
    scene.verify()
    return scene


class WebArgumentError(InputError, ValueError):
    """A --rate that ``pano4d serve`` or ``pano4d web`` cannot use."""


@dataclass(frozen=True)
class Playback:
    """How a page plays one loop of a scene: sample ``i`` shows scene time ``times[i]``
    (frames, ``step`` apart: 1/``rate`` seconds of scene time) through dynamic set
    ``set_of_sample[i]``; ``set_times`` holds the time of each set sent, each once, in the
    order first shown (version 1: the timestamps the samples hold; version 2: every
    sample's own time)."""

    rate: float  # samples a second of scene time
    step: float  # frames between samples: fps / rate
    times: list[float]
    set_times: list[float]
    set_of_sample: list[int]


def playback(scene: ply4d.Ply4dFile, rate: float | None = None) -> Playback:
    """One loop of ``scene`` sampled at ``rate`` samples a second (None: the scene's fps):
    ⌈num_times · rate / fps⌉ samples. A --rate that is not a positive number is refused
    (WebArgumentError) before anything is sent."""
    fps = scene.fps
    rate = fps if rate is None else rate
    if not (math.isfinite(rate) and rate > 0):
        raise WebArgumentError(
            f"--rate {rate:g}: samples a second of scene time must be a positive number "
            f"(the scene plays at {fps:g} fps)"
        )
    times = [
        ply4d.playback_time(i, rate, fps)
        for i in range(ply4d.loop_samples(scene.num_times, fps, rate))
    ]
    shown = [scene.shown_time(t) for t in times]
    set_times = list(dict.fromkeys(shown))
    set_of_time = {t: k for k, t in enumerate(set_times)}
    return Playback(rate, fps / rate, times, set_times, [set_of_time[t] for t in shown])


@dataclass
class SceneNodes:
    """The scene's viser nodes: the static set, one hidden-or-shown node per dynamic set
    sent, and the playback whose samples pick the one shown."""

    static: Any
    dynamic: list[Any]
    playback: Playback

    def show_sample(self, i: int) -> None:
        shown = self.playback.set_of_sample[i]
        for k, handle in enumerate(self.dynamic):
            handle.visible = k == shown


def add_scene(
    server: Any, scene: ply4d.Ply4dFile, plan: Playback, on_set: Callable[[], None]
) -> SceneNodes:
    """Send the static set and the dynamic set of every time in ``plan.set_times`` (only the
    first shown), as a classic viewer must receive them; z is up."""
    server.scene.set_up_direction("+z")

    def add(name: str, g: Gaussians, visible: bool) -> Any:
        a = splat_arrays(for_classic_viewers(g, scene))
        handle = server.scene.add_gaussian_splats(
            name, a.centers, a.covariances, a.rgbs, a.opacities, visible=visible
        )
        on_set()
        return handle

    static = add("/static", scene.static(), True)
    dynamic = [
        add(f"/dynamic/{k:04d}", scene.dynamic(t), k == 0) for k, t in enumerate(plan.set_times)
    ]
    return SceneNodes(static, dynamic, plan)


def set_initial_camera(server: Any, camera: StartCamera) -> None:
    server.initial_camera.position = camera.position
    server.initial_camera.look_at = camera.look_at
    server.initial_camera.up = camera.up
    server.initial_camera.fov = camera.fov


def free_port(host: str) -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


# --- pano4d web ----------------------------------------------------------------------------


def client_html_path() -> Path:
    """viser's prebuilt client (one self-contained HTML file in the wheel)."""
    return Path(viser_module().__file__).parent / "client" / "build" / "index.html"


def index_html(camera: StartCamera, title: str) -> str:
    """A page that opens the client on the recording at the start camera; camera parameters
    given to index.html itself override the start view (e.g. a shared link)."""
    params = {"playbackPath": RECORDING_NAME, **camera.url_params()}
    defaults = json.dumps(params)
    link = html.escape(f"{CLIENT_NAME}?{urlencode(params)}")
    return f"""<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{html.escape(title)}</title>
<script>
  // viser's client reads the recording and the start view from its URL parameters.
  const params = new URLSearchParams({defaults});
  for (const [key, value] of new URLSearchParams(window.location.search)) params.set(key, value);
  window.location.replace("{CLIENT_NAME}?" + params.toString());
</script>
</head>
<body><a href="{link}">Open the scene</a></body>
</html>
"""


def record_scene(scene: ply4d.Ply4dFile, plan: Playback, on_set: Callable[[], None]) -> bytes:
    """The scene as a viser recording: all sets at time 0 (the first sample shown), then
    one sample every 1/rate seconds, so the client's playback bar is the timeline."""
    viser = viser_module()
    host = "127.0.0.1"
    # The loopback server only feeds the serialiser: keep its URL banner (printed to stdout
    # whatever `verbose` says) out of the command's output.
    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host=host, port=free_port(host), verbose=False)
    try:
        set_initial_camera(server, start_camera(scene.header))
        serializer = server.get_scene_serializer()
        nodes = add_scene(server, scene, plan, on_set)
        if len(plan.times) > 1:
            for i in range(1, len(plan.times)):
                serializer.insert_sleep(1.0 / plan.rate)
                nodes.show_sample(i)
            serializer.insert_sleep(1.0 / plan.rate)  # the last sample is shown for 1/rate too
        return bytes(serializer.serialize())
    finally:
        with contextlib.redirect_stdout(io.StringIO()):
            server.stop()


def write_web(
    scene: ply4d.Ply4dFile, plan: Playback, out: Path, on_set: Callable[[], None] = lambda: None
) -> Path:
    """Write ``out/`` (index.html, viser-client.html, scene.viser) for ``scene`` (opened
    with ``open_checked``) played as ``plan`` says.

    The folder is built beside ``out`` and renamed into place, so a failure leaves no
    half-written folder.
    """
    client = client_html_path()
    if out.exists() and not (out.is_dir() and not any(out.iterdir())):
        raise InputError(f"{out} exists and is not an empty folder; choose a new one")
    recording = record_scene(scene, plan, on_set)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        tmp.chmod(0o755)  # mkdtemp's 0700 would hide the folder from a web server's user
        (tmp / RECORDING_NAME).write_bytes(recording)
        shutil.copyfile(client, tmp / CLIENT_NAME)
        (tmp / "index.html").write_text(
            index_html(start_camera(scene.header), Path(scene.path).stem)
        )
        if out.exists():
            out.rmdir()
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


# --- pano4d serve --------------------------------------------------------------------------


class TimeControls:
    """The time slider, play / pause, loop, and the camera presets of the live viewer. The
    slider is the scene time in frames, one step a sample of ``nodes.playback``; playing
    moves it a sample every 1/rate seconds."""

    def __init__(self, server: Any, nodes: SceneNodes, camera: StartCamera) -> None:
        self.server, self.nodes, self.camera = server, nodes, camera
        self.plan = nodes.playback
        gui = server.gui
        last = self.plan.times[-1] if self.plan.times else 0.0
        self.slider = gui.add_slider(
            "time (frames)", min=0.0, max=last, step=self.plan.step, initial_value=0.0
        )
        self.playing = gui.add_checkbox("play", initial_value=False)
        self.loop = gui.add_checkbox("loop", initial_value=True)
        gui.add_button("panorama viewpoint").on_click(lambda _: self.reset_cameras())
        gui.add_button("turntable").on_click(lambda _: self.start_turntable())
        self.slider.on_update(lambda _: nodes.show_sample(self.sample()))
        self._stop = threading.Event()
        threading.Thread(target=self._play, daemon=True).start()

    def sample(self) -> int:
        """The sample the slider is on (the client rounds its value to a few digits)."""
        nearest = round(float(self.slider.value) / self.plan.step)
        return min(max(nearest, 0), len(self.plan.times) - 1)

    def _play(self) -> None:
        while not self._stop.wait(1.0 / self.plan.rate):
            if not self.playing.value or len(self.plan.times) < 2:
                continue
            i = self.sample() + 1
            if i >= len(self.plan.times):
                if not self.loop.value:
                    self.playing.value = False
                    continue
                i = 0
            self.slider.value = self.plan.times[i]

    def reset_cameras(self) -> None:
        for client in self.server.get_clients().values():
            client.camera.position = self.camera.position
            client.camera.look_at = self.camera.look_at
            client.camera.up_direction = self.camera.up
            client.camera.fov = self.camera.fov

    def start_turntable(self) -> None:
        threading.Thread(target=self._turntable, daemon=True).start()

    def _turntable(self) -> None:
        # The cameras of `pano4d render --path turntable`: a full turn in place.
        cams = turntable(16, 9, TURNTABLE_FRAMES)
        for cam in cams:
            position = tuple(float(v) for v in cam.position)
            look_at = tuple(float(p + f) for p, f in zip(position, cam.forward, strict=True))
            for client in self.server.get_clients().values():
                client.camera.position = position
                client.camera.look_at = look_at
            time.sleep(TURNTABLE_SECONDS / TURNTABLE_FRAMES)

    def stop(self) -> None:
        self._stop.set()


def start_server(
    scene: ply4d.Ply4dFile,
    plan: Playback,
    host: str,
    port: int,
    on_set: Callable[[], None] = lambda: None,
) -> tuple[Any, TimeControls]:
    """Start the live viewer on ``host:port`` with ``scene`` (opened with ``open_checked``)
    loaded and played as ``plan`` says; returns (server, controls)."""
    viser = viser_module()
    server = viser.ViserServer(host=host, port=port, verbose=False)
    try:
        camera = start_camera(scene.header)
        set_initial_camera(server, camera)
        server.gui.configure_theme(control_layout="floating", show_share_button=False)
        nodes = add_scene(server, scene, plan, on_set)
        controls = TimeControls(server, nodes, camera)
    except BaseException:
        server.stop()
        raise
    return server, controls


def forwarding_hint(host: str, port: int) -> str:
    """How to reach the viewer from a laptop when it runs on a remote machine."""
    return (
        f"from another machine: ssh -N -L {port}:localhost:{port} USER@THIS_HOST, "
        f"then open http://localhost:{port}"
        + ("" if host in ("127.0.0.1", "localhost") else f" (or http://{host}:{port})")
    )
