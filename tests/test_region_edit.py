"""The region editor's file side: scene.yaml saved with everything but the regions kept
byte for byte, painted masks beside it, what is written passes `pano4d check`, a box
across the seam read the same by both phases, and the flow preview of unsaved regions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from pano4d import config, region_edit
from pano4d.cli import app
from pano4d.config import ConfigError, load_config
from pano4d.images import read_image, write_image
from pano4d.lift.pipeline import moving_region
from pano4d.regions import region_masks

runner = CliRunner()

COMMENTED = """\
# my lake scene — keep these notes
panorama: pano.png   # from the drone

# what moves
regions:
  # the first region
  - box: [10, 20, 110, 60]
    motion: {direction_deg: 0.0, speed: 0.5}  # slow
  - click: [300, 100]
    size: 32
  # leftover notes after the last region
  #  - mask: old.png

# settings below are mine
animate:
  frames: 3   # short
seed: 7
output: out  # relative
"""


@pytest.fixture
def scene(tmp_path: Path) -> Path:
    pixels = np.random.default_rng(0).random((256, 512, 3), dtype=np.float32)
    write_image(tmp_path / "pano.png", pixels)
    path = tmp_path / "scene.yaml"
    path.write_text(COMMENTED)
    return path


def outside_regions(text: str) -> tuple[str, str]:
    """The text before the first region item and after the last one's lines."""
    start = text.index("  - ")
    end = text.index("  # leftover")
    return text[:start], text[end:]


def painted_mask(folder: Path, name: str = "paint.png") -> Path:
    mask = np.zeros((256, 512), np.float32)
    mask[:20, :] = 1.0  # a cap over the north pole
    path = folder / name
    write_image(path, mask)
    return path


def test_save_keeps_every_byte_outside_the_regions(scene: Path) -> None:
    before = scene.read_text()
    regions = [
        {"name": "sky", "box": [500, 0, 12, 40], "motion": {"direction_deg": 33.5, "speed": 1.25}},
        {"name": "cap", "mask_png": str(painted_mask(scene.parent)), "motion": None},
        {"click": [7, 200], "size": 64},
    ]
    result = region_edit.save_regions(scene, regions)
    after = scene.read_text()
    assert outside_regions(after) == outside_regions(before)
    assert after.count("#") == before.count("#") - 1, "only the comment inside an item goes"
    assert "# slow" not in after
    cfg = load_config(scene)
    assert [r.name for r in cfg.regions] == ["sky", "cap", None]
    assert cfg.regions[0].box == [500, 0, 12, 40]
    assert cfg.regions[0].motion == config.Motion(direction_deg=33.5, speed=1.25)
    mask_file = scene.with_name("scene.cap.mask.png")
    assert cfg.regions[1].mask == mask_file and result["masks"] == [str(mask_file)]
    assert cfg.regions[1].motion is None
    assert (cfg.regions[2].click, cfg.regions[2].size) == ([7, 200], 64)
    assert (cfg.animate.frames, cfg.seed) == (3, 7)
    check = runner.invoke(app, ["check", str(scene)])
    assert check.exit_code == 0, check.output
    # Saving what was read gives the same file again.
    shown = region_edit.open_for_editing(scene, scene.parent / "work")
    for region in shown["regions"]:
        region.pop("mask_png", None)
    region_edit.save_regions(scene, shown["regions"])
    assert scene.read_text() == after


def test_invalid_regions_write_nothing_and_name_the_key(scene: Path) -> None:
    before = scene.read_text()
    regions = [
        {"name": "ok", "mask_png": str(painted_mask(scene.parent))},
        {"box": [10, 60, 20, 30]},
    ]
    with pytest.raises(ConfigError, match=r"regions\[1\]\.box: expected v0 < v1"):
        region_edit.save_regions(scene, regions)
    assert scene.read_text() == before
    assert not scene.with_name("scene.ok.mask.png").exists()
    with pytest.raises(ConfigError, match="at least one moving region"):
        region_edit.save_regions(scene, [])
    empty = scene.parent / "empty.png"
    write_image(empty, np.zeros((128, 256), np.float32))
    with pytest.raises(ConfigError, match=r"regions\[0\] \(hole\): the painted mask is empty"):
        region_edit.save_regions(scene, [{"name": "hole", "mask_png": str(empty)}])
    assert scene.read_text() == before
    assert sorted(p.name for p in scene.parent.iterdir()) == [
        "empty.png", "paint.png", "pano.png", "scene.yaml"
    ]  # fmt: skip


# What `pano4d synth` writes, with a hand-made second region: the comments on its lines
# are what a whole-list rewrite used to drop.
SYNTH_LIKE = """\
panorama: pano.png
regions:
  - mask: mask.png          # white = moves (water, clouds)
    motion: {direction_deg: 0, speed: 0.25}  # cloud drift, degrees of arc per frame

  # the flag, by hand
  - name: flag
    box: [10, 20, 110, 60]  # pole to tip
  - click: [300, 100]
    size: 32   # a small one
seed: 7
"""


def test_save_keeps_the_text_of_every_region_it_does_not_change(scene: Path) -> None:
    painted_mask(scene.parent, "mask.png")
    scene.write_text(SYNTH_LIKE)
    # What the viewer sends back for these regions: numbers as floats, motion spelled out.
    shown = [
        {"mask": "mask.png", "motion": {"direction_deg": 0.0, "speed": 0.25}},
        {"name": "flag", "box": [10.0, 20.0, 110.0, 60.0]},
        {"click": [300.0, 100.0], "size": 32},
    ]
    region_edit.save_regions(scene, shown)
    assert scene.read_text() == SYNTH_LIKE, "nothing changed, nothing rewritten"

    region_edit.save_regions(scene, [*shown, {"name": "sky", "box": [0, 0, 512, 30]}])
    added = scene.read_text()
    assert added == SYNTH_LIKE.replace(
        "seed: 7", "  - name: sky\n    box: [0, 0, 512, 30]\nseed: 7"
    ), "the old regions byte for byte, comments included; the new one after them"

    scene.write_text(SYNTH_LIKE)
    moved = {"name": "flag", "box": [12, 20, 110, 60]}
    region_edit.save_regions(scene, [shown[0], moved, shown[2]])
    assert scene.read_text() == SYNTH_LIKE.replace(
        "    box: [10, 20, 110, 60]  # pole to tip", "    box: [12, 20, 110, 60]"
    ), "only the changed region's lines; the comment above it and the others stay"
    assert load_config(scene).regions[1].box == [12, 20, 110, 60]


@pytest.mark.parametrize(
    ("text", "kept"),
    [
        ("panorama: pano.png\nregions: []  # none yet\nseed: 1\n", ["  # none yet\n", "seed: 1\n"]),
        ("panorama: pano.png\nregions:\nseed: 1\n", ["seed: 1\n"]),
        ("panorama: pano.png\n", ["panorama: pano.png\n"]),
        (
            "panorama: pano.png\nregions: [{box: [1, 2, 3, 4]},\n  {click: [1, 2]}]  # two\n",
            ["  # two\n"],
        ),
        (
            "panorama: pano.png\r\nregions:\r\n- box: [1, 2, 3, 4]\r\n# after\r\nseed: 3\r\n",
            ["\r\n# after\r\nseed: 3\r\n"],
        ),
    ],
)
def test_splice_handles_every_form_of_the_regions_key(
    scene: Path, text: str, kept: list[str]
) -> None:
    regions = [{"name": "a", "box": [5, 6, 7, 8]}, {"click": [9, 10], "motion": {"speed": 1.0}}]
    spliced = region_edit.splice_regions(text, regions, scene.parent)
    for part in kept:
        assert part in spliced
    scene.write_text(spliced)
    cfg = load_config(scene)
    assert [r.model_dump(exclude_none=True) for r in cfg.regions] == [
        {"name": "a", "box": [5, 6, 7, 8]},
        {"click": [9, 10], "motion": {"direction_deg": 0.0, "speed": 1.0}},
    ]


def test_a_box_across_the_seam_is_one_region_for_both_phases(scene: Path) -> None:
    region_edit.save_regions(scene, [{"name": "seam", "box": [492, 100, 20, 140]}])
    cfg = load_config(scene)
    animate = region_masks(cfg, 512, 256)[0].numpy()
    rows, cols = np.nonzero(animate)
    assert (rows.min(), rows.max()) == (100, 139)
    assert set(cols) == set(range(492, 512)) | set(range(20)), "40 columns either side of 0°"
    # The lifting phase grows the same region (a still video adds nothing) by its margin.
    lift = moving_region(cfg, torch.zeros(1, 256, 512, 3), (512, 256)).numpy()
    assert lift[animate].all()
    band = lift[100:140]
    assert band[:, 0].all() and band[:, 511].all(), "grown across the seam, not cut at it"
    assert not lift[:, 100:400].any(), "and nowhere near the far side"


def test_show_gives_the_panorama_masks_and_regions_as_written(scene: Path) -> None:
    painted = painted_mask(scene.parent, "clouds.png")
    region_edit.save_regions(scene, [{"name": "clouds", "mask_png": str(painted)}])
    text = scene.read_text().replace("scene.clouds.mask.png", "./scene.clouds.mask.png")
    scene.write_text(text)
    shown = region_edit.open_for_editing(scene, scene.parent / "work")
    assert (shown["width"], shown["height"]) == (512, 256)
    assert (shown["mask_width"], shown["mask_height"]) == (512, 256)
    assert (shown["frames"], shown["fps"]) == (3, 7.0)
    [region] = shown["regions"]
    assert region["name"] == "clouds" and region["mask"] == "./scene.clouds.mask.png"
    assert np.array_equal(read_image(region["mask_png"]), read_image(painted))
    display = read_image(shown["display"])
    assert display.shape == (256, 512, 3)
    assert np.abs(display - read_image(scene.parent / "pano.png")).max() < 1 / 255
    scene.write_text("panorama: pano.png\nregions: []\n")
    assert region_edit.open_for_editing(scene, scene.parent / "work")["regions"] == []


def test_mask_size_caps_the_editing_resolution() -> None:
    assert region_edit.mask_size(512, 256) == (512, 256)
    assert region_edit.mask_size(4096, 2048) == (2048, 1024)
    assert region_edit.mask_size(6000, 3000) == (2000, 1000)
    assert region_edit.mask_size(5000, 2500) == (1250, 625)


def test_preview_moves_only_the_edited_regions(scene: Path, one_torch_thread: None) -> None:
    regions = [{"box": [100, 40, 300, 120], "motion": {"direction_deg": 0.0, "speed": 3.0}}]
    out = scene.parent / "preview"
    result = region_edit.render_preview(scene, regions, out, width=256)
    assert (result["width"], result["height"], len(result["frames"])) == (256, 128, 3)
    frames = [read_image(path) for path in result["frames"]]
    pano = torch.from_numpy(read_image(scene.parent / "pano.png")).permute(2, 0, 1)[None]
    small = torch.nn.functional.interpolate(pano, size=(128, 256), mode="area")[0]
    small = np.round(small.permute(1, 2, 0).numpy() * 255) / 255
    inside = np.zeros((128, 256), bool)
    inside[20:60, 50:150] = True
    for frame in frames:
        assert np.abs(frame - small)[~inside].max() < 1e-6, "pixels outside the box stay"
    assert np.abs(frames[1] - frames[0])[inside].max() > 0.05, "the box moves"
    assert not any(p.parent == scene.parent for p in map(Path, result["frames"]))


def test_cli_round_trip_and_bad_stdin(scene: Path) -> None:
    payload = json.dumps({"regions": [{"name": "w", "box": [1, 2, 30, 40]}]})
    saved = runner.invoke(app, ["regions", "save", str(scene)], input=payload)
    assert saved.exit_code == 0, saved.output
    assert json.loads(saved.stdout)["scene"] == str(scene.resolve())
    shown = runner.invoke(app, ["regions", "show", str(scene), "--work", str(scene.parent / "w")])
    assert json.loads(shown.stdout)["regions"] == [{"name": "w", "box": [1, 2, 30, 40]}]
    for bad, message in [("{", "malformed JSON"), ('{"regions": 3}', "a list of region")]:
        result = runner.invoke(app, ["regions", "save", str(scene)], input=bad)
        assert result.exit_code == 2 and message in result.output
    result = runner.invoke(
        app, ["regions", "save", str(scene)], input='{"regions": [{"box": [1, 2, 3, 4], "x": 1}]}'
    )
    assert result.exit_code == 2 and "unknown region key(s) ['x']" in result.output


def test_region_names_and_scenes_without_regions(scene: Path) -> None:
    scene.write_text("panorama: pano.png\nregions: [{name: '', box: [1, 2, 3, 4]}]\n")
    with pytest.raises(ConfigError, match=r"regions\[0\]\.name: string should have at least 1"):
        load_config(scene)
    scene.write_text("panorama: pano.png\nregions: []\n")
    with pytest.raises(ConfigError, match="at least one moving region"):
        load_config(scene)
    assert load_config(scene, require_regions=False).regions == []
