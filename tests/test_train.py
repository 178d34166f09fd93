"""`train` end to end on a tiny synthetic scene: outputs, the static/dynamic split, resume."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
import torch

from pano4d import ply4d, synth
from pano4d.config import SceneConfig, load_config
from pano4d.lift.pipeline import working_size
from pano4d.train import run_train

TINY = {
    "view_size": 16,
    "init_stride": 4,
    "align_iterations": 20,
    "gaussian_iterations": 12,
    "max_gaussians": 5000,
}


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("scene")
    scene = synth.make_scene(0, 128, 64, 3, views=4, view_size=24)
    synth.write_scene(root, scene)
    return root


def _config(scene_dir: Path, output: Path, depth_file: bool = True) -> SceneConfig:
    """The scene's config with tiny knobs; the true frames stand in for the animating phase."""
    frames = output / "animate" / "frames"
    if not frames.exists():
        shutil.copytree(scene_dir / "gt" / "frames", frames)
    cfg = load_config(scene_dir / "scene.yaml")
    update: dict = {"overrides": TINY, "output": output}
    if depth_file:
        update["depth"] = cfg.depth.model_copy(
            update={"backend": "file", "path": scene_dir / "depth.exr"}
        )
    return cfg.model_copy(update=update)


def test_train_writes_the_run_files_with_a_shared_static_set(
    scene_dir: Path, tmp_path: Path
) -> None:
    cfg = _config(scene_dir, tmp_path / "out", depth_file=False)  # embedded layout depth
    metrics = run_train(cfg, progress=False, render_backend="torch", checkpoint_every=4)
    out = tmp_path / "out"
    for name in ("scene.ply4d", "preview.mp4", "contact.png", "metrics.json"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    on_disk = json.loads((out / "metrics.json").read_text())
    assert on_disk["gaussians"] == metrics["gaussians"]
    assert set(on_disk["timings_s"]) >= {"animate", "depth", "align", "static", "dynamic", "export"}
    views = on_disk["novel_views"]["by_displacement"]
    assert set(views) == {"1%", "5%"} and all(v["psnr"] > 5 for v in views.values())
    assert on_disk["saving"]["storage_ratio"] < 1.0
    # The scene's limits: the fit to the working panorama, and what that holds of the input
    # (the working panorama is narrower than the 128-wide input here).
    fit = on_disk["training_fit"]
    assert fit["working_size"] == on_disk["working_size"] and fit["input_size"] == [128, 64]
    assert 10 < fit["fit_psnr"] < 60 and 10 < fit["resolution_psnr"] < 60

    scene = ply4d.read(out / "scene.ply4d")
    assert scene.num_times == 3
    assert scene.provenance["config_hash"] == metrics["config_hash"]
    n_static = len(scene.static)
    assert n_static == metrics["gaussians"]["static"] > 0
    # Static Gaussians are stored once and identical at every timestamp; moving ones differ.
    first = scene.at(0)
    for t in range(1, 3):
        at_t = scene.at(t)
        for name, tensor in at_t.tensors().items():
            assert torch.equal(tensor[:n_static], first.tensors()[name][:n_static]), name
    assert not torch.equal(scene.dynamic[0].sh, scene.dynamic[2].sh)


def test_resume_after_an_interrupt_matches_an_uninterrupted_run(
    scene_dir: Path, tmp_path: Path, interrupt_train: Callable
) -> None:
    reference = _config(scene_dir, tmp_path / "a")
    run_train(reference, progress=False, render_backend="torch", checkpoint_every=4)

    cfg = _config(scene_dir, tmp_path / "b")
    interrupt_train(cfg, [("static", 6), ("dynamic", 5)])
    assert (tmp_path / "b" / "checkpoints" / "static.pt").is_file()
    assert not (tmp_path / "b" / "scene.ply4d").exists()
    run_train(cfg, progress=False, render_backend="torch", checkpoint_every=4)

    a = ply4d.read(tmp_path / "a" / "scene.ply4d")
    b = ply4d.read(tmp_path / "b" / "scene.ply4d")
    for t in range(a.num_times):
        ga, gb = a.at(t), b.at(t)
        assert len(ga) == len(gb)
        for name, tensor in ga.tensors().items():
            assert torch.allclose(tensor, gb.tensors()[name], atol=1e-5), (t, name)


def test_broken_frames_and_bad_arguments_are_clear_errors(scene_dir: Path, tmp_path: Path) -> None:
    cfg = _config(scene_dir, tmp_path / "c")
    (tmp_path / "c" / "animate" / "frames" / "0001.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match=r"0001\.png"):
        run_train(cfg, progress=False, render_backend="torch")
    with pytest.raises(ValueError, match="checkpoint_every"):
        run_train(cfg, progress=False, checkpoint_every=0)


def test_working_size_matches_the_view_pixel() -> None:
    assert working_size(4096, 128, 80.0) == (576, 288)
    assert working_size(256, 512, 80.0) == (256, 128)


def test_without_ground_truth_the_contact_sheet_uses_views_of_the_moving_region(
    scene_dir: Path, tmp_path: Path
) -> None:
    bare = tmp_path / "bare"
    bare.mkdir()
    for name in ("panorama.png", "mask.png", "depth.exr", "scene.yaml"):
        shutil.copy(scene_dir / name, bare / name)
    shutil.copytree(scene_dir / "gt" / "frames", tmp_path / "frames")
    cfg = load_config(bare / "scene.yaml")
    output = tmp_path / "out"
    shutil.copytree(tmp_path / "frames", output / "animate" / "frames")
    cfg = cfg.model_copy(update={"overrides": {**TINY, "gaussian_iterations": 2}, "output": output})
    metrics = run_train(cfg, progress=False, render_backend="torch")
    assert metrics["novel_views"] is None
    assert (output / "contact.png").stat().st_size > 0


def test_the_train_command_ends_with_a_summary_table(scene_dir: Path, tmp_path: Path) -> None:
    """`pano4d train` ends with a few rows (times, Gaussians, novel views, where the files
    are), not metrics.json printed raw."""
    from typer.testing import CliRunner

    from pano4d.cli import app

    text = (scene_dir / "scene.yaml").read_text()
    for name in ("panorama.png", "mask.png"):
        text = text.replace(f": {name}", f": {scene_dir / name}")
    output = tmp_path / "out"
    knobs = ", ".join(f"{k}: {v}" for k, v in TINY.items())
    text = text.replace("output: output", f"output: {output}") + f"overrides: {{{knobs}}}\n"
    (tmp_path / "scene.yaml").write_text(text)
    shutil.copytree(scene_dir / "gt" / "frames", output / "animate" / "frames")
    result = CliRunner().invoke(app, ["train", str(tmp_path / "scene.yaml"), "--backend", "torch"])
    assert result.exit_code == 0, result.output
    metrics = json.loads((output / "metrics.json").read_text())
    rows = {}
    for line in result.output.splitlines():
        what, _, value = line.strip().partition("  ")
        rows[what] = value.strip()
    assert rows["time"].startswith(f"{sum(metrics['timings_s'].values()):.1f}s (animate ")
    assert rows["Gaussians"].startswith(f"{metrics['gaussians']['stored']:,} stored")
    one = metrics["novel_views"]["by_displacement"]["1%"]
    assert rows["novel views"].startswith(f"{one['psnr']:.1f} dB PSNR, SSIM {one['ssim']:.3f}")
    fit = metrics["training_fit"]
    assert rows["limits"].startswith("the Gaussians fit the ")
    assert f"working panorama to {fit['fit_psnr']:.1f} dB" in rows["limits"]
    assert rows["output"] == str(output)
    assert rows["files"] == "scene.ply4d, preview.mp4, contact.png, loss.png, metrics.json"
    assert '"config_hash"' not in result.output and '"timings_s"' not in result.output


def test_the_summary_names_the_lever_of_the_larger_error() -> None:
    """More Gaussians when the fit to the working panorama is the worse of the two limits,
    a finer working panorama when the resampling loses more, and more Gaussians when the
    working panorama is the input's own size."""
    from pano4d.summary import limits

    sizes = {"working_size": [576, 288], "input_size": [4096, 2048]}
    assert "more Gaussians" in limits({**sizes, "fit_psnr": 26.0, "resolution_psnr": 31.0})
    assert "finer working panorama" in limits({**sizes, "fit_psnr": 33.0, "resolution_psnr": 31.0})
    same = {"working_size": [1024, 512], "input_size": [1024, 512]}
    assert "more Gaussians" in limits({**same, "fit_psnr": 40.0, "resolution_psnr": None})
