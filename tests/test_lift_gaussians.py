"""Initial Gaussians, the static/dynamic split helpers and the per-timestamp optimiser."""

from __future__ import annotations

import math

import pytest
import torch
from sphere_problem import sphere_problem

from pano4d.gaussians import SH_C0, Gaussians
from pano4d.lift.densify import (
    DENSIFY_GRADIENT,
    SPLIT_FACTOR,
    SPLIT_PIXELS,
    Densified,
    split_and_prune,
)
from pano4d.lift.initial import (
    facing_rotations,
    follow_frame_change,
    init_gaussians,
    init_sphere,
    points_in_mask,
    spacetime_start,
)
from pano4d.lift.losses import moved_camera, pearson_loss, sem_alpha
from pano4d.lift.random_dinov2 import random_feature_model
from pano4d.lift.torch_trainer import GaussianTrainer
from pano4d.lift.trainer import Knobs, TrainViews
from pano4d.regions import moving_in_video
from pano4d.spacetime import TimeModel
from pano4d.sphere import equirect_directions, view_layout

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _render(g: Gaussians, camera, background=None):  # type: ignore[no-untyped-def]
    from pano4d.renderer import render

    return render(g, camera, background=background, backend="torch")


def test_init_places_one_disc_per_sample_at_its_depth_with_its_colour() -> None:
    ico = init_sphere(64, 8)
    depth = torch.full((32, 64), 5.0)
    depth[:16] = 40.0  # upper half farther
    frame = torch.zeros(32, 64, 3)
    frame[..., 0] = 1.0
    g = init_gaussians(ico.points, ico.spacing_rad, depth, frame, sh_degree=1)
    assert len(g) == len(ico) and g.sh.shape == (len(ico), 4, 3)
    radius = torch.linalg.norm(g.means, dim=-1)
    low = ico.points[:, 2] < -0.2
    assert torch.allclose(radius[low], torch.tensor(5.0), rtol=1e-4)
    assert torch.allclose(radius[ico.points[:, 2] > 0.2], torch.tensor(40.0), rtol=1e-4)
    # Colour: 0.5 + C0·dc reproduces the frame's red.
    assert torch.allclose(0.5 + SH_C0 * g.sh[:, 0], torch.tensor([1.0, 0.0, 0.0]), atol=1e-5)
    # Footprint grows with depth; the thin axis faces the centre.
    scales = g.log_scales.exp()
    assert torch.allclose(scales[low, 0], torch.tensor(0.7 * ico.spacing_rad * 5.0), rtol=1e-4)
    assert torch.all(scales[:, 2] < scales[:, 0])


def test_a_later_timestamp_starts_with_the_colour_change_of_its_frame() -> None:
    # Frame t − 1 → t: the lower half of the sphere brightens by (0.3, −0.2, 0.1), the upper
    # half is bit-identical. Gaussians well inside each half (bilinear taps on one side).
    ico = init_sphere(64, 2)
    depth = torch.full((32, 64), 4.0)
    before = torch.rand(32, 64, 3) * 0.5 + 0.25
    g = init_gaussians(ico.points, ico.spacing_rad, depth, before, sh_degree=1)
    g.sh[:, 1:] = torch.randn_like(g.sh[:, 1:])  # view-dependent part: not the frame's
    after = before.clone()
    shift = torch.tensor([0.3, -0.2, 0.1])
    after[16:] += shift
    moved = follow_frame_change(g, before, after)
    low, high = ico.points[:, 2] < -0.2, ico.points[:, 2] > 0.2
    gained = SH_C0 * (moved.sh[:, 0] - g.sh[:, 0])
    assert torch.allclose(gained[low], shift.expand(int(low.sum()), 3), atol=1e-5)
    assert torch.equal(moved.sh[high], g.sh[high])  # unchanged pixels: unchanged Gaussians
    assert torch.equal(moved.sh[:, 1:], g.sh[:, 1:])
    for name in ("means", "log_scales", "quats", "opacity_logits"):
        assert torch.equal(getattr(moved, name), getattr(g, name))  # the fit's geometry


def test_the_spacetime_start_is_each_directions_colour_series_in_fourier_terms() -> None:
    # Every direction's colour follows a loop of the first harmonic and the Nyquist one of
    # 4 frames: the start reproduces it at every frame.
    frames_count, height, width = 4, 32, 64
    model = TimeModel(frames_count, colour_harmonics=3, position_harmonics=1)
    t = torch.arange(frames_count, dtype=torch.float64)
    u = 2 * math.pi * t / frames_count
    channel = torch.tensor([0.1, -0.05, 0.08], dtype=torch.float64)
    series = 0.5 + channel * torch.cos(u)[:, None] + 0.04 * torch.cos(2 * u)[:, None]
    frames = series[:, None, None, :].expand(frames_count, height, width, 3).float()
    ico = init_sphere(width, 4)
    g = init_gaussians(ico.points, ico.spacing_rad, torch.full((height, width), 3.0), frames[0])
    start = spacetime_start(g, frames, model)
    for time in range(frames_count):
        rgb = 0.5 + SH_C0 * start.at(float(time)).sh[:, 0]
        assert torch.allclose(rgb, series[time].float().expand_as(rgb), atol=1e-5), time
    assert torch.equal(start.canonical.means, g.means)
    assert bool((start.at(0.0).opacity_logits - g.opacity_logits).abs().max() < 1e-3)
    # Above the frames' Nyquist rate (h = 3 of 4 frames) nothing is fitted.
    assert torch.equal(start.colour_terms[:, 4:], torch.zeros_like(start.colour_terms[:, 4:]))
    assert torch.equal(start.position_terms, torch.zeros_like(start.position_terms))


def test_facing_rotation_turns_local_z_onto_the_direction() -> None:
    d = torch.randn(50, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    d[0] = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    d = d / torch.linalg.norm(d, dim=-1, keepdim=True)
    w, x, y, z = facing_rotations(d).unbind(-1)
    local_z = torch.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], -1)
    assert torch.allclose(local_z, d, atol=1e-10)


def test_the_moving_mask_catches_changes() -> None:
    frames = torch.zeros(3, 8, 16, 3)
    frames[2, 1, 5] = 0.5
    regions = torch.zeros(8, 16, dtype=torch.bool)
    regions[6, 6] = True
    moving = moving_in_video(frames, regions)
    assert moving[1, 5] and moving[6, 6] and moving.sum() == 2


def test_points_in_mask_follows_the_equirect_mapping() -> None:
    dirs = equirect_directions(16, 8, torch.float64).reshape(-1, 3)
    mask = torch.zeros(8, 16, dtype=torch.bool)
    mask[2, 3] = True
    inside = points_in_mask(dirs, mask)
    assert inside.sum() == 1 and inside[2 * 16 + 3]


def test_losses_and_schedule() -> None:
    a = torch.rand(6, 6, generator=torch.Generator().manual_seed(0))
    w = torch.ones(6, 6)
    assert float(pearson_loss(a, 3 * a + 2, w)) == pytest.approx(0.0, abs=1e-5)
    assert float(pearson_loss(a, -a, w)) == pytest.approx(2.0, abs=1e-5)
    assert [sem_alpha(s, 100) for s in (0, 53, 54, 66, 89, 90, 99)] == [
        0.0, 0.0, 0.05, 0.1, 0.1, 0.2, 0.2]  # fmt: skip
    cam = view_layout(1, 80.0, 8)[0]
    moved = moved_camera(cam, torch.tensor([1.0, 2.0, 3.0]))
    assert torch.allclose(moved.position, torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    assert torch.equal(moved.R, cam.R)


def _problem(sh_degree: int = 0) -> tuple[Gaussians, TrainViews]:
    return sphere_problem(12, sh_degree)


def test_optimiser_lowers_the_loss_and_resumes_bit_for_bit() -> None:
    g, views = _problem()
    knobs = Knobs(iterations=16, lambda_geo=0.05)
    reference = GaussianTrainer(g, views, knobs, _render, seed=3)
    first = reference.loss_at(0).item()
    reference.run()
    assert reference.loss_at(0).item() < 0.95 * first

    interrupted = GaussianTrainer(g, views, Knobs(iterations=7, lambda_geo=0.05), _render, seed=3)
    interrupted.run()
    state = interrupted.state_dict()
    resumed = GaussianTrainer(g, views, knobs, _render, seed=3)
    resumed.load_state_dict(state)
    assert resumed.step == 7
    result = resumed.run()
    expected = reference.result()
    for name, tensor in result.tensors().items():
        assert torch.equal(tensor, expected.tensors()[name]), name


def test_frozen_static_set_gets_no_updates_and_densify_respects_the_budget() -> None:
    g, views = _problem()
    static, trainable = g[: len(g) // 2], g[len(g) // 2 :]
    before = static.means.clone()
    trainable = trainable.map(lambda t: t.clone())
    trainable.opacity_logits[:3] = -20.0  # transparent: pruned
    knobs = Knobs(iterations=10, densify=True, densify_every=2, max_gaussians=len(trainable) + 4)
    trainer = GaussianTrainer(trainable, views, knobs, _render, static=static, seed=0)
    trainer.run()
    assert torch.equal(static.means, before)
    assert trainer.static is not None and torch.equal(trainer.static.means, before)
    out = trainer.result()
    assert len(out) <= knobs.max_gaussians
    assert bool((torch.sigmoid(out.opacity_logits) > 0.005).all())
    assert math.isfinite(trainer.last_loss)


def _densify_case(
    sizes_px: list[float], gradients: list[float], budget: int
) -> tuple[Gaussians, Densified]:
    """Gaussians 10 units out whose σ spans ``sizes_px`` working pixels (1 mrad each), each
    seen by 4 steps with mean position gradient ``gradients``, through one decision."""
    n = len(sizes_px)
    pixel = 1e-3
    unit = torch.full((n,), 10.0)
    sigma = torch.tensor(sizes_px) * pixel * 10.0
    g = Gaussians(
        means=torch.tensor([[10.0, 0.1 * i, 0.0] for i in range(n)]),
        log_scales=torch.stack([sigma.log(), sigma.log(), (0.1 * sigma).log()], -1),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]] * n),
        opacity_logits=torch.zeros(n),
        sh=torch.zeros(n, 1, 3),
    )
    count = torch.full((n,), 4.0)
    knobs = Knobs(iterations=10, max_gaussians=budget, pixel_angle=pixel)
    decision = split_and_prune(
        g, unit, torch.tensor(gradients) * count, count, knobs, torch.Generator(), 5
    )
    return g, decision


def test_densification_grows_where_the_gradient_is_and_stops_where_the_fit_is_done() -> None:
    """The rule (3DGS's, in screen-space units): Gaussians whose mean gradient is under
    DENSIFY_GRADIENT are left alone, so a fitted set does not grow whatever its budget;
    those over it are split when they span more than SPLIT_PIXELS working pixels (two
    children 1/SPLIT_FACTOR the size) and cloned when smaller (the original stays)."""
    under, over = 0.5 * DENSIFY_GRADIENT, 2 * DENSIFY_GRADIENT
    large, small = 3 * SPLIT_PIXELS, 0.5 * SPLIT_PIXELS
    g, fitted = _densify_case([large, small, large], [under, under, 0.0], budget=10_000)
    assert len(fitted.gaussians) == len(g) and not bool(fitted.child.any())
    assert fitted.stats.limit == "gradient" and fitted.stats.candidates == 0
    assert fitted.stats.seen == 3  # every one was seen by some step

    g, grown = _densify_case([large, small, large, small], [over, over, under, under], 10_000)
    s = grown.stats
    assert (s.split, s.cloned, s.candidates, s.after) == (1, 1, 2, 6), s
    assert s.limit == "gradient" and s.threshold == pytest.approx(over)
    # The large one is gone, replaced by two children 1/SPLIT_FACTOR its size near it.
    assert sorted(grown.source.tolist()) == [0, 0, 1, 1, 2, 3]
    children = grown.gaussians[(grown.source == 0)]
    assert torch.allclose(children.log_scales, g.log_scales[0] - math.log(SPLIT_FACTOR))
    assert bool(grown.child[grown.source == 0].all())
    # The small one is kept (its moments with it) and copied (moments from zero).
    clone_rows = grown.source == 1
    assert sorted(grown.child[clone_rows].tolist()) == [False, True]
    for copy in grown.gaussians[clone_rows].tensors().values():
        assert torch.equal(copy[0], copy[1])


def test_split_children_are_drawn_from_the_parents_own_ellipsoid() -> None:
    """A disc facing the origin (any direction) splits into children on its surface, spread
    along its wide axes: the jitter is rotated by the Gaussian's quaternion."""
    n = 64
    directions = torch.randn(n, 3, generator=torch.Generator().manual_seed(1))
    dirs = directions / directions.norm(dim=-1, keepdim=True)
    pixel, wide = 1e-3, 0.05
    g = Gaussians(
        means=10.0 * dirs,
        log_scales=torch.tensor([[wide, wide, 1e-3 * wide]]).log().expand(n, 3).clone(),
        quats=facing_rotations(dirs.double()).float(),
        opacity_logits=torch.zeros(n),
        sh=torch.zeros(n, 1, 3),
    )
    count = torch.full((n,), 4.0)
    knobs = Knobs(iterations=10, max_gaussians=10 * n, pixel_angle=pixel)
    d = split_and_prune(
        g, torch.full((n,), 10.0), 2 * DENSIFY_GRADIENT * count, count, knobs,
        torch.Generator().manual_seed(0), 5,
    )  # fmt: skip
    assert d.stats.split == n
    offsets = d.gaussians.means - g.means[d.source]
    normal = (offsets * dirs[d.source]).sum(-1)
    tangent = offsets - normal[:, None] * dirs[d.source]
    assert float(normal.abs().max()) < 5 * 0.5 * 1e-3 * wide  # on the surface
    spread = float(tangent.norm(dim=-1).pow(2).mean().sqrt())
    assert spread == pytest.approx(0.5 * wide * math.sqrt(2), rel=0.25)  # both wide axes


def test_densification_spends_the_budget_on_the_largest_gradients_first() -> None:
    sizes = [3 * SPLIT_PIXELS] * 4
    gradients = [g * DENSIFY_GRADIENT for g in (2.0, 8.0, 4.0, 1.5)]
    _, d = _densify_case(sizes, gradients, budget=6)  # room for 2 of the 4 candidates
    assert d.stats.limit == "budget" and d.stats.candidates == 4 and d.stats.split == 2
    assert sorted(set(d.source[d.child].tolist())) == [1, 2]  # the 8× and 4× ones
    assert len(d.gaussians) == 6 and d.stats.clipped == 0


def test_semantic_loss_runs_with_a_tiny_dinov2_once_the_schedule_starts(tmp_path) -> None:  # type: ignore[no-untyped-def]
    features = random_feature_model(tmp_path, patch_size=6, image_size=12)
    g, views = _problem()
    knobs = Knobs(iterations=4, lambda_sem=1.0, sem_scale=4.0)
    trainer = GaussianTrainer(g, views, knobs, _render, features=features, seed=0)
    trainer.step = 3  # past 54 %: α = 0.05, so the perturbed render and both CLS run
    without = GaussianTrainer(g, views, Knobs(iterations=4), _render, seed=0)
    without.step = 3
    with_sem, plain = trainer.loss_at(0).item(), without.loss_at(0).item()
    assert math.isfinite(with_sem) and with_sem >= plain
    trainer.run()
    assert trainer.step == 4


def test_the_initial_spacing_counts_working_pixels_whatever_the_input_width(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The same preset on a 128- and a 512-wide panorama works at the same resolution (its
    views' pixel size), so it starts from the same Gaussians: ``init_stride`` counts pixels of
    the working panorama, not of the input (which gave 16× the Gaussians for 4× the width)."""
    from pano4d import synth
    from pano4d.config import load_config
    from pano4d.lift.pipeline import initial_sets, prepare

    counts = {}
    for width in (128, 512):
        root = tmp_path / str(width)
        synth.write_scene(root, synth.make_scene(0, width, width // 2, 2, views=1, view_size=8))
        cfg = load_config(root / "scene.yaml")
        cfg = cfg.model_copy(update={"overrides": {"view_size": 16, "init_stride": 2}})
        inputs = prepare(cfg, root / "gt" / "frames", "torch", "torch")
        assert inputs.frames.shape[2] == 72  # 16 px over 80°
        sets = initial_sets(inputs, torch.full(inputs.moving.shape, 5.0))
        counts[width] = sets.points
    assert counts[128] == counts[512] == len(init_sphere(72, 2))
