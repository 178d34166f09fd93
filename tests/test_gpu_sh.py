"""bench/gpu.sh, the one command for every GPU figure, checked here without a GPU: its dry
run, its prerequisite lines, and a smoke run of two parts (one made to fail) on lavapipe."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "bench" / "gpu.sh"
VIEWER_BENCH = ROOT / "target" / "release" / "viewer-bench"


def gpu_sh(*args: str, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(SCRIPT), *args],
        cwd=ROOT,
        env={**os.environ, **env},
        capture_output=True,
        text=True,
        timeout=600,
    )


@pytest.fixture(scope="module")
def viewer_bench() -> Path:
    """The release viewer-bench, built from the current sources (cargo does nothing when
    `cargo test --release` already built it; a stale binary would test old code)."""
    subprocess.run(
        ["cargo", "build", "--release", "--locked", "-p", "pano4d-viewer", "--bin",
         "viewer-bench"],
        cwd=ROOT,
        check=True,
    )  # fmt: skip
    return VIEWER_BENCH


def test_dry_run_names_every_part_and_runs_nothing(tmp_path: Path, viewer_bench: Path) -> None:
    out = tmp_path / "out"
    result = gpu_sh("--smoke", "--dry-run", str(out), VIEWER_BENCH=str(viewer_bench))
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == "prerequisites: all present (smoke mode)"
    scripts = {"raster": "bench/raster.py", "viewer": "viewer-bench",
               "animate": "bench/animate.py", "quality": "bench/quality.py"}  # fmt: skip
    for part, script in scripts.items():
        [line] = [line for line in lines if line.startswith(f"{part}: ")]
        assert script in line, line
    assert any(line.startswith("train_step: ") for line in lines)
    assert not out.exists()


def test_each_missing_prerequisite_is_one_line_and_nothing_runs(tmp_path: Path) -> None:
    """A Python with none of the modules (a bare venv), no viewer-bench: exit 2, one line
    per missing module and one for the binary, no output folder."""
    bare = tmp_path / "bare"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(bare)], check=True)
    out = tmp_path / "out"
    result = gpu_sh(
        str(out),
        PANO4D_GPU_PYTHON=str(bare / "bin" / "python"),
        VIEWER_BENCH=str(tmp_path / "no-viewer-bench"),
        PANO4D_WHEELS=str(tmp_path / "no-wheels"),
    )
    assert result.returncode == 2, result.stdout + result.stderr
    lines = result.stderr.splitlines()
    assert all(line.startswith("gpu.sh: missing: ") for line in lines), lines
    modules = {line.split("Python module ")[1].split(":")[0] for line in lines if "module" in line}
    expected = {"numpy", "torch", "yaml", "rich", "pydantic", "pydantic_core",
                "annotated_types", "typing_inspection", "typing_extensions", "OpenImageIO",
                "diffusers", "transformers", "safetensors", "huggingface_hub",
                "importlib_metadata", "lazy_importer", "kornia", "kornia_rs"}  # fmt: skip
    assert modules == expected
    assert sum("no-viewer-bench" in line for line in lines) == 1
    assert len(lines) == len(expected) + 1 + (0 if _ffmpeg() else 1)
    assert not out.exists()


def _ffmpeg() -> bool:
    return subprocess.run(["sh", "-c", "command -v ffmpeg"], capture_output=True).returncode == 0


def test_a_failing_part_does_not_stop_the_next(tmp_path: Path, viewer_bench: Path) -> None:
    """animate made to fail (frames: 1 is refused), then the viewer's smoke run on lavapipe:
    exit 1, the summary names the failure, and the viewer's JSON is written."""
    out = tmp_path / "out"
    result = gpu_sh(
        "--smoke", str(out), "animate", "viewer",
        VIEWER_BENCH=str(viewer_bench), ANIMATE_ARGS="--frames 1",
    )  # fmt: skip
    assert result.returncode == 1, result.stdout + result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mode"] == "smoke"
    assert summary["parts"]["animate"]["status"].startswith("failed")
    assert summary["parts"]["viewer"]["status"] == "passed"
    assert "failed: animate" in result.stdout
    viewer = json.loads((out / "viewer.json").read_text())
    [case] = viewer["cases"]
    assert case["gaussians"] == 5000 and case["playback"].startswith("all on the GPU")
    assert (out / "animate.log").read_text()  # the failing part's output is kept
