"""The indoor scene kind (pano4d.synth.room): its layout, exact depth of known surfaces, what
moves, the lights' shadows, the band-limited textures and ``pano4d synth --kind room``.

What every kind must do (determinism, depth on the surface hit, views, seam and poles, loop,
files) is tested for the room too, in tests/test_synth.py."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from pano4d import synth
from pano4d.cli import app
from pano4d.sphere import equirect_directions
from pano4d.synth.room import Room
from pano4d.synth.room_geometry import (
    LABEL_CEILING,
    LABEL_FLOOR,
    LABEL_FURNITURE,
    LABEL_GROUND,
    LABEL_OUTSIDE,
    LABEL_SCREEN,
    LABEL_WALL,
    WALLS,
)
from pano4d.synth.textures import cell_blend, pulse_coverage
from pano4d.synth.world import LABEL_SKY

SEED, WIDTH, HEIGHT, FRAMES = 3, 256, 128, 4


@pytest.fixture(scope="module")
def scene() -> synth.SynthScene:
    return synth.make_scene(SEED, WIDTH, HEIGHT, FRAMES, views=2, view_size=32, kind="room")


def test_layout_is_a_room(scene: synth.SynthScene) -> None:
    room = scene.world
    assert isinstance(room, Room)
    lo, hi = room.box.lo, room.box.hi
    for axis in (0, 1):  # walls 2–6 m from the camera
        assert 2.2 <= -lo[axis] <= 5.0 and 2.4 <= hi[axis] <= 6.0
    assert lo[2] == -room.camera_height and 2.6 <= hi[2] - lo[2] <= 3.3
    for f in room.furniture:  # everything stands inside the room
        local = room.box.to_local(torch.tensor([f.shape.centre]))
        assert room.box.contains(local, margin=0.0), f
    labels = set(scene.labels.unique().tolist())
    assert {LABEL_FLOOR, LABEL_CEILING, LABEL_WALL, LABEL_SCREEN, LABEL_SKY} <= labels
    assert labels & ({LABEL_GROUND} | {LABEL_OUTSIDE + j for j in range(len(room.outside))})
    # Depth spans the room and the far exterior seen through the window.
    depth = scene.depth[scene.labels != LABEL_SKY]
    assert float(depth.median()) < 6.0 and float(depth.max()) > 30.0


def test_known_surfaces_have_exact_depth(scene: synth.SynthScene) -> None:
    room = scene.world
    down_up = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    hits = room.cast(torch.zeros(3), down_up)
    assert hits.label.tolist() == [LABEL_FLOOR, LABEL_CEILING]
    assert float(hits.depth[0]) == pytest.approx(room.camera_height, abs=1e-6)
    assert float(hits.depth[1]) == pytest.approx(room.box.hi[2], abs=1e-6)

    # Through the window: a pane's centre opens onto the exterior, the cross bar is wall.
    win = room.window
    axis, sign = WALLS[win.wall]
    wall_at = room.box.hi[axis] if sign > 0 else room.box.lo[axis]
    quarter_s = win.s0 + (win.s1 - win.s0) / 4
    mid_s, mid_z = (win.s0 + win.s1) / 2, (win.z0 + win.z1) / 2
    targets = torch.zeros(2, 3)
    targets[:, axis] = wall_at
    targets[:, 1 - axis] = torch.tensor([quarter_s, mid_s])
    targets[:, 2] = torch.tensor([(win.z0 + win.z1) / 2 + 0.2, mid_z])
    world = room.box.to_world(targets)
    hits = room.cast(torch.zeros(3), world / torch.linalg.norm(world, dim=-1, keepdim=True))
    distance = torch.linalg.norm(world, dim=-1)
    pane, bar = 0, 1
    assert int(hits.label[pane]) in {LABEL_SKY, LABEL_GROUND} | {
        LABEL_OUTSIDE + j for j in range(len(room.outside))
    }
    assert float(hits.depth[pane]) > 5 * float(distance[pane])
    assert int(hits.label[bar]) == LABEL_WALL
    assert float(hits.depth[bar]) == pytest.approx(float(distance[bar]), rel=1e-6)

    # Spheres seen straight on: the ray to the centre meets the surface at |c| − r.
    seen = 0
    for i, f in enumerate(room.furniture):
        if f.shape.kind != "sphere":
            continue
        centre = torch.tensor(f.shape.centre)
        hit = room.cast(torch.zeros(3), (centre / torch.linalg.norm(centre))[None])
        if int(hit.label[0]) == LABEL_FURNITURE + i:
            seen += 1
            expected = float(torch.linalg.norm(centre)) - f.shape.size[0]
            assert float(hit.depth[0]) == pytest.approx(expected, abs=1e-5)
    assert seen >= 2


def test_nothing_lies_between_the_camera_and_what_it_hits(scene: synth.SynthScene) -> None:
    room = scene.world
    dirs = equirect_directions(WIDTH, HEIGHT).view(-1, 3)[::7]
    hits = room.cast(torch.zeros(3), dirs)
    inside = hits.depth < 1.01 * float(torch.tensor(room.box.hi).abs().max()) * 2
    outside = ~inside | (hits.label == LABEL_SKY) | (hits.label == LABEL_GROUND)
    outside |= hits.label >= LABEL_OUTSIDE
    for fraction in torch.linspace(0.02, 0.995, 60):
        p = (hits.depth * fraction)[:, None] * dirs
        for f in room.furniture:  # no furniture before the hit
            assert bool((f.shape.residual(p) > -1e-4).all()), f
        # Before an indoor hit the ray is inside the room; a ray that reaches the exterior
        # crosses the wall's plane only inside an open pane.
        indoor = ~outside
        assert bool((room.box.residual(p[indoor]) < 1e-4).all())
    axis, sign = WALLS[room.window.wall]
    wall_at = room.box.hi[axis] if sign > 0 else room.box.lo[axis]
    far = outside.nonzero()[:, 0]
    local = room.box.to_local(dirs[far])
    crossing = local * (wall_at / local[:, axis])[:, None]
    assert len(far) > 0
    assert bool(room.window.open_at(crossing[:, 1 - axis], crossing[:, 2]).all())


def test_only_the_screen_and_the_sky_move(scene: synth.SynthScene) -> None:
    frames = scene.frames.to_tensor()
    changed = (frames != frames[:1]).any(dim=-1).any(dim=0)
    assert not (changed & ~scene.mask).any()
    assert torch.equal(scene.mask, (scene.labels == LABEL_SKY) | (scene.labels == LABEL_SCREEN))
    screen = scene.labels == LABEL_SCREEN
    assert int(screen.sum()) > 20 and float(changed[screen].float().mean()) > 0.6
    sky = scene.labels == LABEL_SKY
    assert float(changed[sky].float().mean()) > 0.1  # clouds drift past the window
    # The screen's picture changes a lot between frames, as a video does.
    assert float((frames[1] - frames[0])[screen].abs().mean()) > 0.05


def test_lights_cast_exact_shadows(scene: synth.SynthScene) -> None:
    room = scene.world
    table = next(f for f in room.furniture if f.material == "wood" and f.wall is None)
    x, y, z = table.shape.centre
    light = torch.tensor([x, y, room.box.hi[2] - 0.3])  # straight above the table
    under = torch.tensor([[x, y, -room.camera_height]])  # the floor under its top
    on_top = torch.tensor([[x, y, z + table.shape.size[2] + 1e-3]])
    assert float(room.lit_from(light, under)[0]) == 0.0
    assert float(room.lit_from(light, on_top)[0]) == 1.0
    # The scene's own lights reach most of what the camera sees indoors, not all of it.
    dirs = equirect_directions(WIDTH, HEIGHT).view(-1, 3)[::5]
    hits = room.cast(torch.zeros(3), dirs)
    indoor = (hits.label != LABEL_SKY) & (hits.label != LABEL_GROUND)
    indoor &= hits.label < LABEL_OUTSIDE
    points = hits.depth[indoor, None] * dirs[indoor]
    lit = room.lit_from(room.lights[0].position, points)
    assert 0.5 < float(lit.mean()) < 1.0


def test_thin_lines_fade_to_their_mean_instead_of_aliasing() -> None:
    x = (torch.arange(10_000, dtype=torch.float64) + 0.5) * 1e-4  # off the pulses' edges
    sharp = pulse_coverage(x, 0.1, 0.02, torch.zeros_like(x))  # no footprint: the pulses
    expected = (x.remainder(0.1) < 0.02).to(x.dtype)
    torch.testing.assert_close(sharp, expected, atol=1e-6, rtol=0)
    # Filtered over many periods a pulse train is its duty cycle everywhere.
    wide = pulse_coverage(x, 0.1, 0.02, torch.full_like(x, 1.0))
    torch.testing.assert_close(wide, torch.full_like(x, 0.2), atol=1e-4, rtol=0)
    # Over one pixel the coverage changes by at most (step / footprint), never jumps.
    footprint = torch.full_like(x, 0.01)
    steps = pulse_coverage(x, 0.1, 0.02, footprint).diff().abs()
    assert float(steps.max()) <= float(x[1] - x[0]) / 0.01 * 1.01
    lower, upper, share = cell_blend(x, 0.1, footprint)
    value = torch.lerp(torch.sin(lower), torch.sin(upper), share)  # a value per cell
    assert float(value.diff().abs().max()) <= float(x[1] - x[0]) / 0.01 * 2.0 * 1.01


def test_synth_command_writes_a_room(tmp_path: Path) -> None:
    runner = CliRunner()
    out = tmp_path / "room"
    args = ["synth", str(out), "--kind", "room", "--width", "512", "--frames", "2", "--views", "1"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    text = (out / "scene.yaml").read_text()
    assert text.startswith("# Synthetic room ") and "the screen and the sky" in text
    bad = runner.invoke(app, ["synth", str(tmp_path / "x"), "--kind", "cave"])
    assert bad.exit_code == 2
    assert "--kind must be one of landscape, room, got 'cave'" in bad.output
    assert not (tmp_path / "x").exists()
