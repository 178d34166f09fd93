"""Bad input on the real command line: every command, in a subprocess, on a scene that a
finished `pano4d train` left behind.

Each case breaks one input (a panorama that is not 2:1, a region box off the image, a
broken frame, an unreadable checkpoint, a damaged scene file, a bad option value, a full
disk) and checks that the command prints one `error:` line naming the file, key or value
and what was expected, exits with 2, prints no traceback, and leaves every earlier output
byte for byte as it was. An internal error exits with 1, its traceback only under --debug.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from pano4d_process import (
    TinyDisk,
    error_line,
    pano4d,
    python,
    tiny_disk,
    tiny_scene,
    tree_digest,
)

from pano4d.images import write_image


def train_in_place(folder: Path, prefix: tuple[str, ...] = ()) -> None:
    """`pano4d train` the tiny scene in ``folder``."""
    done = pano4d("train", folder / "scene.yaml", "--checkpoint-every", "4", prefix=prefix)
    assert done.returncode == 0, done.stderr


def restored(folder: Path) -> Path:
    """``folder`` as ``train_in_place`` left it, at the same path: the inputs' hash covers
    absolute paths, so a scene moved elsewhere would start over."""
    shutil.rmtree(folder)
    shutil.copytree(folder.with_name("pristine"), folder)
    return folder


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny scene and everything `pano4d train` writes for it (its frames at the working
    size), its full-resolution animation (`pano4d animate`), and a copy of it all."""
    folder = tmp_path_factory.mktemp("cli") / "scene"
    tiny_scene(folder, frames=2)
    train_in_place(folder)
    animated = pano4d("animate", folder / "scene.yaml")
    assert animated.returncode == 0, animated.stderr
    shutil.copytree(folder, folder.with_name("pristine"))
    return folder


@pytest.fixture
def scene(trained: Path) -> Path:
    """The trained scene's folder for one test to break."""
    return restored(trained)


# --- breakages: each changes one input of the scene folder --------------------------------
def panorama_not_2_to_1(folder: Path) -> None:
    write_image(folder / "panorama.png", np.full((256, 600, 3), 0.5, np.float32))


def box_outside_the_image(folder: Path) -> None:
    yaml = folder / "scene.yaml"
    text = yaml.read_text().replace("- mask: mask.png", "- box: [500, 10, 600, 60]")
    yaml.write_text(text)


def broken_frame(folder: Path) -> None:
    (folder / "output" / "animate" / "moving" / "0001.png").write_bytes(b"\x89PNG not a png")


def broken_working_frame(folder: Path) -> None:
    """A broken frame of the store `pano4d train` reads (output/animate/WxH/moving)."""
    (frame,) = (folder / "output" / "animate").glob("*x*/moving/0001.exr")
    frame.write_bytes(b"v/1\x01 not an exr")


def broken_frame_of_a_killed_run(folder: Path) -> None:
    """A broken frame that a resumed animating phase has to read (no done.json)."""
    broken_frame(folder)
    (folder / "output" / "animate" / "done.json").unlink()


def unreadable_checkpoint(folder: Path) -> None:
    (folder / "output" / "checkpoints" / "static.pt").write_bytes(b"PK\x03\x04 half a zip")


def junk_scene_file(folder: Path) -> None:
    (folder / "junk.ply4d").write_bytes(b"not a scene")


def nothing(folder: Path) -> None:
    pass


Case = tuple[str, Callable[[Path], None], list[str], list[str]]
# (name, breakage, arguments after `pano4d`: {s} is the scene folder, words the line names)
CASES: list[Case] = [
    ("check-2to1", panorama_not_2_to_1, ["check", "{s}/scene.yaml"],
     ["panorama.png", "600×256", "must be exactly 2:1"]),
    ("check-box", box_outside_the_image, ["check", "{s}/scene.yaml"],
     ["regions[0].box", "[500.0, 10.0, 600.0, 60.0]", "outside the 512×256", "panorama.png"]),
    ("train-2to1", panorama_not_2_to_1, ["train", "{s}/scene.yaml"],
     ["panorama.png", "600×256", "must be exactly 2:1"]),
    ("train-box", box_outside_the_image, ["train", "{s}/scene.yaml"],
     ["regions[0].box", "outside the 512×256"]),
    ("train-frame", broken_working_frame, ["train", "{s}/scene.yaml"],
     ["moving/0001.exr", "cannot read this image"]),
    ("train-checkpoint", unreadable_checkpoint, ["train", "{s}/scene.yaml"],
     ["checkpoints/static.pt", "unreadable checkpoint", "delete it"]),
    ("animate-2to1", panorama_not_2_to_1, ["animate", "{s}/scene.yaml"],
     ["panorama.png", "must be exactly 2:1"]),
    ("animate-box", box_outside_the_image, ["animate", "{s}/scene.yaml"],
     ["regions[0].box", "outside the 512×256"]),
    ("animate-frame", broken_frame_of_a_killed_run, ["animate", "{s}/scene.yaml"],
     ["moving/0001.png", "cannot read this image"]),
    ("eval-frame", broken_frame, ["eval", "{s}/scene.yaml"],
     ["moving/0001.png", "cannot read this image"]),
    ("eval-2to1", panorama_not_2_to_1, ["eval", "{s}/scene.yaml"],
     ["panorama.png", "must be exactly 2:1"]),
    ("export-junk", junk_scene_file, ["export", "{s}/junk.ply4d", "{s}/out.ply"],
     ["junk.ply4d", "truncated .ply4d"]),
    ("export-time", nothing, ["export", "{s}/output/scene.ply4d", "{s}/out.ply", "--time", "-1"],
     ["time -1", "a scene time is a finite number of frames ≥ 0"]),
    ("render-junk", junk_scene_file, ["render", "{s}/junk.ply4d", "-o", "{s}/out.png"],
     ["junk.ply4d", "truncated .ply4d"]),
    ("render-time", nothing, ["render", "{s}/output/scene.ply4d", "-o", "{s}/out.png", "-t", "nan"],
     ["time nan", "frames ≥ 0"]),
    ("web-rate", nothing, ["web", "{s}/output/scene.ply4d", "{s}/site", "--rate", "0"],
     ["--rate 0", "must be a positive number"]),
    ("render-camera", nothing,
     ["render", "{s}/output/scene.ply4d", "-o", "{s}/out.png", "--camera",
      '{"position": [0, 0], "forward": [1, 0, 0]}'],
     ["--camera position must be a 3-vector", "[0, 0]"]),
    ("render-path", nothing,
     ["render", "{s}/output/scene.ply4d", "-o", "{s}/out.mp4", "--path", "spiral"],
     ["--path", "'spiral'", "turntable"]),
    ("init-exists", nothing, ["init", "{s}/scene.yaml"], ["scene.yaml exists", "--force"]),
    ("synth-2to1", nothing, ["synth", "{s}/new", "--width", "600", "--height", "256"],
     ["--width must be twice --height", "600x256"]),
    ("demo-odd", nothing, ["demo", "{s}/new", "--width", "1023"],
     ["--width must be twice --height", "1023x511"]),
    ("synth-small", nothing, ["synth", "{s}/new", "--width", "256"],
     ["--width 256", "256x128 panorama is smaller than the 512x256 that pano4d train reads"]),
    ("demo-small", nothing, ["demo", "{s}/new", "--width", "510"],
     ["--width 510", "510x255", "512x256"]),
    ("batch-missing", nothing, ["batch", "{s}/nope.yaml", "--report", "{s}/batch.json"],
     ["nope.yaml not found"]),
    ("render-stereo-perspective", nothing,
     ["render", "{s}/output/scene.ply4d", "-o", "{s}/v.mp4", "--stereo", "top-bottom"],
     ["--stereo top-bottom", "add --projection equirect"]),
    ("render-stereo-mode", nothing,
     ["render", "{s}/output/scene.ply4d", "-o", "{s}/v.mp4", "--projection", "equirect",
      "--stereo", "side-by-side"], ["--stereo", "'side-by-side'", "top-bottom"]),
    ("render-ipd", nothing,
     ["render", "{s}/output/scene.ply4d", "-o", "{s}/v.mp4", "--projection", "equirect",
      "--stereo", "top-bottom", "--ipd", "0"], ["--ipd 0.0", "must be positive"]),
    ("render-ipd-negative", nothing,
     ["render", "{s}/output/scene.ply4d", "-o", "{s}/v.mp4", "--projection", "equirect",
      "--stereo", "top-bottom", "--ipd", "-0.1"], ["--ipd -0.1", "must be positive"]),
    ("render-equirect-2to1", nothing,
     ["render", "{s}/output/scene.ply4d", "-o", "{s}/v.png", "--projection", "equirect",
      "--width", "1000", "--height", "600"], ["1000x600", "must be 2:1"]),
    ("render-equirect-8k", nothing,
     ["render", "{s}/output/scene.ply4d", "-o", "{s}/v.mp4", "--projection", "equirect",
      "--width", "16384"], ["16384x8192", "1 to 8192"]),
    ("render-stereo-8k", nothing,
     ["render", "{s}/output/scene.ply4d", "-o", "{s}/v.mp4", "--projection", "equirect",
      "--stereo", "top-bottom", "--width", "8192", "--height", "16384"],
     ["8192x16384", "1 to 8192"]),
    ("render-equirect-turntable", nothing,
     ["render", "{s}/output/scene.ply4d", "-o", "{s}/v.mp4", "--projection", "equirect",
      "--path", "turntable"], ["--path 'turntable'", "fly-through"]),
    ("export-format", nothing,
     ["export", "{s}/output/scene.ply4d", "{s}/out.xyz", "--format", "xyz"],
     ["--format 'xyz'", "ply, compressed-ply, spz, sog, splat"]),
    ("export-sequence-time", nothing,
     ["export", "{s}/output/scene.ply4d", "{s}/seq", "--sequence", "--time", "1"],
     ["--sequence", "--time 1"]),
]  # fmt: skip


@pytest.mark.parametrize(("breakage", "args", "words"), [c[1:] for c in CASES],
                         ids=[c[0] for c in CASES])  # fmt: skip
def test_bad_input_is_one_line_and_loses_nothing(
    scene: Path, breakage: Callable[[Path], None], args: list[str], words: list[str]
) -> None:
    breakage(scene)
    before = tree_digest(scene)
    line = error_line(pano4d(*(a.replace("{s}", str(scene)) for a in args)))
    for word in words:
        assert word in line, (word, line)
    assert tree_digest(scene) == before


def test_no_adapter_is_one_line(tmp_path: Path) -> None:
    line = error_line(pano4d("info", env={"PANO4D_ADAPTER": "no-such-adapter"}))
    assert "no wgpu adapter" in line and "PANO4D_ADAPTER" in line and "no-such-adapter" in line


def test_option_values_are_checked_before_anything_runs(tmp_path: Path) -> None:
    for args in (["synth", tmp_path / "s", "--frames", "0"],
                 ["demo", tmp_path / "d", "--frames", "1"],
                 ["train", tmp_path / "x.yaml", "--checkpoint-every", "0"],
                 ["demo", tmp_path / "d", "--preset", "fast"]):  # fmt: skip
        result = pano4d(*args)
        assert result.returncode == 2 and "Invalid value" in result.stderr, result.stderr
        assert "Traceback" not in result.stderr
    assert not any(tmp_path.iterdir())


# An internal error: the library raising something that is no input error.
BROKEN_LIBRARY = """
import sys
import pano4d.config

def load_config(path):
    raise ZeroDivisionError("planted")

pano4d.config.load_config = load_config
from pano4d.cli import main
sys.argv[0] = "pano4d"
main()
"""


def test_an_internal_error_exits_1_with_the_traceback_only_under_debug(scene: Path) -> None:
    line = error_line(python("-c", BROKEN_LIBRARY, "check", scene / "scene.yaml"), 1)
    assert "internal error" in line and "ZeroDivisionError: planted" in line
    assert "pano4d --debug check" in line
    debug = python("-c", BROKEN_LIBRARY, "--debug", "check", scene / "scene.yaml")
    assert debug.returncode == 1
    assert "Traceback (most recent call last)" in debug.stderr and "in load_config" in debug.stderr


# --- a full disk ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def disk(tmp_path_factory: pytest.TempPathFactory, trained: Path) -> Iterator[TinyDisk]:
    """A tmpfs holding the tiny scene trained where it lies (scene/) and a copy (pristine/)."""
    with tiny_disk(tmp_path_factory.mktemp("tmpfs")) as disk:
        inputs = shutil.ignore_patterns("output")
        shutil.copytree(trained.with_name("pristine"), disk.root / "scene", ignore=inputs)
        train_in_place(disk.mountpoint / "scene", prefix=disk.enter)
        shutil.copytree(disk.root / "scene", disk.root / "pristine")
        yield disk


def longer_training(folder: Path) -> None:
    """A lifting knob changed: the static and dynamic stages must run again."""
    yaml = folder / "scene.yaml"
    yaml.write_text(yaml.read_text().replace("gaussian_iterations: 12", "gaussian_iterations: 16"))


def fresh_animation(folder: Path) -> None:
    shutil.rmtree(folder / "output" / "animate")


FULL_DISK: list[Case] = [
    ("train", longer_training, ["train", "{s}/scene.yaml", "--checkpoint-every", "4"],
     ["{s}/output/checkpoints/static.pt"]),
    ("animate", fresh_animation, ["animate", "{s}/scene.yaml"], ["{s}/output/animate/"]),
    ("synth", nothing, ["synth", "{s}/new", "--width", "512", "--frames", "2"], ["{s}/new/"]),
    ("demo", nothing, ["demo", "{s}/new", "--width", "512", "--frames", "2"], ["{s}/new/"]),
    ("render", nothing, ["render", "{s}/output/scene.ply4d", "-o", "{s}/view.png"],
     ["{s}/view.png"]),
    ("render-path", nothing,
     ["render", "{s}/output/scene.ply4d", "-o", "{s}/view.mp4", "--path", "turntable",
      "--frames", "4", "--width", "64", "--height", "32"], ["{s}/view.mp4"]),
    ("export", nothing, ["export", "{s}/output/scene.ply4d", "{s}/t0.ply"], ["{s}/t0.ply"]),
    ("export-sequence", nothing,
     ["export", "{s}/output/scene.ply4d", "{s}/seq", "--format", "sog", "--sequence"],
     ["{s}/seq:"]),
    ("render-360", nothing,
     ["render", "{s}/output/scene.ply4d", "-o", "{s}/vr.mp4", "--projection", "equirect",
      "--width", "64"], ["{s}/vr.mp4"]),
    ("init", nothing, ["init", "{s}/other.yaml"], ["{s}/other.yaml"]),
]  # fmt: skip


@pytest.mark.parametrize(("name", "breakage", "args", "words"), FULL_DISK,
                         ids=[c[0] for c in FULL_DISK])  # fmt: skip
def test_a_full_disk_is_one_line_and_loses_nothing(
    disk: TinyDisk,
    name: str,
    breakage: Callable[[Path], None],
    args: list[str],
    words: list[str],
) -> None:
    seen = restored(disk.root / "scene")  # the test's view of the scene folder on the tmpfs
    inside = disk.mountpoint / "scene"  # the command's
    breakage(seen)
    before = tree_digest(seen)
    filler = disk.fill()
    try:
        result = pano4d(*(a.replace("{s}", str(inside)) for a in args), prefix=disk.enter)
        line = error_line(result)
        assert "No space left on device" in line, line
        for word in words:
            assert word.replace("{s}", str(inside)) in line, (word, line)
        assert tree_digest(seen) == before  # nothing half-written, no temporary file left
    finally:
        filler.unlink()
    if name == "train":  # with the space back, the same command finishes
        again = pano4d(*(a.replace("{s}", str(inside)) for a in args), prefix=disk.enter)
        assert again.returncode == 0, again.stderr
