"""scene.yaml loading: defaults, path resolution, and the message of every error path."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from pano4d import config
from pano4d.config import PRESETS, ConfigError, SceneConfig, config_hash, load_config
from pano4d.images import write_image
from pano4d.regions import region_mask

MINIMAL = "panorama: pano.png\nregions:\n  - box: [10, 20, 110, 60]\n"


@pytest.fixture
def scene_dir(tmp_path: Path) -> Path:
    write_image(tmp_path / "pano.png", np.zeros((256, 512, 3), np.float32))
    return tmp_path


def write_yaml(folder: Path, text: str, name: str = "scene.yaml") -> Path:
    path = folder / name
    path.write_text(text)
    return path


def load_error(folder: Path, text: str) -> str:
    path = write_yaml(folder, text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert all(line.startswith(f"{path}: ") for line in message.splitlines()), message
    return message


def test_minimal_config_gets_defaults(scene_dir: Path) -> None:
    cfg = load_config(write_yaml(scene_dir, MINIMAL))
    assert cfg.panorama == scene_dir / "pano.png"
    assert cfg.panorama.is_absolute()
    assert cfg.regions[0].box == [10, 20, 110, 60]
    assert cfg.regions[0].kind == "box"
    assert cfg.regions[0].motion is None
    assert cfg.animate.backend == "flow"
    assert (cfg.animate.frames, cfg.animate.steps, cfg.animate.fps) == (14, 25, 7.0)
    assert (cfg.animate.views, cfg.animate.fov_deg, cfg.animate.dtype) == (20, 80.0, "auto")
    assert cfg.depth.backend == "layout"
    assert (cfg.depth.camera_height, cfg.depth.far) == (1.6, 1000.0)
    assert cfg.features.backend == "none"
    assert (cfg.lift.views, cfg.lift.fov_deg) == (20, 80.0)
    assert cfg.preset == "balanced"
    assert cfg.overrides == {}
    assert cfg.seed == 0
    assert cfg.output == scene_dir / "output"
    assert cfg.device == "auto"


def test_full_config_resolves_paths_against_the_yaml_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    scene = tmp_path / "scenes" / "lake"
    (scene / "inputs").mkdir(parents=True)
    (tmp_path / "models" / "svd").mkdir(parents=True)
    write_image(scene / "inputs" / "pano.png", np.zeros((256, 512, 3), np.float32))
    write_image(scene / "inputs" / "water.png", np.ones((128, 256), np.float32))
    write_image(scene / "inputs" / "depth.exr", np.ones((256, 512), np.float32))
    text = """
panorama: inputs/pano.png
regions:
  - mask: inputs/water.png
    motion: {direction_deg: 90, speed: 1.5}
  - click: [500, 100]
    size: 64
animate: {backend: svd, weights: ../../models/svd, frames: 8, dtype: float16}
depth: {backend: file, path: inputs/depth.exr}
preset: draft
overrides: {gaussian_iterations: 10, lambda_geo: 1}
seed: 3
output: ../runs/lake
device: cpu
"""
    path = write_yaml(scene, text)
    monkeypatch.chdir(tmp_path / "models")  # the working directory must not matter
    cfg = load_config(path)
    assert cfg.regions[0].mask == scene / "inputs" / "water.png"
    assert cfg.regions[0].motion is not None and cfg.regions[0].motion.speed == 1.5
    assert cfg.regions[1].kind == "click" and cfg.regions[1].size == 64
    assert cfg.animate.weights == tmp_path / "models" / "svd"
    assert cfg.depth.path == scene / "inputs" / "depth.exr"
    assert cfg.output == tmp_path / "scenes" / "runs" / "lake"
    knobs = cfg.resolved_preset()
    assert knobs.gaussian_iterations == 10
    assert knobs.lambda_geo == 1
    assert knobs.view_size == PRESETS["draft"]["view_size"]


def test_unknown_keys_suggest_the_close_match(scene_dir: Path) -> None:
    message = load_error(
        scene_dir, "panorama: pano.png\nregons: []\nregions: [{box: [1, 2, 3, 4]}]"
    )
    assert "top level: unknown key 'regons' — did you mean 'regions'?" in message
    message = load_error(scene_dir, MINIMAL + "animate: {framse: 3}\ndepth: {camera_hieght: 2}\n")
    assert "animate: unknown key 'framse' — did you mean 'frames'?" in message
    assert "depth: unknown key 'camera_hieght' — did you mean 'camera_height'?" in message
    message = load_error(
        scene_dir, "panorama: pano.png\nregions:\n  - box: [1, 2, 3, 4]\n    bx: 1"
    )
    assert "regions[0]: unknown key 'bx' — did you mean 'box'?" in message


def test_wrong_type_names_key_value_and_expectation(scene_dir: Path) -> None:
    message = load_error(scene_dir, MINIMAL + "animate: {frames: many}\nseed: 1.5\n")
    assert "animate.frames: expected an integer, got 'many'" in message
    assert "seed: expected an integer, got 1.5" in message
    assert len(message.splitlines()) == 2


def test_quoted_exponent_gets_a_yaml_hint(scene_dir: Path) -> None:
    message = load_error(scene_dir, MINIMAL + "depth: {far: 1e3}\n")
    assert "depth.far: expected a number" in message
    assert "write it unquoted, with a dot, as 1.0e3" in message


def test_bad_enum_lists_the_allowed_values(scene_dir: Path) -> None:
    message = load_error(scene_dir, MINIMAL + "animate: {backend: sdv}\ndevice: gpu\n")
    assert "animate.backend: expected one of 'flow' or 'svd', got 'sdv'" in message
    assert "device: expected one of 'auto', 'cpu' or 'cuda', got 'gpu'" in message


@pytest.mark.parametrize(
    ("section", "expected"),
    [
        ("animate: {backend: svd}", "animate: backend 'svd' needs 'weights'"),
        ("depth: {backend: dpt}", "depth: backend 'dpt' needs 'weights'"),
        ("features: {backend: dinov2}", "features: backend 'dinov2' needs 'weights'"),
        ("depth: {backend: file}", "depth: backend 'file' needs 'path'"),
    ],
)
def test_backends_name_what_they_need(scene_dir: Path, section: str, expected: str) -> None:
    assert expected in load_error(scene_dir, MINIMAL + section + "\n")


def test_missing_files_and_folders_are_reported(scene_dir: Path) -> None:
    (scene_dir / "not_a_folder").write_text("x")
    message = load_error(
        scene_dir,
        "panorama: missing.png\nregions: [{mask: nomask.png}]\n"
        "animate: {backend: svd, weights: not_a_folder}\n",
    )
    assert f"panorama: file not found: {scene_dir / 'missing.png'}, got 'missing.png'" in message
    assert f"regions[0].mask: file not found: {scene_dir / 'nomask.png'}" in message
    assert "animate.weights: expected a weights folder, found a file" in message


def test_empty_regions_needs_one_moving_region(scene_dir: Path) -> None:
    message = load_error(scene_dir, "panorama: pano.png\nregions: []\n")
    assert "regions: a scene needs at least one moving region" in message
    message = load_error(scene_dir, "panorama: pano.png\n")
    assert "regions: required key is missing" in message


@pytest.mark.parametrize(
    ("region", "expected"),
    [
        ("{box: [1, 2, 3]}", "regions[0].box: expected 4 numbers [u0, v0, u1, v1], got [1, 2, 3]"),
        ("{box: [1, 9, 3, 4]}", "regions[0].box: expected v0 < v1"),
        ("{box: [5, 1, 5, 4]}", "regions[0].box: expected u0 ≠ u1"),
        ("{box: [x, 1, 5, 4]}", "regions[0].box[0]: expected a number, got 'x'"),
        ("{click: [1, 2, 3]}", "regions[0].click: expected 2 numbers [u, v]"),
        ("{click: [1, 2], size: 0}", "regions[0].size: expected a value > 0, got 0"),
        ("{box: [1, 2, 3, 4], click: [1, 2]}", "exactly one of mask / box / click, got box, click"),
        (
            "{motion: {speed: 1}}",
            "regions[0]: expected exactly one of mask / box / click, got none",
        ),
        ("{box: [1, 2, 3, 4], size: 8}", "regions[0]: 'size' only applies to a click region"),
    ],
)
def test_bad_regions(scene_dir: Path, region: str, expected: str) -> None:
    assert expected in load_error(scene_dir, f"panorama: pano.png\nregions: [{region}]\n")


def test_range_checks(scene_dir: Path) -> None:
    message = load_error(
        scene_dir,
        MINIMAL + "animate: {frames: 1, motion_bucket: 300, guidance_min: 4}\nlift: {fov_deg: 180}",
    )
    assert "animate.frames: expected a value ≥ 2, got 1" in message
    assert "animate.motion_bucket: expected a value ≤ 255, got 300" in message
    assert "lift.fov_deg: expected a value < 180.0, got 180" in message


def test_guidance_order(scene_dir: Path) -> None:
    message = load_error(scene_dir, MINIMAL + "animate: {guidance_min: 4, guidance_max: 2}\n")
    assert "animate: expected guidance_min ≤ guidance_max, got 4.0 > 2.0" in message


def test_malformed_yaml_reports_line_and_column(scene_dir: Path) -> None:
    message = load_error(
        scene_dir, "panorama: pano.png\nregions:\n  - box: [1, 2, 3, 4]\n\tseed: 1\n"
    )
    assert "malformed YAML at line 4, column 1" in message
    message = load_error(scene_dir, "panorama: pano.png\nregions: [{box: [1, 2, 3, 4]}\n")
    assert "while parsing a flow sequence at line 2, column 10" in message


def test_duplicate_key_is_an_error(scene_dir: Path) -> None:
    message = load_error(scene_dir, MINIMAL + "seed: 1\nseed: 2\n")
    assert "line 5, column 1: key 'seed' appears twice" in message


def test_not_a_mapping_and_empty_file(scene_dir: Path) -> None:
    assert "expected a mapping of keys" in load_error(scene_dir, "- panorama\n")
    assert "the file is empty" in load_error(scene_dir, "")
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(scene_dir / "nope.yaml")


def test_unknown_override_suggests_the_knob(scene_dir: Path) -> None:
    message = load_error(scene_dir, MINIMAL + "overrides: {view_sise: 64, sh_degree: 1.5}\n")
    assert "overrides: unknown knob 'view_sise' (got 64) — did you mean 'view_size'?" in message
    assert "'sh_degree' expects an integer, got 1.5" in message


def test_a_knob_of_words_takes_one_of_them(scene_dir: Path) -> None:
    message = load_error(scene_dir, MINIMAL + "overrides: {dynamic_model: spacetim}\n")
    expected = "'dynamic_model' expects 'per_timestamp', 'spacetime' or 'tracked', got 'spacetim'"
    assert expected in message
    cfg = load_config(write_yaml(scene_dir, MINIMAL + "overrides: {dynamic_model: spacetime}\n"))
    assert cfg.resolved_preset().dynamic_model == "spacetime"


def test_a_knob_outside_its_bounds_is_named_with_them(scene_dir: Path) -> None:
    knobs = "{later_iteration_share: 0, sh_degree: 4, gaussian_iterations: 0, lr_color: -0.1}"
    message = load_error(scene_dir, MINIMAL + f"overrides: {knobs}\n")
    assert "'later_iteration_share' expects a value > 0 and ≤ 1, got 0" in message
    assert "'sh_degree' expects a value ≥ 0 and ≤ 3, got 4" in message
    assert "'gaussian_iterations' expects a value ≥ 1, got 0" in message
    assert "'lr_color' expects a value ≥ 0, got -0.1" in message
    edges = "{later_iteration_share: 1, sh_degree: 0, gaussian_iterations: 1, lr_color: 0}"
    cfg = load_config(write_yaml(scene_dir, MINIMAL + f"overrides: {edges}\n"))
    assert cfg.resolved_preset().later_iteration_share == 1.0


def test_resolved_preset_rejects_unknown_override_set_after_validation(scene_dir: Path) -> None:
    cfg = load_config(write_yaml(scene_dir, MINIMAL))
    bypassed = cfg.model_copy(update={"overrides": {"max_gausians": 5}})
    with pytest.raises(ConfigError, match="did you mean 'max_gaussians'"):
        bypassed.resolved_preset()


def test_presets_share_knobs_and_draft_is_cheapest() -> None:
    names = set(PRESETS["draft"])
    assert all(set(knobs) == names for knobs in PRESETS.values())
    for knob in ("view_size", "align_iterations", "gaussian_iterations", "max_gaussians"):
        assert PRESETS["draft"][knob] < PRESETS["balanced"][knob] <= PRESETS["max"][knob]


def test_config_hash_is_stable_and_sensitive(scene_dir: Path) -> None:
    first = config_hash(load_config(write_yaml(scene_dir, MINIMAL)))
    again = config_hash(load_config(write_yaml(scene_dir, MINIMAL + "seed: 0\n", "same.yaml")))
    other = config_hash(load_config(write_yaml(scene_dir, MINIMAL + "seed: 1\n", "other.yaml")))
    assert first == again
    assert first != other
    assert len(first) == 64 and int(first, 16) >= 0


def test_template_loads_and_documents_every_key(tmp_path: Path) -> None:
    write_image(tmp_path / "lake.png", np.zeros((256, 512, 3), np.float32))
    path = config.write_example(tmp_path / "scene.yaml", panorama="lake.png")
    cfg = load_config(path)
    assert cfg.panorama == tmp_path / "lake.png"
    assert cfg == SceneConfig.model_validate(
        {"panorama": "lake.png", "regions": [{"box": [0, 128, 256, 192], "motion": {}}]},
        context={"base_dir": tmp_path},
    )
    raw = yaml.safe_load(path.read_text())
    assert set(raw) == set(SceneConfig.model_fields)
    for section in ("animate", "depth", "features", "lift"):
        assert set(raw[section]) == set(type(getattr(cfg, section)).model_fields), section
    assert region_mask(cfg.regions[0], 512, 256).sum() == 256 * 64
    text = path.read_text()
    for knob in PRESETS["draft"]:
        assert knob in text, f"template does not mention override knob {knob}"


def test_write_example_refuses_to_overwrite(tmp_path: Path) -> None:
    target = tmp_path / "scene.yaml"
    target.write_text("mine")
    with pytest.raises(FileExistsError, match="force=True"):
        config.write_example(target)
    assert target.read_text() == "mine"
    config.write_example(target, force=True)
    assert target.read_text().startswith("# pano4d scene")
    assert "panorama: panorama.png" in target.read_text()


def test_box_click_and_mask_regions_to_masks(tmp_path: Path) -> None:
    seam = config.Region(box=[500, 10, 20, 20])
    mask = region_mask(seam, 512, 256)
    assert mask[10:20, 500:].all() and mask[10:20, :20].all()
    assert mask.sum() == 10 * 32
    click = config.Region(click=[5, 100], size=16)
    assert click.pixel_box(512, 256) == (509.0, 92.0, 13.0, 108.0)
    assert region_mask(click, 512, 256).sum() == 16 * 16
    with pytest.raises(ConfigError, match=r"outside the 512×256 panorama"):
        region_mask(config.Region(box=[0, 0, 600, 10]), 512, 256)
    write_image(tmp_path / "m.png", np.zeros((128, 256), np.float32))
    blank = config.Region.model_validate({"mask": "m.png"}, context={"base_dir": tmp_path})
    with pytest.raises(ConfigError, match="no white pixels"):
        region_mask(blank, 512, 256)


def test_the_template_names_every_knob() -> None:
    """templates/scene.yaml documents the knobs `overrides:` takes: each one is named there."""
    from pano4d.config import TEMPLATE_PATH, PresetKnobs

    text = TEMPLATE_PATH.read_text(encoding="utf-8")
    missing = [name for name in PresetKnobs.model_fields if name not in text]
    assert not missing, f"templates/scene.yaml does not name the knobs {missing}"


@pytest.mark.parametrize(
    "override",
    [
        "later_iteration_share: 0.3",
        "stop_when_converged: true",
        "dynamic_windows: false",
        "lr_time_centre: 0.02",
        "lr_time_width: 0.01",
    ],
)
def test_a_dynamic_only_knob_keeps_the_stages_before_the_dynamic_one(
    scene_dir: Path, override: str
) -> None:
    """The checkpoints' keys (lift.checkpoints.stage_keys): a knob only the dynamic stage
    reads changes only that stage's key, so a rerun with another value keeps the static
    set; gaussian_iterations changes the static stage's and, chained, the dynamic one's."""
    from pano4d.lift.checkpoints import stage_keys

    def keys(overrides: str) -> dict[str, str]:
        return stage_keys(load_config(write_yaml(scene_dir, MINIMAL + overrides)))

    base = keys("")
    changed = keys(f"overrides: {{{override}}}\n")
    steps = keys("overrides: {gaussian_iterations: 50}\n")
    assert [s for s in base if changed[s] != base[s]] == ["dynamic"]
    assert [s for s in base if steps[s] != base[s]] == ["static", "dynamic"]
