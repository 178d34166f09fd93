"""`pano4d serve` and `pano4d web` in a real browser (headless Chromium, WebGL2 on SwiftShader).

A tiny scene (a wall of ~500 Gaussians in front of the viewpoint, and a blob in front of it that
is red at timestamp 0 and blue, moved, at timestamp 1) is shown by viser's client; the canvas
is compared with `pano4d render` (SH-0 colour, the same camera) and the change between the
two timestamps must stay inside the blob's region.
"""

from __future__ import annotations

import contextlib
import functools
import http.server
import math
import os
import subprocess
import sys
import threading
import types
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from browser import Browser, module_browser, psnr
from pano4d_process import error_line, pano4d

from pano4d import ply4d, web
from pano4d.camera import Camera
from pano4d.gaussians import Gaussians, rgb_to_sh_dc
from pano4d.renderer import render
from pano4d.share_formats import for_classic_viewers
from pano4d.spacetime import SpacetimeGaussians, TimeModel

WIDTH, HEIGHT = 640, 360
# SwiftShader's splats against pano4d's rasteriser, SH-0 colour, measured 2026-11-24: see
# README "In the browser". viser quantises colour/opacity to 8 bits and covariances to float16
# and sorts splats by centre depth, pano4d sorts per tile: a few dB off bit-exact.
MIN_PSNR_DB = 24.0
# Outside the moving region (the blob's pixels at either timestamp, grown by DILATE pixels)
# a time change may move a pixel by at most this much (99.9th percentile of |Δ|).
OUTSIDE_TOLERANCE = 0.06
DILATE = 6


def wall(seed: int) -> Gaussians:
    """~500 opaque round Gaussians of random colour in a slab 4 m in front of the viewpoint,
    covering the whole start view (depths jittered, so every renderer sorts them alike)."""
    gen = torch.Generator().manual_seed(seed)
    y, z = torch.meshgrid(torch.arange(-5, 5.01, 0.35), torch.arange(-3, 3.01, 0.35), indexing="ij")
    n = y.numel()
    x = 4.0 + 0.6 * torch.rand(n, generator=gen)
    rgb = torch.rand(n, 3, generator=gen) * 0.8 + 0.1
    return Gaussians(
        means=torch.stack([x, y.reshape(-1), z.reshape(-1)], dim=-1),
        log_scales=torch.full((n, 3), math.log(0.2)),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
        opacity_logits=torch.full((n,), 5.0),
        sh=rgb_to_sh_dc(rgb)[:, None, :],
    )


def blob(centre: tuple[float, float, float], rgb: tuple[float, float, float]) -> Gaussians:
    """60 flat-coloured Gaussians in a ball of radius 0.3 at ``centre``."""
    gen = torch.Generator().manual_seed(7)
    n = 60
    means = torch.tensor(centre) + 0.3 * torch.rand(n, 3, generator=gen) - 0.15
    return Gaussians(
        means=means,
        log_scales=torch.full((n, 3), math.log(0.08)),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
        opacity_logits=torch.full((n,), 5.0),
        sh=rgb_to_sh_dc(torch.tensor(rgb).repeat(n, 1))[:, None, :],
    )


def tiny_scene() -> ply4d.Scene4D:
    return ply4d.Scene4D(
        static=wall(seed=0),
        dynamic=[blob((2.0, 0.3, 0.0), (1.0, 0.1, 0.1)), blob((2.0, -0.3, 0.2), (0.1, 0.2, 1.0))],
        timestamps=[0.0, 0.5],
        fps=1.0,  # timestamp t plays from t to t + 1 s in the `pano4d web` recording
    )


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("web") / "tiny.ply4d"
    ply4d.write(path, tiny_scene())
    return path


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    yield from module_browser(WIDTH, HEIGHT)


def reference(scene_file: Path, t: int, size: tuple[int, int]) -> np.ndarray:
    """What `pano4d render` draws at the browser's start view, canvas size ``(w, h)``: the
    client keeps viser's vertical fov, so the horizontal fov follows the canvas aspect."""
    w, h = size
    camera = web.start_camera(ply4d.open(scene_file).header)
    hfov = math.degrees(2 * math.atan(math.tan(camera.fov / 2) * w / h))
    cam = Camera.from_fov(hfov, w, h, camera.position, (1.0, 0.0, 0.0))
    g = ply4d.open(scene_file).at(t)
    return render(g, cam).rgb.clamp(0, 1).numpy()  # `pano4d render`'s default (wgpu) rasteriser


def moving_mask(ref0: np.ndarray, ref1: np.ndarray) -> np.ndarray:
    """Pixels the blob covers at either timestamp, grown by DILATE pixels."""
    mask = torch.from_numpy(np.abs(ref0 - ref1).max(-1) > 0.02)[None, None].float()
    grown = torch.nn.functional.max_pool2d(mask, 2 * DILATE + 1, stride=1, padding=DILATE)
    return grown[0, 0].numpy() > 0


def textured(frame: np.ndarray) -> bool:
    """The shell is drawn: the canvas is not one flat colour (viser's empty background)."""
    return float(frame.std()) > 0.05


def check_scene_and_time_change(
    b: Browser,
    scene_file: Path,
    change_time: functools.partial[None],
    show_first: functools.partial[None] | None = None,
) -> None:
    """The page shows timestamp 0 as `pano4d render` draws it, then (after ``change_time``)
    timestamp 1, changed only where the blob is. ``show_first`` (a page that plays its
    timeline) pauses it on timestamp 0: once before, and once more if the first settled
    frame is not timestamp 0 (typed while the page loads, the pause can land after it)."""
    if show_first is not None:
        show_first()
    first = b.wait_for_scene(textured)
    size = (first.shape[1], first.shape[0])
    ref0, ref1 = reference(scene_file, 0, size), reference(scene_file, 1, size)
    if show_first is not None and psnr(first, ref0) < MIN_PSNR_DB:
        show_first()
        first = b.wait_for_scene(lambda f: textured(f) and psnr(f, ref0) >= MIN_PSNR_DB, 30.0)
    assert psnr(first, ref0) >= MIN_PSNR_DB, psnr(first, ref0)
    change_time()
    second = b.wait_for_scene(lambda f: textured(f) and float(np.abs(f - first).max()) > 0.3)
    assert psnr(second, ref1) >= MIN_PSNR_DB, psnr(second, ref1)
    moving = moving_mask(ref0, ref1)
    delta = np.abs(second - first).max(-1)
    assert 0.01 < moving.mean() < 0.3, moving.mean()  # the blob is in view, not everywhere
    assert np.quantile(delta[~moving], 0.999) <= OUTSIDE_TOLERANCE
    assert delta[moving].mean() > 0.1  # the blob did change colour where it is


def test_serve_shows_the_scene_and_its_time_slider(scene_file: Path, browser: Browser) -> None:
    port = web.free_port("127.0.0.1")
    command = [sys.executable, "-m", "pano4d.cli", "serve", str(scene_file), "--port", str(port)]
    proc = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, env=os.environ.copy())
    try:
        assert proc.stderr is not None
        lines = []
        for line in proc.stderr:
            lines.append(line)
            if "http://127.0.0.1:" in line:
                break
        assert f"http://127.0.0.1:{port}" in "".join(lines), lines
        browser.open(f"http://127.0.0.1:{port}/")

        def next_timestamp() -> None:
            from selenium.webdriver.common.keys import Keys

            slider = browser.driver.find_element("css selector", "[role=slider]")
            slider.send_keys(Keys.ARROW_RIGHT)

        check_scene_and_time_change(browser, scene_file, functools.partial(next_timestamp))
    finally:
        proc.terminate()
        proc.wait(timeout=30)


@contextlib.contextmanager
def file_server(folder: Path) -> Iterator[str]:
    """`python -m http.server` on loopback, in a thread; yields its URL."""
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(folder))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()


def test_web_folder_shows_the_scene_and_its_timeline(
    scene_file: Path, browser: Browser, tmp_path: Path
) -> None:
    out = tmp_path / "site"
    result = pano4d("web", scene_file, out)
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["index.html", "scene.viser", web.CLIENT_NAME]
    with file_server(out) as url:
        browser.open(f"{url}/index.html")
        assert "playbackPath=scene.viser" in browser.driver.current_url

        def show_time(seconds: str) -> None:
            from selenium.webdriver.common.keys import Keys

            box = browser.driver.find_element("css selector", "input.mantine-NumberInput-input")
            box.send_keys(Keys.CONTROL, "a")
            box.send_keys(seconds)

        # 0.5 s pauses the playback on timestamp 0 (it plays 0 s to 1 s), 1.5 s on timestamp 1
        check_scene_and_time_change(
            browser, scene_file, functools.partial(show_time, "1.5"),
            functools.partial(show_time, "0.5"),
        )  # fmt: skip
        if os.environ.get("PANO4D_WEB_SCREENSHOT"):  # README's picture: the whole page
            browser.driver.get_screenshot_as_file(os.environ["PANO4D_WEB_SCREENSHOT"])


def test_web_refuses_a_damaged_scene_before_writing(scene_file: Path, tmp_path: Path) -> None:
    data = scene_file.read_bytes()
    for name, damaged in [
        ("truncated", data[: len(data) - 100]),
        ("flipped", data[:-200] + bytes([data[-200] ^ 0xFF]) + data[-199:]),
    ]:
        path = tmp_path / f"{name}.ply4d"
        path.write_bytes(damaged)
        out = tmp_path / f"{name}-site"
        line = error_line(pano4d("web", path, out))
        assert str(path) in line, line
        assert not out.exists()
        assert [p.name for p in tmp_path.iterdir() if p.name.startswith(f".{name}")] == []


class RecordingScene:
    """The part of a viser server's ``scene`` that ``web.add_scene`` uses, keeping the
    arrays of each set it is sent."""

    def __init__(self) -> None:
        self.sent: dict[str, web.SplatArrays] = {}

    def set_up_direction(self, direction: str) -> None:
        pass

    def add_gaussian_splats(
        self, name: str, centers: np.ndarray, covariances: np.ndarray, rgbs: np.ndarray,
        opacities: np.ndarray, visible: bool,
    ) -> str:  # fmt: skip
        self.sent[name] = web.SplatArrays(centers, covariances, rgbs, opacities)
        return name


def sent_to_viser(path: Path, rate: float | None = None) -> dict[str, web.SplatArrays]:
    server = types.SimpleNamespace(scene=RecordingScene())
    scene = ply4d.open(path)
    web.add_scene(server, scene, web.playback(scene, rate), lambda: None)
    return server.scene.sent


def assert_same_arrays(a: web.SplatArrays, b: web.SplatArrays) -> None:
    for name in ("centers", "covariances", "rgbs", "opacities"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_viser_gets_an_antialiased_scene_baked(scene_file: Path, tmp_path: Path) -> None:
    """viser draws classic: a classic scene's sets go as stored, an antialiased one's baked
    at its training views (the same sets `pano4d export` writes)."""
    classic = ply4d.open(scene_file)
    sets = {"/static": classic.static(), "/dynamic/0000": classic.dynamic(0),
            "/dynamic/0001": classic.dynamic(1)}  # fmt: skip
    sent = sent_to_viser(scene_file)
    for name, g in sets.items():
        assert_same_arrays(sent[name], web.splat_arrays(g))
    scene = tiny_scene()  # the same sets, trained antialiased
    scene.antialiased = True
    scene.camera = {"position": [0.0, 0.0, 0.0], "params": {"fov_deg": 80.0, "view_size": 512}}
    path = tmp_path / "antialiased.ply4d"
    ply4d.write(path, scene)
    sent = sent_to_viser(path)
    for name, g in sets.items():
        assert_same_arrays(sent[name], web.splat_arrays(for_classic_viewers(g, ply4d.open(path))))
        assert (sent[name].opacities < web.splat_arrays(g).opacities).any(), name


def spacetime_blob(tmp_path: Path) -> tuple[SpacetimeGaussians, Path]:
    """The blob as a spacetime set (format version 2) looping over 3 frames at 3 fps,
    swinging sideways and changing colour, in front of the wall."""
    moving = SpacetimeGaussians.still(TimeModel(3, 1, 1), blob((2.0, 0.3, 0.0), (1.0, 0.1, 0.1)))
    moving.position_terms[:, 1, 1] = 0.5  # sin₁ of y: the blob swings sideways
    moving.colour_terms[:, 0, 2] = 1.0  # cos₁ of blue
    path = tmp_path / "spacetime.ply4d"
    ply4d.write(path, ply4d.Scene4D(wall(seed=0), moving, [0.0, 1 / 3, 2 / 3], 3.0))
    return moving, path


def test_viser_gets_a_version_2_scene_at_every_timestamp(tmp_path: Path) -> None:
    """A spacetime set (format version 2) goes as one node per timestamp at the scene's
    fps, each the set evaluated there, as a version-1 scene's sets go."""
    moving, path = spacetime_blob(tmp_path)
    sent = sent_to_viser(path)
    assert sorted(sent) == ["/dynamic/0000", "/dynamic/0001", "/dynamic/0002", "/static"]
    assert_same_arrays(sent["/static"], web.splat_arrays(wall(seed=0)))
    for t in range(3):
        assert_same_arrays(sent[f"/dynamic/{t:04d}"], web.splat_arrays(moving.at(t)))
    assert not np.array_equal(sent["/dynamic/0000"].centers, sent["/dynamic/0001"].centers)


def test_a_rate_samples_a_version_2_loop_and_picks_version_1_sets(tmp_path: Path) -> None:
    """At --rate 7 a 3-frame, 3 fps version-2 loop is 7 samples, each the set evaluated at
    its own time (i · 3/7 frames); a 2-timestamp, 1 fps version-1 scene at --rate 3 is 6
    samples that show its 2 stored sets, each sent once, and at --rate 0.5 one sample."""
    moving, path = spacetime_blob(tmp_path)
    plan = web.playback(ply4d.open(path), 7.0)
    assert len(plan.times) == len(plan.set_times) == 7 and plan.step == pytest.approx(3 / 7)
    assert plan.set_of_sample == list(range(7))
    sent = sent_to_viser(path, 7.0)
    assert len(sent) == 8
    for i in range(7):
        assert plan.times[i] == pytest.approx(i * 3 / 7)
        assert_same_arrays(sent[f"/dynamic/{i:04d}"], web.splat_arrays(moving.at(i * 3 / 7)))

    v1 = tmp_path / "v1.ply4d"
    ply4d.write(v1, tiny_scene())
    plan = web.playback(ply4d.open(v1), 3.0)
    assert plan.times == pytest.approx([0, 1 / 3, 2 / 3, 1, 4 / 3, 5 / 3])
    assert (plan.set_times, plan.set_of_sample) == ([0.0, 1.0], [0, 0, 0, 1, 1, 1])
    assert sorted(sent_to_viser(v1, 3.0)) == ["/dynamic/0000", "/dynamic/0001", "/static"]
    slow = web.playback(ply4d.open(v1), 0.5)
    assert (slow.times, slow.set_times) == ([0.0], [0.0])
    assert sorted(sent_to_viser(v1, 0.5)) == ["/dynamic/0000", "/static"]


def test_the_recording_plays_the_samples_at_the_rate(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`pano4d web --rate 2` on a 1 fps version-1 scene of 2 timestamps: 4 samples, 0.5 s
    each, the 2 stored sets sent once; `--rate 7` on a 3-frame, 3 fps version-2 scene: 7
    samples, 1/7 s each, each its own set. The progress bar counts the sets sent."""
    import viser.infra
    from typer.testing import CliRunner

    from pano4d import progress
    from pano4d.cli import app

    sleeps: list[float] = []
    shown: list[int] = []
    totals: list[int | None] = []
    insert_sleep = viser.infra.StateSerializer.insert_sleep
    show_sample = web.SceneNodes.show_sample
    task = progress.Bars.task

    def sleep(self: viser.infra.StateSerializer, duration: float) -> None:
        sleeps.append(duration)
        insert_sleep(self, duration)

    def show(self: web.SceneNodes, i: int) -> None:
        shown.append(self.playback.set_of_sample[i])
        show_sample(self, i)

    def counted(self: progress.Bars, description: str, total: int | None) -> progress.Task:
        totals.append(total)
        return task(self, description, total)

    monkeypatch.setattr(viser.infra.StateSerializer, "insert_sleep", sleep)
    monkeypatch.setattr(web.SceneNodes, "show_sample", show)
    monkeypatch.setattr(progress.Bars, "task", counted)
    v1 = tmp_path / "v1.ply4d"
    ply4d.write(v1, tiny_scene())
    _, v2 = spacetime_blob(tmp_path)
    for path, rate, expected in [
        (v1, "2", ([0.5] * 4, [0, 1, 1], [3])),
        (v2, "7", ([1 / 7] * 7, [1, 2, 3, 4, 5, 6], [8])),
    ]:
        sleeps.clear(), shown.clear(), totals.clear()
        site = tmp_path / f"{path.stem}-site"
        result = CliRunner().invoke(app, ["web", str(path), str(site), "--rate", rate])
        assert result.exit_code == 0, result.output
        assert (sleeps, shown, totals) == expected
        assert (site / web.RECORDING_NAME).stat().st_size > 0


@pytest.mark.parametrize("rate", ["0", "-1", "nan", "inf"])
@pytest.mark.parametrize("command", ["serve", "web"])
def test_a_rate_that_is_not_one_is_one_error_line(
    scene_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, command: str, rate: str
) -> None:
    """Before anything is sent or written."""
    from typer.testing import CliRunner

    from pano4d.cli import app

    def nothing_sent(*args: object, **kwargs: object) -> None:
        raise AssertionError("the scene was sent")  # and `serve` would run until stopped

    monkeypatch.setattr(web, "start_server", nothing_sent)
    monkeypatch.setattr(web, "write_web", nothing_sent)
    args = [str(tmp_path / "site")] if command == "web" else []
    result = CliRunner().invoke(app, [command, str(scene_file), *args, "--rate", rate])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: --rate {rate}"), lines
    assert "positive number" in lines[0]
    assert list(tmp_path.iterdir()) == []


class Control(types.SimpleNamespace):
    """A viser GUI handle: a value and the callbacks run when the page changes it."""

    def on_update(self, callback: Callable[[Any], None]) -> None:
        self.callbacks = [*getattr(self, "callbacks", []), callback]

    on_click = on_update

    def move_to(self, value: float) -> None:
        self.value = value
        for callback in self.callbacks:
            callback(None)


class ControlGui:
    """The part of viser's ``server.gui`` that ``web.TimeControls`` uses."""

    def add_slider(self, label: str, **kwargs: float) -> Control:
        self.slider = Control(label=label, value=kwargs["initial_value"], **kwargs)
        return self.slider

    def add_checkbox(self, label: str, initial_value: bool) -> Control:
        return Control(label=label, value=initial_value)

    def add_button(self, label: str) -> Control:
        return Control(label=label)


def test_the_serve_slider_steps_through_the_samples(tmp_path: Path) -> None:
    """At --rate 7 the 3-frame loop's slider runs 0 to 18/7 frames in steps of 3/7, and a
    value the page rounds to its digits shows that sample's set."""
    _, path = spacetime_blob(tmp_path)
    scene = ply4d.open(path)
    plan = web.playback(scene, 7.0)
    gui = ControlGui()
    server = types.SimpleNamespace(gui=gui)
    nodes = web.SceneNodes(Control(), [Control(visible=k == 0) for k in range(7)], plan)
    controls = web.TimeControls(server, nodes, web.start_camera(scene.header))
    controls.stop()
    assert (gui.slider.min, gui.slider.max) == (0.0, pytest.approx(18 / 7))
    assert gui.slider.step == pytest.approx(3 / 7)
    gui.slider.move_to(round(4 * 3 / 7, 4))
    assert controls.sample() == 4
    assert [node.visible for node in nodes.dynamic] == [k == 4 for k in range(7)]
