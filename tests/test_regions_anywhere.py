"""Regions of any size anywhere (a property test): a box, a click or a painted mask from one
pixel to the whole sphere, at the poles, across the seam, on panoramas from 512×256 to
8192×4096. Every region that covers an input pixel passes `pano4d check`, animates at the
working size (keeping at least one working pixel) and reaches `prepare`'s moving region;
one that covers no input pixel is refused with one line naming it, by `pano4d check` and by
the animating phase alike. Never an internal error."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from pano4d.animate.pipeline import animation_input, run_animate
from pano4d.cli import app
from pano4d.config import validate_config
from pano4d.images import write_image
from pano4d.lift.pipeline import prepare, working_panorama
from pano4d.regions import RegionError, region_mask

WIDTHS = (512, 2048, 8192)
MASK_WIDTH = 512  # painted masks are resized to the panorama (nearest neighbour)
TINY = {"view_size": 32}  # a 128-px-wide working panorama at draft's 90° views


@pytest.fixture(scope="module")
def panoramas(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    """One textured panorama per width (written once: an 8192-wide one takes seconds)."""
    folder = tmp_path_factory.mktemp("panoramas")
    rng = np.random.default_rng(0)
    texture = rng.random((16, 32, 3), dtype=np.float32)
    paths = {}
    for width in WIDTHS:
        image = np.kron(texture, np.ones((width // 32, width // 32, 1), np.float32))
        paths[width] = folder / f"panorama{width}.png"
        write_image(paths[width], image)
    return paths


@st.composite
def regions(draw: st.DrawFn) -> tuple[int, dict[str, Any], np.ndarray | None]:
    """(panorama width, the region as scene.yaml has it, a painted mask or None)."""
    width = draw(st.sampled_from(WIDTHS))
    height = width // 2
    kind = draw(st.sampled_from(["box", "click", "mask"]))
    # Sizes from a fraction of a pixel to the whole sphere, log-uniform.
    extent = width * 2.0 ** draw(st.floats(-np.log2(width) - 2, 0.0))
    # Positions: at the seam, at a pole, or anywhere.
    u = draw(st.one_of(st.just(0.0), st.just(width - 0.5), st.floats(0.0, width - 0.01)))
    v = draw(st.one_of(st.just(0.0), st.just(height - 0.5), st.floats(0.0, height - 0.01)))
    motion = {"direction_deg": draw(st.sampled_from([0.0, 90.0])), "speed": 2.0}
    if kind == "box":
        top, bottom = v, min(float(height), v + max(extent / 2, 0.01))
        if bottom <= top:
            top, bottom = v - 0.01, v
        right = (u + extent) % width if extent < width else width
        if right == u:
            right = (u + 0.01) % width
        return width, {"box": [u, top, right, bottom], "motion": motion}, None
    if kind == "click":
        size = max(1, round(extent))
        return width, {"click": [u, v], "size": size, "motion": motion}, None
    scale = width // MASK_WIDTH
    mask = np.zeros((MASK_WIDTH // 2, MASK_WIDTH), np.float32)
    row, column = int(v) // scale, int(u) // scale
    side = max(1, round(extent / scale))
    columns = np.arange(column, column + side) % MASK_WIDTH
    mask[row : row + max(1, side // 2)][:, columns] = 1.0
    return width, {"mask": "mask.png", "motion": motion}, mask


@settings(
    max_examples=14,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(case=regions())
def test_any_region_anywhere_trains_or_is_refused_in_one_line(
    case: tuple[int, dict[str, Any], np.ndarray | None],
    panoramas: dict[int, Path],
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    width, region, mask = case
    folder = tmp_path_factory.mktemp("scene")
    if mask is not None:
        write_image(folder / "mask.png", mask)
    raw = {
        "panorama": str(panoramas[width]),
        "regions": [region],
        "animate": {"frames": 2},
        "preset": "draft",
        "overrides": TINY,
        "output": "out",
    }
    cfg = validate_config(raw, base_dir=folder)
    (folder / "scene.yaml").write_text(_yaml(raw))
    checked = CliRunner().invoke(app, ["check", str(folder / "scene.yaml")])
    covers = bool(region_mask(cfg.regions[0], width, width // 2).any())
    if not covers:
        assert checked.exit_code == 2, checked.output
        lines = [line for line in checked.output.splitlines() if line.strip()]
        assert lines == [lines[0]] and lines[0].startswith("error: regions[0]"), checked.output
        with pytest.raises(RegionError, match=r"regions\[0\].*covers no pixel"):
            run_animate(cfg, working_panorama(cfg)[1], progress=False)
        return
    assert checked.exit_code == 0, checked.output
    size = working_panorama(cfg)[1]
    working = animation_input(cfg, size).regions
    assert working.mask.any() and bool((working.blend[working.mask] > 0).all())
    animated = run_animate(cfg, size, progress=False)
    assert animated.store.complete() and animated.store.size() == size
    inputs = prepare(cfg, animated.store.folder, "torch", "torch")
    assert tuple(inputs.frames.shape[1:3]) == (size[1], size[0])
    assert bool(inputs.moving[working.mask].all())
    assert torch.isfinite(inputs.frames).all()


def _yaml(raw: dict[str, Any]) -> str:
    import yaml

    return yaml.safe_dump(raw)
