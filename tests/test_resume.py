"""Resume, proven: a real `pano4d train` killed with SIGKILL inside each stage, then rerun.

Every stage is seeded, so a rerun that started over would also match an uninterrupted run;
metrics.json's ``resumed_at`` says where each stage was picked up, and the tests assert it.
After each kill every file under its final name must read back whole (writes are atomic),
and the finished rerun must equal the uninterrupted run bit for bit (one thread: the run is
deterministic).
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
import torch
from pano4d_process import pano4d, tiny_scene

from pano4d import ply4d
from pano4d.gaussians import Gaussians
from pano4d.images import read_image
from pano4d.spacetime import SpacetimeGaussians
from pano4d.train import KILL_AT_ENV

SIGKILLED = -9


def train(folder: Path, kill_at: str | None = None) -> int:
    env = {KILL_AT_ENV: kill_at} if kill_at else None
    done = pano4d("train", folder / "scene.yaml", "--checkpoint-every", "4", env=env)
    assert done.returncode in (0, SIGKILLED), done.stderr
    return done.returncode


def metrics(folder: Path) -> dict:
    return json.loads((folder / "output" / "metrics.json").read_text())


def everything_reads_back(output: Path) -> None:
    """Every file under its final name is whole: a kill leaves only temporary files half
    written (their names start with '.')."""
    for path in output.rglob("*"):
        if not path.is_file() or path.name.startswith("."):
            continue
        if path.suffix == ".pt":
            assert isinstance(torch.load(path, weights_only=False), dict), path
        elif path.suffix in (".png", ".exr"):
            read_image(path)
        elif path.suffix == ".json":
            json.loads(path.read_text())
        elif path.suffix == ".ply4d":
            ply4d.open(path).verify()


def assert_same_scene(a: Path, b: Path) -> None:
    sa, sb = ply4d.read(a / "output" / "scene.ply4d"), ply4d.read(b / "output" / "scene.ply4d")
    assert sa.num_times == sb.num_times
    for t in range(sa.num_times):
        ga, gb = sa.at(t).tensors(), sb.at(t).tensors()
        for name in ga:
            assert torch.equal(ga[name], gb[name]), (t, name)
    # The animating phase's store at the working size (output/animate/WxH/moving).
    frames = sorted((a / "output" / "animate").glob("*/moving/*"))
    assert len(frames) > 2, "the frame store: static.exr, box.json and the frames"
    for frame in frames:
        other = b / frame.relative_to(a)
        if frame.suffix == ".exr":  # its header carries the time it was written (capDate)
            mine, theirs = read_image(frame), read_image(other)
            assert mine.tobytes() == theirs.tobytes(), frame.name
        else:
            assert frame.read_bytes() == other.read_bytes(), frame.name


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny scene trained without interruption, and a copy of its inputs (pristine/)."""
    folder = tmp_path_factory.mktemp("resume") / "reference"
    tiny_scene(folder)
    shutil.copytree(folder, folder.with_name("pristine"))
    assert train(folder) == 0
    return folder


# (where to kill: PANO4D_TEST_KILL_AT, what the rerun's metrics.json must say it resumed)
KILLS = [
    ("animate:2", "animate", {"frame": 2}),  # after frames 0 and 1
    ("depth:2", "depth", {"frame": 2}),
    ("align:25", "align", {"frame": 1}),  # inside frame 1's fit (frame 0 took 20 steps)
    ("static:6", "static", {"step": 4}),  # the checkpoint of step 4
    ("dynamic:9", "dynamic", {"t": 0, "step": 8}),
    ("export:2", "static", {"step": 12}),  # after scene.ply4d, preview.mp4: only export reruns
]


@pytest.mark.parametrize(("kill_at", "stage", "resumed"), KILLS, ids=[k[0] for k in KILLS])
def test_a_run_killed_inside_a_stage_resumes_there_and_ends_as_if_never_killed(
    reference: Path, kill_at: str, stage: str, resumed: dict[str, int]
) -> None:
    # Inputs' hashes cover absolute paths: each case runs in a folder of its own name.
    folder = reference.with_name(kill_at.replace(":", "-"))
    shutil.copytree(reference.with_name("pristine"), folder)
    assert train(folder, kill_at) == SIGKILLED
    everything_reads_back(folder / "output")
    assert train(folder) == 0
    assert metrics(folder)["resumed_at"][stage] == resumed
    assert_same_scene(reference, folder)


def trained_and_killed(reference: Path, name: str, knobs: str) -> list[Path]:
    """The pristine inputs with ``knobs`` added to their overrides, trained twice: without
    interruption (NAME/) and killed inside the dynamic stage, then rerun (NAME-killed/)."""
    runs = []
    for folder, kill_at in ((name, None), (f"{name}-killed", "dynamic:9")):
        run = reference.with_name(folder)
        shutil.copytree(reference.with_name("pristine"), run)
        yaml = run / "scene.yaml"
        yaml.write_text(yaml.read_text().replace("overrides: {", f"overrides: {{{knobs}, "))
        if kill_at is not None:
            assert train(run, kill_at) == SIGKILLED
            everything_reads_back(run / "output")
        assert train(run) == 0
        runs.append(run)
    return runs


def test_the_spacetime_stage_killed_inside_resumes_there_and_ends_as_if_never_killed(
    reference: Path,
) -> None:
    # One dynamic set for every timestamp: its optimisation checkpoints like the static
    # set's (the (view, time) generator's state in it), and a rerun after a kill ends with
    # the same version-2 scene as a run never killed. The static set is the reference's.
    runs = trained_and_killed(reference, "spacetime", "dynamic_model: spacetime")
    assert metrics(runs[1])["resumed_at"]["dynamic"] == {"step": 8}
    assert ply4d.open(runs[0] / "output" / "scene.ply4d").version == 2
    assert metrics(runs[0])["gaussians"]["dynamic_model"] == "spacetime"
    assert_same_scene(*runs)
    static = [ply4d.open(f / "output" / "scene.ply4d").static() for f in (reference, runs[0])]
    assert torch.equal(static[0].means, static[1].means)  # the knob keeps the static stage


def test_the_tracked_stage_killed_inside_resumes_and_passes_through_its_frames(
    reference: Path,
) -> None:
    # The per-timestamp sequence with one set whose positions and colours alone follow the
    # frames, stored as one version-2 set: resumed as the sequence is, and with one harmonic
    # for 3 frames the stored set passes through every frame's pose the sequence kept.
    knobs = "dynamic_model: tracked, colour_harmonics: 1, position_harmonics: 1"
    runs = trained_and_killed(reference, "tracked", knobs)
    assert metrics(runs[1])["resumed_at"]["dynamic"] == {"t": 0, "step": 8}
    assert ply4d.open(runs[0] / "output" / "scene.ply4d").version == 2
    assert metrics(runs[0])["gaussians"]["dynamic_model"] == "tracked"
    assert_same_scene(*runs)
    checkpoint = torch.load(runs[0] / "output" / "checkpoints" / "dynamic.pt", weights_only=False)
    poses = [Gaussians.from_numpy(g) for g in checkpoint["done"]]
    stored = ply4d.read(runs[0] / "output" / "scene.ply4d").dynamic
    assert isinstance(stored, SpacetimeGaussians)
    for t, pose in enumerate(poses):
        for name in ("log_scales", "quats", "opacity_logits"):  # frame 0's throughout
            assert torch.equal(pose.tensors()[name], poses[0].tensors()[name]), (t, name)
        got = stored.at(t)
        assert (got.means - pose.means).abs().max() < 1e-4 * pose.means.abs().max(), t
        assert (got.sh[:, 0] - pose.sh[:, 0]).abs().max() < 1e-4, t
    assert not torch.equal(poses[1].means, poses[0].means)  # the positions did follow
    # every frame's optimisation in losses.json, each having stored the one set
    losses = json.loads((runs[0] / "output" / "losses.json").read_text())
    names = [o["name"] for o in losses["optimisations"]]
    assert names == ["static", *(f"dynamic t={t}" for t in range(len(poses)))]


def test_a_config_change_discards_exactly_the_stages_it_affects(reference: Path) -> None:
    folder = reference.with_name("longer")
    shutil.copytree(reference.with_name("pristine"), folder)
    assert train(folder) == 0
    yaml = folder / "scene.yaml"
    yaml.write_text(yaml.read_text().replace("gaussian_iterations: 12", "gaussian_iterations: 16"))
    assert train(folder) == 0
    resumed_at = metrics(folder)["resumed_at"]
    frames = 3
    assert resumed_at["animate"] == {"frame": frames}  # kept
    assert resumed_at["depth"] == {"frame": frames}  # kept
    assert resumed_at["align"] == {"frame": frames}  # kept
    assert resumed_at["static"] == {"step": 0}  # started over
    assert resumed_at["dynamic"] == {"t": 0, "step": 0}  # started over


# An open(2) that can write: (path, flags) of openat / open / creat lines in strace's log.
OPEN_CALL = re.compile(
    r'\b(?:openat|open|creat)\((?:[^,"]+, )?"((?:[^"\\]|\\.)*)"(?:, ([A-Z0-9_|]+))?'
)


def test_no_file_is_ever_written_under_its_final_name(reference: Path) -> None:
    """Whatever writes it (Python, torch, OpenImageIO, ffmpeg, the Rust extension), a file of
    the output folder is only ever opened for writing under a temporary name (starting with
    '.') and renamed into place when whole: what a kill at any instant can leave behind.
    strace sees every process and language alike."""
    if shutil.which("strace") is None:
        pytest.skip("strace is not installed (scripts/install-apt.sh installs it)")
    folder = reference.with_name("traced")
    shutil.copytree(reference.with_name("pristine"), folder)
    log = folder / "strace.log"
    trace = ("strace", "-f", "-qq", "-e", "trace=%file", "-o", str(log))
    done = pano4d("train", folder / "scene.yaml", "--checkpoint-every", "4", prefix=trace)
    assert done.returncode == 0, done.stderr
    output = (folder / "output").resolve()
    written = []
    for match in OPEN_CALL.finditer(log.read_text()):
        path, flags = Path(match.group(1)), match.group(2) or "O_CREAT"  # creat() has no flags
        if not {"O_WRONLY", "O_RDWR", "O_CREAT"} & set(flags.split("|")):
            continue
        path = path if path.is_absolute() else Path.cwd() / path
        if path.resolve().is_relative_to(output):
            written.append(path)
    assert len(written) > 20, "the trace saw the run's writes"  # frames, checkpoints, scene
    final = sorted({str(p.relative_to(output)) for p in written if not p.name.startswith(".")})
    assert final == [], final
