"""`pano4d batch` on a local Ray instance: three tiny scenes, one with a broken panorama.

`pano4d train` reproduces a scene bit for bit run to run on one torch thread and one
lavapipe thread (with more, CPU reductions and the rasteriser's float atomic adds change
order, and the optimisation drifts). A one-CPU batch slot trains on one of each, so a batch
task must write the very bytes `pano4d train` writes alone under the same two settings.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import torch
from typer.testing import CliRunner

from pano4d.batch import BatchError, collect_scenes
from pano4d.cli import app
from pano4d.images import write_image
from pano4d.synth import run_synth

runner = CliRunner()
TINY = "overrides: {view_size: 32, init_stride: 8, align_iterations: 20, gaussian_iterations: 20}\n"
# wall times, ratios made of them, and where a run resumed its stages
DETERMINISTIC_METRICS_SKIP = ("timings_s", "saving", "resumed_at")
ONE_THREAD = {"OMP_NUM_THREADS": "1", "LP_NUM_THREADS": "1"}  # what a one-CPU slot runs on
KILLED_IN_DYNAMIC = """
import sys
from pano4d.config import load_config
from pano4d.train import run_train

def kill(stage, step):
    if stage == "dynamic":
        raise SystemExit(3)

run_train(load_config(sys.argv[1]), progress=False, on_step=kill)
"""


def _scene(folder: Path, seed: int) -> Path:
    """A 512×256, 2-frame synthetic scene whose training takes seconds."""
    path = run_synth(folder, 512, 256, 2, seed, views=2)
    text = path.read_text().replace("speed: 30", "speed: 3")  # less for the flow tracer to trace
    path.write_text(text + TINY)
    return path


def _one_thread(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, **ONE_THREAD}
    return subprocess.run([sys.executable, *args], env=env, capture_output=True, text=True)


def _train_alone(scene: Path) -> Path:
    """`pano4d train` on one scene; its output moved aside to make room for the batch's."""
    done = _one_thread("-m", "pano4d.cli", "train", str(scene))
    assert done.returncode == 0, done.stderr
    alone = scene.parent / "alone"
    (scene.parent / "output").rename(alone)
    return alone


def _batch(root: Path) -> tuple[Any, dict[str, Any]]:
    """The batch as a user gives it: a list file (one scene file, one folder) and a folder."""
    listing = root / "scenes.txt"
    listing.write_text("# two of the three\na/scene.yaml\n\nc   # the broken one\n")
    report = root / "batch.json"
    result = runner.invoke(app, ["batch", str(listing), str(root / "b"), "--report", str(report)])
    scenes = json.loads(report.read_text())["scenes"]
    return result, {Path(s["scene"]).parent.name: s for s in scenes}


@pytest.fixture(scope="module")
def first_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("batch")
    a, b = _scene(root / "a", 0), _scene(root / "b", 1)
    (root / "c").mkdir()
    shutil.copy(a, root / "c" / "scene.yaml")
    shutil.copy(root / "a" / "mask.png", root / "c" / "mask.png")
    (root / "c" / "panorama.png").write_bytes(b"not a png")
    alone = {"a": _train_alone(a), "b": _train_alone(b)}
    killed = _one_thread("-c", KILLED_IN_DYNAMIC, str(b))  # b dies once its static set is done
    assert killed.returncode == 3, killed.stderr
    assert (root / "b" / "output" / "checkpoints" / "static.pt").is_file()
    assert not (root / "b" / "output" / "scene.ply4d").exists()
    result, scenes = _batch(root)
    return {"root": root, "alone": alone, "result": result, "scenes": scenes}


def _unwrapped(text: str) -> str:
    """Console output with rich's line wrapping undone."""
    return " ".join(text.split())


def _metrics(folder: Path) -> dict[str, Any]:
    metrics = json.loads((folder / "metrics.json").read_text())
    return {k: v for k, v in metrics.items() if k not in DETERMINISTIC_METRICS_SKIP}


def test_batch_trains_each_scene_as_train_would_and_reports_the_broken_one(
    first_run: dict[str, Any],
) -> None:
    result, scenes, root = first_run["result"], first_run["scenes"], first_run["root"]
    assert result.exit_code == 1, result.output  # not every scene succeeded
    assert {k: s["status"] for k, s in scenes.items()} == {
        "a": "ok",
        "b": "resumed",
        "c": "failed",
    }
    assert scenes["a"]["resumed_from"] is None
    assert scenes["b"]["resumed_from"] == "dynamic t=0"  # killed half-way, resumed there
    error = scenes["c"]["error"]
    assert "\n" not in error and "panorama.png" in error and "cannot read" in error, error
    assert "Traceback" in Path(scenes["c"]["log"]).read_text()
    output = _unwrapped(result.output)  # a long path moves where rich wraps the line
    assert "failed" in output and "cannot read this image" in output
    for name in ("a", "b"):
        out, alone = root / name / "output", first_run["alone"][name]
        assert (out / "scene.ply4d").read_bytes() == (alone / "scene.ply4d").read_bytes(), name
        assert _metrics(out) == _metrics(alone), name
        row = scenes[name]
        assert set(row["timings_s"]) >= {"animate", "depth", "align", "static", "dynamic"}
        assert row["gaussians"] > 0 and set(row["psnr"]) == {"1%", "5%"}


def test_a_rerun_skips_the_finished_scenes(first_run: dict[str, Any]) -> None:
    root = first_run["root"]
    written = {n: (root / n / "output" / "scene.ply4d").stat().st_mtime_ns for n in ("a", "b")}
    result, scenes = _batch(root)
    assert result.exit_code == 1, result.output
    assert [scenes[n]["status"] for n in ("a", "b", "c")] == ["skipped", "skipped", "failed"]
    for name in ("a", "b"):
        # Nothing ran: no task time, the stage timings are those the first run recorded.
        assert scenes[name]["wall_s"] is None and scenes[name]["ray"] == {}
        assert scenes[name]["timings_s"] == first_run["scenes"][name]["timings_s"]
        assert (root / name / "output" / "scene.ply4d").stat().st_mtime_ns == written[name]
    assert scenes["c"]["error"] == first_run["scenes"]["c"]["error"]


def test_scene_arguments_expand_and_bad_ones_are_one_clear_line(tmp_path: Path) -> None:
    for name in ("x", "y/deep"):
        (tmp_path / name).mkdir(parents=True)
        (tmp_path / name / "scene.yaml").write_text("")
    listing = tmp_path / "list.txt"
    listing.write_text("x/scene.yaml  # first\ny\nx/scene.yaml\n")
    expected = [tmp_path / "x" / "scene.yaml", tmp_path / "y" / "deep" / "scene.yaml"]
    assert collect_scenes([listing, tmp_path / "y"]) == expected  # each scene once
    listing.write_text("x\nnope/scene.yaml\n")
    with pytest.raises(BatchError, match=r"list\.txt line 2: .*nope.* not found"):
        collect_scenes([listing])
    result = runner.invoke(app, ["batch", str(tmp_path / "missing.yaml")])
    assert result.exit_code == 2 and "missing.yaml not found" in _unwrapped(result.output)


def test_two_scenes_writing_one_output_folder_are_refused(tmp_path: Path) -> None:
    pano = tmp_path / "panorama.png"
    write_image(pano, torch.rand(256, 512, 3).numpy())
    text = "panorama: panorama.png\nregions: [{box: [0, 0, 10, 10]}]\noutput: out\n"
    (tmp_path / "one.yaml").write_text(text)
    (tmp_path / "two.yaml").write_text(text)
    result = runner.invoke(app, ["batch", str(tmp_path), "--report", str(tmp_path / "b.json")])
    assert result.exit_code == 2 and "both write to" in _unwrapped(result.output), result.output
    assert not (tmp_path / "b.json").exists()


def test_without_ray_the_command_says_how_to_install_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    result = runner.invoke(app, ["batch", str(tmp_path)])
    assert result.exit_code == 2
    output = _unwrapped(result.output)
    assert "pip install 'pano4d[cluster]'" in output and "Traceback" not in output


def test_a_gpu_task_renders_on_the_gpu_ray_gave_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """wgpu does not read CUDA_VISIBLE_DEVICES: the task names its GPU's PCI slot instead."""
    import ray

    from pano4d.batch import gpu

    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    smi = bin_dir / "nvidia-smi"
    smi.write_text("#!/bin/sh\necho '0, 00000000:3B:00.0'\necho '1, 00000000:AF:00.0'\n")
    smi.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    # pin_adapter writes os.environ itself: set-then-delete makes monkeypatch restore the
    # variable as it was before this test (absent or not), so it never leaks into later tests.
    monkeypatch.setenv("PANO4D_ADAPTER", "placeholder")
    monkeypatch.delenv("PANO4D_ADAPTER")
    monkeypatch.setattr(ray, "get_gpu_ids", lambda: [1])
    assert gpu.pin_adapter() == "pci:00000000:AF:00.0"
    assert os.environ["PANO4D_ADAPTER"] == "pci:00000000:AF:00.0"
    # The user's own choice stands; a task without a GPU leaves wgpu to pick.
    monkeypatch.setenv("PANO4D_ADAPTER", "cpu")
    assert gpu.pin_adapter() == "cpu"
    monkeypatch.delenv("PANO4D_ADAPTER")
    monkeypatch.setattr(ray, "get_gpu_ids", lambda: [])
    assert gpu.pin_adapter() is None and "PANO4D_ADAPTER" not in os.environ
