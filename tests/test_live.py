"""`pano4d train --serve`: the live view, in a real browser (headless Chromium, WebGL2 on
SwiftShader, as tests/test_web.py).

One short `pano4d train --serve` of the tiny scene (pano4d_process.tiny_scene: 2 frames, 12
steps an optimisation, 6 for t=1, a checkpoint every 4) runs in a subprocess with three
test hooks (``HELD_TRAIN``): it writes down every snapshot the live view is given, it waits
at dynamic t=1's first checkpoint until the test has looked at the page, and it waits
again when the command is done, before the process exits (and the system would close the
port for it). The tests read what that one run left: the page during training, the
snapshots against the checkpoints, the server gone by the last line. A port in use and
the options without --serve are refused before anything trains.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from browser import Browser, module_browser
from pano4d_process import ONE_THREAD, TINY, tiny_scene
from sphere_problem import sphere_problem
from typer.testing import CliRunner

from pano4d import live, web
from pano4d.cli import app
from pano4d.config import load_config
from pano4d.errors import InputError
from pano4d.gaussians import Gaussians
from pano4d.lift.pipeline import SceneSnapshot, dynamic_iterations, make_trainer
from pano4d.lift.trainer import Knobs
from pano4d.renderer import render
from pano4d.spacetime import SpacetimeGaussians, TimeModel

WIDTH, HEIGHT = 640, 360
EVERY = 4  # --checkpoint-every

# `pano4d train` (its arguments after the script's name) with the test's hooks, controlled
# through the folder LIVE_TEST_DIR: each snapshot the live view is given, as
# [optimisation, step], a line of snapshots.jsonl; at the n-th step callback of the stage
# LIVE_TEST_HOLD_AT ("stage:n") it waits for the file go-on, and when the command is done
# for the file exit, each wait announced on stderr.
HELD_TRAIN = """
import json, os, sys, time
from pathlib import Path

import pano4d.live
import pano4d.train
from pano4d.cli import main

folder = Path(os.environ["LIVE_TEST_DIR"])
stage, count = os.environ["LIVE_TEST_HOLD_AT"].split(":")


def wait_for(name):
    print(f"waiting for {name}", file=sys.stderr, flush=True)
    while not (folder / name).exists():
        time.sleep(0.1)


calls = 0


def hold(name, step):
    global calls
    calls += name == stage
    if name == stage and calls == int(count):
        wait_for("go-on")


given = pano4d.live.LiveView.show


def show(view, snapshot):
    with (folder / "snapshots.jsonl").open("a") as f:
        f.write(json.dumps([snapshot.optimisation, snapshot.step]) + "\\n")
    given(view, snapshot)


pano4d.train.kill_hook_from_env = lambda: hold
pano4d.live.LiveView.show = show
sys.argv[0] = "pano4d"
try:
    main()
finally:
    wait_for("exit")
"""


@dataclass(frozen=True)
class LiveRun:
    """What the held `pano4d train --serve` left, and what the browser saw of it."""

    scene: Path  # scene.yaml
    port: int
    empty: np.ndarray  # the canvas of a live view before any snapshot
    empty_text: str  # and that page's text
    canvas: np.ndarray  # the canvas at dynamic t=1's first checkpoint
    text: str  # and the page's text then
    sliders: list[dict[str, str | None]]  # the page's sliders' aria-value{min,max,now}
    port_open_at_end: bool  # once the command is done, before the process exits
    stderr: list[str]  # every line, the test hooks' own left out
    returncode: int
    snapshots: list[tuple[str, int]]


def textured(frame: np.ndarray) -> bool:
    """Splats are drawn: the canvas is not one flat colour (viser's empty background)."""
    return frame.size > 0 and float(frame.std()) > 0.05


def page_text(b: Browser, contains: str = "", timeout: float = 60.0) -> str:
    """The page's text once it contains ``contains`` (the last one seen after ``timeout``)."""
    deadline = time.monotonic() + timeout
    while True:
        text = str(b.driver.execute_script("return document.body.innerText"))
        if contains in text or time.monotonic() > deadline:
            return text
        time.sleep(0.5)


def sliders(b: Browser) -> list[dict[str, str | None]]:
    found = b.driver.find_elements("css selector", "[role=slider]")
    names = ("aria-valuemin", "aria-valuemax", "aria-valuenow")
    return [{name: e.get_attribute(name) for name in names} for e in found]


def port_open(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
    except OSError:
        return False
    return True


def lines_until(stream: Any, marker: str, into: list[str]) -> None:
    """Read ``stream``'s lines into ``into`` up to the one containing ``marker`` (left out);
    AssertionError if the stream ends first."""
    for line in stream:
        if marker in line:
            return
        into.append(line.rstrip("\n"))
    raise AssertionError(f"the command ended before {marker!r}: {into}")


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    yield from module_browser(WIDTH, HEIGHT)


@pytest.fixture(scope="module")
def pristine(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny scene's folder, never trained: a test trains (or not) a copy of it."""
    folder = tmp_path_factory.mktemp("live") / "pristine"
    tiny_scene(folder, frames=2)
    return folder


@pytest.fixture(scope="module")
def run(pristine: Path, browser: Browser) -> LiveRun:
    """A live view with no snapshot yet in the browser, then the held `pano4d train
    --serve` of a copy of the tiny scene (module docstring) with the browser on its page
    while it waits at dynamic t=1's first checkpoint."""
    folder = pristine.parent
    scene = shutil.copytree(pristine, folder / "scene") / "scene.yaml"
    # The page before any snapshot: the empty scene the trained one must differ from.
    port = web.free_port("127.0.0.1")
    with live.serving("127.0.0.1", port):
        browser.open(f"http://127.0.0.1:{port}/")
        empty_text = page_text(browser, "first checkpoint")
        empty = browser.wait_for_scene(lambda f: f.size > 0)
    port = web.free_port("127.0.0.1")
    hooks = folder / "hooks"
    hooks.mkdir()
    env = {**os.environ, **ONE_THREAD, "LIVE_TEST_DIR": str(hooks),
           # dynamic t=0's steps, then t=1's up to its first checkpoint
           "LIVE_TEST_HOLD_AT": f"dynamic:{TINY['gaussian_iterations'] + EVERY}"}  # fmt: skip
    command = [sys.executable, "-c", HELD_TRAIN, "train", str(scene), "--serve",
               "--port", str(port), "--checkpoint-every", str(EVERY)]  # fmt: skip
    proc = subprocess.Popen(
        command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env
    )
    stderr: list[str] = []
    try:
        assert proc.stderr is not None
        lines_until(proc.stderr, "waiting for go-on", stderr)
        browser.open(f"http://127.0.0.1:{port}/")
        canvas = browser.wait_for_scene(textured)
        text = page_text(browser, "dynamic t=1")
        shown_sliders = sliders(browser)
        (hooks / "go-on").touch()
        lines_until(proc.stderr, "waiting for exit", stderr)
        open_at_end = port_open(port)
    finally:
        (hooks / "go-on").touch()
        (hooks / "exit").touch()
        try:
            proc.wait(timeout=120)
        finally:
            proc.kill()
    records = (hooks / "snapshots.jsonl").read_text().splitlines()
    return LiveRun(
        scene, port, empty, empty_text, canvas, text, shown_sliders, open_at_end, stderr,
        proc.returncode, [tuple(json.loads(line)) for line in records],
    )  # fmt: skip


def test_the_page_shows_the_gaussians_and_the_step_while_they_train(run: LiveRun) -> None:
    assert "appear at the static stage's first checkpoint" in run.empty_text, run.empty_text
    assert textured(run.canvas)
    assert run.canvas.shape == run.empty.shape
    assert float(np.abs(run.canvas - run.empty).mean()) > 0.1  # not the empty scene
    # The latest snapshot (a browser connecting gets it at once), not an earlier one.
    assert "training dynamic t=1: step 4 of 6" in run.text, run.text
    # Two timestamps so far, the slider at the one in training.
    assert run.sliders == [{"aria-valuemin": "0", "aria-valuemax": "1", "aria-valuenow": "1"}]


def test_the_live_view_gets_the_gaussians_only_where_training_reads_them_back(
    run: LiveRun,
) -> None:
    """At each checkpoint (every EVERY steps, none at an optimisation's last step: its end
    is saved with the stage's result) and at each optimisation's end, never in between."""
    knobs = load_config(run.scene).resolved_preset()
    full = knobs.gaussian_iterations
    optimisations = {
        "static": full,
        "dynamic t=0": dynamic_iterations(full, 0, knobs.later_iteration_share),
        "dynamic t=1": dynamic_iterations(full, 1, knobs.later_iteration_share),
    }
    expected = [(name, step) for name, steps in optimisations.items()
                for step in [*range(EVERY, steps, EVERY), steps]]  # fmt: skip
    assert run.snapshots == expected


def test_the_server_stops_when_training_ends_and_the_last_line_says_what_shows_the_result(
    run: LiveRun,
) -> None:
    assert run.returncode == 0, run.stderr
    assert run.stderr[0].startswith(f"live view: http://127.0.0.1:{run.port} "), run.stderr
    assert not run.port_open_at_end
    output = load_config(run.scene).output
    assert run.stderr[-1] == (
        f"the live view has stopped; pano4d serve {output}/scene.ply4d shows the result"
    )


def test_a_port_in_use_is_one_error_line_before_anything_trains(
    pristine: Path, tmp_path: Path
) -> None:
    scene = shutil.copytree(pristine, tmp_path / "scene") / "scene.yaml"
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        result = CliRunner().invoke(app, ["train", str(scene), "--serve", "--port", str(port)])
    assert result.exit_code == 2, result.output
    # One line, nothing before it (no progress bar, no address), nothing after it.
    assert result.output.splitlines() == [
        f"error: --port {port}: 127.0.0.1:{port} is already in use (another pano4d serve or "
        "train --serve?); choose another --port"
    ]
    assert not (tmp_path / "scene" / "output").exists()


@pytest.mark.parametrize("option", [["--port", "8081"], ["--host", "0.0.0.0"]])
def test_the_live_views_options_need_serve(option: list[str], tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["train", str(tmp_path / "scene.yaml"), *option])
    assert result.exit_code == 2, result.output
    assert result.output.splitlines() == [
        f"error: {' '.join(option)} is the live view's: add --serve"
    ]


def _copied(s: Gaussians | SpacetimeGaussians) -> Any:
    """``s.to_numpy()`` with arrays of its own (``Tensor.numpy()`` shares the tensor's)."""

    def copy(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: copy(v) for k, v in value.items()}
        return np.array(value)

    return copy(s.to_numpy())


def _numpy_equal(a: Any, b: Any) -> bool:
    """``to_numpy()`` forms (nested dicts of arrays) equal bit for bit."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_numpy_equal(a[k], b[k]) for k in a)
    return bool(np.array_equal(np.asarray(a), np.asarray(b)))


@pytest.mark.usefixtures("one_torch_thread")
@pytest.mark.parametrize("trained", ["gaussians", "spacetime"])
@pytest.mark.parametrize("kind", ["resident", "torch"])
def test_what_a_checkpoint_reads_back_is_the_trainers_result(kind: str, trained: str) -> None:
    """``trained_in(state_dict())``, the set a live view is given at a checkpoint, equals
    ``result()`` at that step and stays so while training goes on."""
    g, views = sphere_problem(16, 0)
    start: Gaussians | SpacetimeGaussians = g
    if trained == "spacetime":
        start = SpacetimeGaussians.still(TimeModel(2, 1, 1), g)
        views.times = [float(i % 2) for i in range(len(views.cameras))]

    def render_fn(s: Gaussians, camera: Any, background: torch.Tensor | None = None) -> Any:
        return render(s, camera, background=background, backend="wgpu")

    trainer = make_trainer(kind, start, views, Knobs(iterations=4, densify=False), render_fn)
    for _ in range(2):
        trainer.train_step()
    shown = trainer.trained_in(trainer.state_dict())
    assert type(shown) is type(start)
    kept = _copied(shown)
    assert _numpy_equal(kept, trainer.result().to_numpy())
    trainer.train_step()
    assert _numpy_equal(shown.to_numpy(), kept)  # later steps do not reach it
    assert not _numpy_equal(kept, trainer.result().to_numpy())


def test_a_port_taken_or_a_host_not_of_this_machine_is_refused_before_serving() -> None:
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        with pytest.raises(InputError, match=re.escape(f"127.0.0.1:{port} is already in use")):
            live.check_port("127.0.0.1", port)
    live.check_port("127.0.0.1", port)  # free again
    with pytest.raises(InputError, match=re.escape("--host 256.0.0.1: not an address to")):
        live.check_port("256.0.0.1", port)


def _snapshot(
    optimisation: str, static: Gaussians, dynamic: list[Gaussians] | SpacetimeGaussians | None
) -> SceneSnapshot:
    return SceneSnapshot(optimisation, 4, 12, static, dynamic, 3, False, 100.0)


@pytest.fixture
def view() -> Iterator[live.LiveView]:
    with live.serving("127.0.0.1", web.free_port("127.0.0.1")) as v:
        yield v


def test_what_the_page_gets_of_each_stage(view: live.LiveView) -> None:
    """The sender's work (``_send``) on the snapshots of a run: the static set, then one
    node per timestamp as they come (a finished one not sent again), the slider from the
    second on; a spacetime set evaluated at each of its timestamps."""
    g = sphere_problem(8, 0)[0]
    static, first, second = g[:40], g[40:60], g[60:]
    view._send(_snapshot("static", static, None))
    assert view.static_shown is static and view.dynamic_nodes == [] and view.slider is None
    assert view.status.content.startswith("**training static**: step 4 of 12")
    view._send(_snapshot("dynamic t=0", static, [first]))
    node = view.dynamic_nodes[0]
    assert view.slider is None
    view._send(_snapshot("dynamic t=1", static, [first, second]))
    assert view.dynamic_nodes[0] is node  # t=0 is done: not sent again
    assert (view.slider.max, view.slider.value) == (1, 1)
    assert [n.visible for n in view.dynamic_nodes] == [False, True]
    view.slider.value = 0
    assert [n.visible for n in view.dynamic_nodes] == [True, False]
    moving = SpacetimeGaussians.still(TimeModel(3, 1, 1), first)
    view._send(_snapshot("dynamic", static, moving))
    assert len(view.dynamic_nodes) == 3 and view.slider.max == 2
    assert "20 dynamic, one set for 3 timestamps" in view.status.content


def test_nothing_is_converted_while_no_browser_is_connected(view: live.LiveView) -> None:
    g = sphere_problem(8, 0)[0]
    view.show(_snapshot("static", g, None))
    time.sleep(1.0)  # the sender would have sent it by now
    assert view.static_shown is None and view.pending is not None
