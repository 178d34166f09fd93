"""The pano4d command line: help, init, check, synth argument errors."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from pano4d import ply4d
from pano4d.cli import app
from pano4d.gaussians import Gaussians
from pano4d.spacetime import SpacetimeGaussians, TimeModel

runner = CliRunner()


def test_help_lists_only_working_commands() -> None:
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    for command in ("init", "check", "synth", "demo"):
        assert command in result.output
    assert "panorama" in result.output


def test_init_writes_a_commented_example_and_refuses_to_overwrite(tmp_path: Path) -> None:
    target = tmp_path / "scene.yaml"
    result = runner.invoke(app, ["init", str(target)])
    assert result.exit_code == 0, result.output
    text = target.read_text()
    assert text.lstrip().startswith("#") and "regions:" in text
    again = runner.invoke(app, ["init", str(target)])
    assert again.exit_code == 2
    assert "--force" in again.output
    assert target.read_text() == text  # nothing lost


def test_check_reports_a_malformed_scene_clearly(tmp_path: Path) -> None:
    (tmp_path / "pano.png").write_bytes(b"")
    scene = tmp_path / "scene.yaml"
    scene.write_text("panorama: pano.png\nregons:\n  - box: [0, 0, 10, 10]\n")
    result = runner.invoke(app, ["check", str(scene)])
    assert result.exit_code == 2
    assert "regons" in result.output and "did you mean 'regions'" in result.output


def test_synth_rejects_a_non_2_to_1_size(tmp_path: Path) -> None:
    result = runner.invoke(app, ["synth", str(tmp_path / "s"), "--width", "300", "--height", "200"])
    assert result.exit_code == 2
    assert "twice" in result.output


def test_export_writes_a_plain_ply_and_reports_bad_input(tmp_path: Path) -> None:
    def gs(n: int, offset: float) -> Gaussians:
        return Gaussians(
            torch.rand(n, 3) + offset,
            torch.zeros(n, 3),
            torch.tensor([[1.0, 0, 0, 0]] * n),
            torch.zeros(n),
            torch.zeros(n, 1, 3),
        )

    scene = ply4d.Scene4D(gs(4, 0.0), [gs(2, 1.0), gs(3, 2.0)], [0.0, 0.5], 2.0)
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, scene)
    out = tmp_path / "t1.ply"
    result = runner.invoke(app, ["export", str(path), str(out), "--time", "1"])
    assert result.exit_code == 0, result.output
    assert len(ply4d.read_ply(out)) == 7
    later = runner.invoke(app, ["export", str(path), str(out), "--time", "5.5"])
    assert later.exit_code == 0 and "(time 5.5)" in later.output, later.output
    assert len(ply4d.read_ply(out)) == 7  # 5.5 mod 2 = 1.5: timestamp 1, held
    bad = runner.invoke(app, ["export", str(path), str(out), "--time", "-1"])
    assert bad.exit_code == 2 and "error" in bad.output
    (tmp_path / "junk.ply4d").write_bytes(b"not a scene")
    junk = runner.invoke(app, ["export", str(tmp_path / "junk.ply4d"), str(out)])
    assert junk.exit_code == 2 and "junk.ply4d" in junk.output


def tiny_spacetime_scene(path: Path) -> ply4d.Scene4D:
    """A version-2 scene of 2 static and 5 moving Gaussians looping over 3 frames."""
    canonical = Gaussians(
        torch.rand(5, 3), torch.zeros(5, 3), torch.tensor([[1.0, 0, 0, 0]] * 5),
        torch.zeros(5), torch.zeros(5, 1, 3),
    )  # fmt: skip
    moving = SpacetimeGaussians.still(TimeModel(3, 1, 1), canonical)
    moving.position_terms.uniform_(-1, 1)
    moving.colour_terms.uniform_(-1, 1)
    scene = ply4d.Scene4D(canonical[:2], moving, [0.0, 0.5, 1.0], 2.0)
    ply4d.write(path, scene)
    return scene


def test_export_of_a_version_2_scene_is_its_set_at_the_time(tmp_path: Path) -> None:
    """At a timestamp and between two: the spacetime set evaluated at that real time."""
    path = tmp_path / "scene.ply4d"
    scene = tiny_spacetime_scene(path)
    for time in ("1", "2.5"):
        out = tmp_path / f"t{time}.ply"
        result = runner.invoke(app, ["export", str(path), str(out), "--time", time])
        assert result.exit_code == 0, result.output
        assert f"(time {time})" in result.output
        exported, expected = ply4d.read_ply(out), scene.at(float(time))
        assert len(exported) == 7
        for name, tensor in expected.tensors().items():
            assert torch.equal(exported.tensors()[name], tensor), name
    between = ply4d.read_ply(tmp_path / "t2.5.ply")
    assert not torch.equal(between.means, scene.at(2).means)
    assert not torch.equal(between.means, scene.at(0).means)  # frame 3 is frame 0


@pytest.mark.parametrize("time", ["nan", "-1", "inf", "-inf"])
@pytest.mark.parametrize("command", ["export", "render"])
def test_a_time_that_is_not_one_is_one_error_line(tmp_path: Path, command: str, time: str) -> None:
    path = tmp_path / "scene.ply4d"
    tiny_spacetime_scene(path)
    out = tmp_path / ("out.ply" if command == "export" else "out.png")
    args = [str(path), str(out)] if command == "export" else [str(path), "--out", str(out)]
    result = runner.invoke(app, [command, *args, "--time", time])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: time {time}"), lines
    assert "frames ≥ 0" in lines[0]
    assert not out.exists()


def test_synth_animate_eval_end_to_end(tmp_path: Path) -> None:
    from pano4d import images

    out = tmp_path / "scene"
    assert (
        runner.invoke(
            app, ["synth", str(out), "--width", "512", "--frames", "3", "--views", "1"]
        ).exit_code
        == 0
    )
    for name in ("panorama.png", "depth.exr", "mask.png", "scene.yaml", "gt/views.json"):
        assert (out / name).exists(), name
    whole = tmp_path / "whole"
    result = runner.invoke(app, ["animate", str(out / "scene.yaml"), "--frames-out", str(whole)])
    assert result.exit_code == 0, result.output
    # The frame store: the static panorama once and each frame's moving box.
    crops = sorted((out / "output" / "animate" / "moving").glob("0*.png"))
    assert len(crops) == 3
    frames = sorted(whole.glob("*.png"))
    assert len(frames) == 3
    assert images.read_image(frames[1]).shape == (256, 512, 3)
    evaluated = runner.invoke(app, ["eval", str(out / "scene.yaml")])
    assert evaluated.exit_code == 0, evaluated.output
    assert "static" in evaluated.output
    missing = runner.invoke(app, ["eval", str(tmp_path / "nope.yaml")])
    assert missing.exit_code == 2 and "nope.yaml" in missing.output


def test_check_caps_the_view_size_at_the_panorama_pixel(tmp_path: Path) -> None:
    import numpy as np

    from pano4d.images import write_image

    write_image(tmp_path / "pano.png", np.full((512, 1024, 3), 0.5, dtype=np.float32))
    scene = tmp_path / "scene.yaml"
    scene.write_text("panorama: pano.png\nregions:\n  - box: [0, 0, 10, 10]\npreset: max\n")
    result = runner.invoke(app, ["check", str(scene)])
    assert result.exit_code == 0, result.output
    # An 80° view spans 228 pixels of a 1024-wide panorama: 1024 would only resample them.
    assert "view_size = 224" in result.output and "capped" in result.output
    assert "init_stride = 1" in result.output
