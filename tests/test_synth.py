"""Synthetic scenes (pano4d.synth): determinism, exact depth, motion, views and files.

The ``scene`` fixture runs the properties every kind must have on each kind of SCENE_KINDS;
``landscape`` tests what only the outdoor kind has (tests/test_synth_room.py the room's)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

from pano4d import synth
from pano4d.camera import Camera
from pano4d.sphere import equirect_directions, equirect_to_dir
from pano4d.synth.landscape import CAMERA_HEIGHT, LABEL_OBJECT, LABEL_TERRAIN, LABEL_WATER
from pano4d.synth.objects import OBJECT_KINDS
from pano4d.synth.scene import SCENE_KINDS
from pano4d.synth.terrain import FLAT_RADIUS
from pano4d.synth.views import VIEW_FRACTIONS, median_scene_depth, render_panorama, render_view
from pano4d.synth.world import LABEL_SKY, SKY_DEPTH

SEED, WIDTH, HEIGHT, FRAMES = 3, 256, 128, 4


@pytest.fixture(scope="module", params=sorted(SCENE_KINDS))
def scene(request: pytest.FixtureRequest) -> synth.SynthScene:
    return synth.make_scene(SEED, WIDTH, HEIGHT, FRAMES, views=4, view_size=48, kind=request.param)


@pytest.fixture(scope="module")
def landscape() -> synth.SynthScene:
    return synth.make_scene(SEED, WIDTH, HEIGHT, FRAMES, views=4, view_size=48)


def test_same_seed_same_scene_other_seed_other_scene(scene: synth.SynthScene) -> None:
    again = synth.make_scene(SEED, WIDTH, HEIGHT, FRAMES, views=4, view_size=48, kind=scene.kind)
    assert torch.equal(again.panorama, scene.panorama)
    assert torch.equal(again.depth, scene.depth)
    assert torch.equal(again.mask, scene.mask)
    assert torch.equal(again.frames[2], scene.frames[2])
    for a, b in zip(again.views, scene.views, strict=True):
        assert torch.equal(a.image, b.image) and torch.equal(
            a.camera.world_to_cam, b.camera.world_to_cam
        )
        assert a.time == b.time
    other = synth.make_scene(SEED + 1, WIDTH, HEIGHT, FRAMES, views=1, view_size=16,
                             kind=scene.kind)  # fmt: skip
    assert (other.panorama - scene.panorama).abs().mean() > 0.02
    assert other.world.metadata() != scene.world.metadata()


def test_shapes_and_ranges(scene: synth.SynthScene) -> None:
    assert scene.panorama.shape == (HEIGHT, WIDTH, 3) and scene.panorama.dtype == torch.float32
    assert scene.depth.shape == (HEIGHT, WIDTH) and scene.depth.dtype == torch.float32
    assert scene.mask.shape == (HEIGHT, WIDTH) and scene.mask.dtype == torch.bool
    assert scene.frames.shape == (FRAMES, HEIGHT, WIDTH, 3) and len(scene.frames) == FRAMES
    assert float(scene.panorama.min()) >= 0.0 and float(scene.panorama.max()) <= 1.0
    assert torch.equal(scene.frames[0], scene.panorama)
    assert float(scene.depth.max()) == SKY_DEPTH  # the sky, seen from the origin
    # Nothing nearer than the floor or ground below the camera (furniture may be nearer).
    if scene.kind == "landscape":
        assert float(scene.depth.min()) >= CAMERA_HEIGHT * 0.999


def test_every_label_is_drawn(landscape: synth.SynthScene) -> None:
    present = set(landscape.labels.unique().tolist())
    assert {LABEL_SKY, LABEL_TERRAIN, LABEL_WATER} <= present


def test_depth_lies_on_the_surface_it_hit(scene: synth.SynthScene) -> None:
    dirs = equirect_directions(WIDTH, HEIGHT).view(-1, 3)
    points = scene.depth.view(-1, 1) * dirs
    residual = scene.world.surface_residual(points, scene.labels.view(-1))
    assert not residual.isnan().any()
    assert float(residual.abs().max()) < 5e-3


def test_marched_hills_lie_on_the_terrain(landscape: synth.SynthScene) -> None:
    dirs = equirect_directions(WIDTH, HEIGHT).view(-1, 3)
    points = landscape.depth.view(-1, 1) * dirs
    labels = landscape.labels.view(-1)
    residual = landscape.world.surface_residual(points, labels)
    # Hills beyond the flat meadow are marched; the meadow is analytic.
    far = (labels == LABEL_TERRAIN) & (landscape.depth.view(-1) > FLAT_RADIUS)
    assert int(far.sum()) > 100
    assert float(residual[far].abs().max()) < 5e-3


def test_terrain_hits_are_the_first_crossing_along_the_ray(landscape: synth.SynthScene) -> None:
    scene = landscape
    dirs = equirect_directions(WIDTH, HEIGHT).view(-1, 3)
    depth, labels = scene.depth.view(-1), scene.labels.view(-1)
    sel = (labels == LABEL_TERRAIN) & (depth > FLAT_RADIUS + 5)
    d, t_hit = dirs[sel], depth[sel]
    # Dense samples before the hit (finer than the march) must be above the terrain.
    buried = torch.zeros(d.shape[0], dtype=torch.bool)
    for fraction in torch.linspace(0.3, 0.995, 200):
        p = (t_hit * fraction)[:, None] * d
        gap = p[:, 2] - scene.world.terrain.height(p[:, 0], p[:, 1])
        buried |= gap < -0.05
    # A thin ridge skipped at a grazing angle may hide a few rays; not more.
    assert d.shape[0] > 500
    assert float(buried.float().mean()) < 0.01


def test_view_from_the_origin_equals_the_panorama(scene: synth.SynthScene) -> None:
    world, pano, depth = scene.world, scene.panorama, scene.depth
    gen = torch.Generator().manual_seed(0)
    rows = torch.randint(HEIGHT // 8, HEIGHT - HEIGHT // 8, (16,), generator=gen)
    cols = torch.randint(0, WIDTH, (16,), generator=gen)
    for row, col in zip(rows.tolist(), cols.tolist(), strict=True):
        forward = equirect_to_dir(col + 0.5, row + 0.5, WIDTH, HEIGHT)
        # An odd-sized view's centre pixel looks exactly along its forward axis.
        camera = Camera.from_fov(10.0, 9, 9, (0.0, 0.0, 0.0), forward)
        image, z = render_view(world, camera, time=0)
        torch.testing.assert_close(image[4, 4], pano[row, col], atol=2e-3, rtol=0)
        torch.testing.assert_close(z[4, 4], depth[row, col], atol=1e-3, rtol=1e-4)


def test_displaced_views(scene: synth.SynthScene) -> None:
    median = median_scene_depth(scene.world)
    assert len(scene.views) == 4
    for i, view in enumerate(scene.views):
        fraction = VIEW_FRACTIONS[i % 2]
        assert view.displacement_fraction == fraction
        distance = float(torch.linalg.norm(view.camera.position))
        assert distance == pytest.approx(fraction * median, rel=1e-6)
        assert 0 <= view.time < FRAMES
        assert view.image.shape == (48, 48, 3) and view.depth.shape == (48, 48)
        # Each pixel's depth is on a surface: re-cast the unprojected point from the camera.
        uv = view.camera.pixel_grid().view(-1, 2).double()
        points = view.camera.unproject(uv, view.depth.view(-1).double()).float()
        dirs = view.camera.world_directions().view(-1, 3)
        hits = scene.world.cast(view.camera.position.float(), dirs)
        residual = scene.world.surface_residual(points, hits.label)
        assert float(residual.abs().max()) < 1e-2


def test_static_pixels_are_identical_and_moving_pixels_change(scene: synth.SynthScene) -> None:
    frames = scene.frames.to_tensor()
    changed = (frames != frames[:1]).any(dim=-1).any(dim=0)
    assert torch.equal(frames[:, ~scene.mask], frames[:1, ~scene.mask].expand(FRAMES, -1, -1))
    assert not (changed & ~scene.mask).any()  # the mask covers every changed pixel
    assert int(changed.sum()) > 0


def test_the_water_moves(landscape: synth.SynthScene) -> None:
    frames = landscape.frames.to_tensor()
    changed = (frames != frames[:1]).any(dim=-1).any(dim=0)
    water = landscape.labels == LABEL_WATER
    assert bool(changed[water].all())
    assert float(changed[landscape.mask].float().mean()) > 0.3  # clear sky does not change


def test_frames_loop(scene: synth.SynthScene) -> None:
    world = scene.world
    dirs = equirect_directions(WIDTH, HEIGHT).view(-1, 3)
    hits = world.cast(torch.zeros(3), dirs)
    at_loop = world.shade(torch.zeros(3), dirs, hits, FRAMES).view(HEIGHT, WIDTH, 3)
    assert torch.equal(at_loop, scene.panorama)
    # No jump at the wrap: the last-to-first step is like any other step.
    steps = [
        float((scene.frames[(t + 1) % FRAMES] - scene.frames[t]).abs().mean())
        for t in range(FRAMES)
    ]
    assert steps[-1] < 2.0 * min(steps[:-1]) and steps[-1] > 0.5 * max(steps[:-1])


def test_the_world_shows_any_real_time_between_its_frames(scene: synth.SynthScene) -> None:
    # Ground truth half-way between two frames (what a spacetime scene is measured against
    # at t + 0.5): a real time is not truncated to the frame before it, integer times are
    # the frames, and a time a loop later is the same time.
    world = scene.world
    dirs = equirect_directions(WIDTH, HEIGHT).view(-1, 3)
    hits = world.cast(torch.zeros(3), dirs)

    def shade(time: float) -> torch.Tensor:
        return world.shade(torch.zeros(3), dirs, hits, time).view(HEIGHT, WIDTH, 3)

    half = shade(1.5)
    assert torch.equal(shade(1.0), scene.frames[1])
    assert torch.allclose(shade(1.5 + FRAMES), half, atol=1e-5)
    moving = scene.mask
    for neighbour in (scene.frames[1], scene.frames[2]):
        assert float((half - neighbour)[moving].abs().mean()) > 1e-3
    assert torch.equal(half[~moving], scene.frames[1][~moving])


def test_seam_and_poles_are_continuous(scene: synth.SynthScene) -> None:
    pano, depth = scene.panorama, scene.depth

    # Across the 0°/360° seam the image changes as between any two neighbouring columns. A
    # row "jumps" between two columns when its step there is well above the steps either
    # side; the share of rows that jump at the seam is no larger than at most boundaries.
    def jump_share(image: torch.Tensor) -> torch.Tensor:  # per column boundary c-1 | c
        step = (image - image.roll(1, dims=1)).abs().reshape(HEIGHT, WIDTH, -1).amax(-1)
        beside = torch.maximum(step.roll(1, dims=1), step.roll(-1, dims=1))
        return (step > 2 * beside + 0.01).float().mean(dim=0)

    for image in (pano, depth.log()):
        share = jump_share(image)
        assert float(share[0]) <= float(share.quantile(0.95))
    # The top and bottom rows each go round a small circle about the pole (a few centimetres
    # across on the floor or ground): neighbours on it, the seam's pair included, are half a
    # millimetre apart, and textures filtered over a pixel of a 1024-wide panorama (~1 cm)
    # change little over that.
    for row in (0, HEIGHT - 1):
        ring = pano[row]
        assert float((ring.roll(1, dims=0) - ring).abs().max()) < 0.05
        assert float(depth[row].max() / depth[row].min()) < 1.01


def test_objects_are_where_the_metadata_says(landscape: synth.SynthScene) -> None:
    scene = landscape
    world = scene.world
    assert len(scene.world.objects) == len(OBJECT_KINDS)
    for i, obj in enumerate(scene.world.objects):
        centre = torch.tensor(obj.centre)
        to_centre = centre / torch.linalg.norm(centre)
        hits = world.cast(torch.zeros(3), to_centre[None])
        distance = float(torch.linalg.norm(centre))
        if obj.kind == "sphere":
            expected = distance - obj.size[0]
        elif obj.kind == "pole":
            expected = distance * (1.0 - obj.size[0] / math.hypot(*obj.centre[:2]))
        else:  # the box face the ray meets: slab test in the box frame
            local = obj.to_local(torch.zeros(1, 3))[0]
            direction = obj.to_local(to_centre[None], direction=True)[0]
            half = torch.tensor(obj.size)
            expected = float(((-torch.sign(direction) * half - local) / direction).max())
        assert int(hits.label[0]) == LABEL_OBJECT + i
        assert float(hits.depth[0]) == pytest.approx(expected, abs=1e-3)
        assert obj.centre[2] + CAMERA_HEIGHT == pytest.approx(
            obj.size[2], abs=1e-6
        )  # on the ground


def test_panorama_looks_like_a_landscape(landscape: synth.SynthScene) -> None:
    scene = landscape
    pano = scene.panorama
    assert bool((pano.view(-1, 3).std(dim=0) > 0.08).all())
    sky = pano[scene.labels == LABEL_SKY]
    ground = pano[scene.labels == LABEL_TERRAIN]
    assert float(sky.mean()) > float(ground.mean())  # the sky is brighter than the ground
    assert float(sky[:, 2].mean()) > float(sky[:, 0].mean())  # and blue
    assert float(ground[:, 1].mean()) > float(ground[:, 2].mean())  # the meadow is green
    top, bottom = pano[: HEIGHT // 4], pano[3 * HEIGHT // 4 :]
    assert float(top.mean()) > float(bottom.mean())


def test_bad_arguments_are_refused(scene: synth.SynthScene) -> None:
    with pytest.raises(ValueError, match="frames"):
        synth.make_scene(0, 64, 32, 0, kind=scene.kind)
    with pytest.raises(ValueError, match="unknown scene kind 'cave'"):
        synth.make_scene(0, 64, 32, 2, kind="cave")
    with pytest.raises(ValueError, match="2:1"):
        render_panorama(scene.world, 100, 100)
    with pytest.raises(ValueError, match="outside the"):
        scene.world.cast(torch.tensor([500.0, 0.0, 0.0]), torch.tensor([[1.0, 0.0, 0.0]]))


def test_written_folder(scene: synth.SynthScene, tmp_path: Path) -> None:
    from pano4d.config import load_config
    from pano4d.images import read_image

    out = tmp_path / "synth"
    (out / "gt" / "frames").mkdir(parents=True)
    (out / "gt" / "frames" / "0099.png").write_bytes(b"stale")  # from an older, longer run
    yaml_path = synth.write_scene(out, scene, SEED)
    assert yaml_path == out / "scene.yaml"
    files = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
    expected = ["depth.exr", "gt/views.json", "mask.png", "panorama.png", "scene.yaml"]
    expected += [f"gt/frames/{t:04d}.png" for t in range(FRAMES)]
    expected += [f"gt/views/{i:04d}.png" for i in range(len(scene.views))]
    assert files == sorted(expected)

    depth = read_image(out / "depth.exr")
    assert depth.shape == (HEIGHT, WIDTH, 1)
    assert torch.equal(torch.from_numpy(depth[..., 0]), scene.depth)
    mask = read_image(out / "mask.png")
    assert torch.equal(torch.from_numpy(mask[..., 0] > 0.5), scene.mask)
    frame = read_image(out / "gt" / "frames" / "0002.png")
    assert (torch.from_numpy(frame) - scene.frames[2]).abs().max() <= 0.5 / 255 + 1e-6

    data = json.loads((out / "gt" / "views.json").read_text())
    assert data["seed"] == SEED and data["frames"] == FRAMES and data["kind"] == scene.kind
    assert data["scene"] == json.loads(json.dumps(scene.world.metadata()))
    for entry, view in zip(data["views"], scene.views, strict=True):
        camera = Camera.from_dict(entry)
        assert torch.allclose(camera.world_to_cam, view.camera.world_to_cam)
        assert torch.allclose(camera.K, view.camera.K)
        assert entry["time"] == view.time
        assert (out / "gt" / entry["image"]).is_file()

    cfg = load_config(yaml_path)
    assert cfg.seed == SEED
    assert cfg.animate.frames == FRAMES
    hint = scene.world.motion_hint()
    assert cfg.regions[0].motion.speed == pytest.approx(hint.speed, rel=1e-5)
    assert cfg.depth.camera_height == scene.world.camera_height
    assert yaml_path.read_text().startswith(f"# Synthetic {scene.kind} ")
    with pytest.raises(ValueError, match="seed"):
        synth.write_scene(out, scene, SEED + 1)


def test_synth_writes_only_what_train_reads(tmp_path: Path) -> None:
    """`pano4d synth` and the panorama reader of `pano4d train` share one minimum size:
    synth refuses a panorama one pixel pair below it before writing anything, and the
    reader refuses that size and reads the minimum."""
    from typer.testing import CliRunner

    from pano4d.cli import app
    from pano4d.images import (
        PANORAMA_MIN_HEIGHT,
        PANORAMA_MIN_WIDTH,
        ImageError,
        read_panorama,
        write_image,
    )

    below = PANORAMA_MIN_WIDTH - 2
    args = ["--width", str(below), "--frames", "2", "--views", "1"]
    small = CliRunner().invoke(app, ["synth", str(tmp_path / "small"), *args])
    assert small.exit_code == 2, small.output
    expected = f"smaller than the {PANORAMA_MIN_WIDTH}x{PANORAMA_MIN_HEIGHT} that pano4d train"
    assert expected in " ".join(small.output.split())
    assert not (tmp_path / "small").exists()
    for width, readable in ((below, False), (PANORAMA_MIN_WIDTH, True)):
        path = tmp_path / f"{width}.png"
        write_image(path, torch.rand(width // 2, width, 3).numpy())
        if readable:
            assert read_panorama(path).shape == (width // 2, width, 3)
        else:
            with pytest.raises(ImageError, match="smaller than the minimum"):
                read_panorama(path)
