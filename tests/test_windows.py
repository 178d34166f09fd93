"""A dynamic step on windows (lift.windows) is the whole view's step: on one step, the loss
and its terms, the pixel gradient where the dynamic set can draw, the parameter gradients
and the Adam update equal the whole-view computation within float tolerance, on both
trainers, with L_temporal and L_geo on; and the windows and the static Gaussians they keep
are what the scene needs."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from pano4d.camera import Camera
from pano4d.gaussians import Gaussians
from pano4d.lift.resident import ResidentTrainer
from pano4d.lift.torch_trainer import GaussianTrainer
from pano4d.lift.trainer import Knobs, Trainer, TrainViews
from pano4d.lift.windows import (
    SSIM_MARGIN,
    ViewWindow,
    previous_in_windows,
    reach_window,
    touching,
    windowed,
)
from pano4d.renderer import RenderOutput, render

W, H = 160, 96
KNOBS = Knobs(iterations=10, lambda_temporal=0.1, lambda_geo=0.05)
# The windows' footprints and every render here in the knobs' rasteriser mode (the default,
# antialiased), as the pipeline draws them.
MODE = ("wgpu", KNOBS.antialiased)


def draw(g: Gaussians, camera: Camera, background: torch.Tensor | None = None) -> RenderOutput:
    return render(g, camera, background=background, antialiased=KNOBS.antialiased)


def cloud(seed: int, n: int, centre: list[float], spread: float, scale: float) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)
    return Gaussians(
        torch.tensor(centre) + spread * torch.randn(n, 3, generator=gen),
        math.log(scale) + 0.3 * torch.randn(n, 3, generator=gen),
        torch.randn(n, 4, generator=gen),
        torch.randn(n, generator=gen) + 1.0,
        torch.cat([0.5 * torch.randn(n, 1, 3, generator=gen),
                   0.1 * torch.randn(n, 3, 3, generator=gen)], dim=1),  # SH degree 1
    )  # fmt: skip


@pytest.fixture(scope="module")
def scene() -> dict[str, object]:
    """A static set filling the view, a small dynamic set to one side, the whole view's
    targets (rgb, Θ's depth, a previous render) and the same as windows."""
    camera = Camera.from_fov(70.0, W, H)
    static = cloud(0, 500, [5.0, 0.0, 0.0], 2.0, 0.08)
    dynamic = cloud(1, 40, [5.0, 1.6, 0.5], 0.1, 0.02)
    full = draw(Gaussians.cat([static, dynamic]), camera).rgb
    gen = torch.Generator().manual_seed(2)
    target = (full + 0.1 * torch.rand(H, W, 3, generator=gen)).clamp(0, 1)
    previous = full + 0.05 * torch.randn(H, W, 3, generator=gen)
    depth = 4.0 + torch.rand(H, W, generator=gen)
    views = TrainViews([camera], target[None], torch.ones(1, H, W), depth[None], previous[None])
    window = reach_window(camera, torch.zeros(H, W), dynamic, *MODE)
    s = draw(static, camera)
    windows = windowed(views, [window], [s])
    static_drawn = static[touching(static, windows.cameras, *MODE)]
    return {
        "camera": camera, "static": static, "dynamic": dynamic, "views": views,
        "window": window, "windows": windows, "static_drawn": static_drawn,
    }  # fmt: skip


def test_the_window_and_the_static_set_follow_the_dynamic_set(scene: dict) -> None:
    window, static, static_drawn = scene["window"], scene["static"], scene["static_drawn"]
    assert isinstance(window, ViewWindow)
    assert window.share(scene["camera"]) < 0.7  # the dynamic set sits to one side
    assert 0 < len(static_drawn) < 0.9 * len(static)
    # Every static Gaussian left out draws nothing into the window.
    camera = scene["windows"].cameras[0]
    dropped = static[~touching(static, [camera], *MODE)]
    assert float(draw(dropped, camera).alpha.max()) == 0.0


def test_the_previous_frame_renders_only_its_window(scene: dict) -> None:
    """t − 1's frame (L_temporal's target) from the window alone pasted into the static render
    is the whole view's render of the static set and t − 1's set (here the dynamic set with
    other colours: a later timestamp starts from t − 1's geometry)."""
    camera, static, window = scene["camera"], scene["static"], scene["window"]
    dynamic: Gaussians = scene["dynamic"]
    gen = torch.Generator().manual_seed(4)
    previous = replace(dynamic, sh=torch.randn(dynamic.sh.shape, generator=gen))
    whole = draw(Gaussians.cat([static, previous]), camera).rgb
    pasted = previous_in_windows(
        draw, [window], [camera], [draw(static, camera)], scene["static_drawn"], previous
    )[0]
    assert window.share(camera) < 0.7
    assert float((whole - draw(static, camera).rgb).abs().max()) > 0.1  # previous shows
    assert torch.allclose(pasted, whole, rtol=0, atol=1e-5)


def trainer(kind: str, views: TrainViews, static: Gaussians, dynamic: Gaussians) -> Trainer:
    if kind == "torch":
        return GaussianTrainer(dynamic, views, KNOBS, draw, static, seed=3)
    return ResidentTrainer(dynamic, views, KNOBS, static=static, seed=3)


def _by_name(parts: object) -> dict[str, float]:
    """A session's LossParts as {part: value}."""
    names = ("total", "l1", "d_ssim", "temporal", "one_minus_pearson", "covered_weight",
             "geo_applied")  # fmt: skip
    return {name: float(getattr(parts, name)) for name in names}


@pytest.mark.parametrize("kind", ["torch", "resident"])
def test_one_windowed_step_is_the_whole_views_step(scene: dict, kind: str) -> None:
    whole = trainer(kind, scene["views"], scene["static"], scene["dynamic"])
    part = trainer(kind, scene["windows"], scene["static_drawn"], scene["dynamic"])
    assert scene["windows"].cameras[0].width < W
    before = scene["dynamic"]
    if isinstance(whole, GaussianTrainer) and isinstance(part, GaussianTrainer):
        for t in (whole, part):
            t.loss_at(0).backward()
        for name, p in whole.params.items():
            q = part.params[name]
            assert p.grad is not None and q.grad is not None
            scale = float(p.grad.abs().max()) + 1e-12
            assert torch.allclose(p.grad, q.grad, rtol=0, atol=1e-4 * scale), name
        losses = [dict(t.last_terms) for t in (whole, part)]
        for t in (whole, part):
            t.optimiser.step()
    else:
        assert isinstance(whole, ResidentTrainer) and isinstance(part, ResidentTrainer)
        for t in (whole, part):
            t._session.step(0)
        losses = [_by_name(t._session.loss()) for t in (whole, part)]
    assert set(losses[0]) == set(losses[1])
    for term, value in losses[0].items():
        assert float(losses[1][term]) == pytest.approx(float(value), rel=1e-5, abs=1e-6), term
    a, b = whole.result(), part.result()
    for name, moved in a.tensors().items():
        step = (moved - before.tensors()[name]).abs().max()
        assert float(step) > 0, name  # the step moved it
        assert float((moved - b.tensors()[name]).abs().max()) <= 1e-4 * float(step), name


def test_the_pixel_gradient_is_the_whole_views_where_the_set_can_draw(scene: dict) -> None:
    """The device's loss gradient on a window equals the whole view's on the window's pixels
    that are more than SSIM_MARGIN from its edges inside the view (the reach and its SSIM
    taps); nearer the edge it differs, but only on pixels no dynamic Gaussian reaches."""
    window: ViewWindow = scene["window"]
    scene_all = Gaussians.cat([scene["static"], scene["dynamic"]])
    camera = scene["camera"]
    gradients = []
    for views, cam in [(scene["views"], camera), (scene["windows"], window.camera(camera))]:
        t = ResidentTrainer(scene["dynamic"], views, KNOBS, static=scene["static"])
        out = draw(scene_all, cam)
        pixels = torch.cat([out.rgb, out.alpha[..., None], (out.depth * out.alpha)[..., None]], -1)
        gradient = t._session.loss_gradient(0, pixels.reshape(-1).numpy()).pixel_gradient
        gradients.append(torch.from_numpy(gradient).reshape(cam.height, cam.width, 5))
    whole, part = window.crop(gradients[0]), gradients[1]
    inner = torch.zeros(window.height, window.width, dtype=torch.bool)
    x0 = SSIM_MARGIN if window.x0 > 0 else 0
    x1 = window.width - (SSIM_MARGIN if window.x0 + window.width < W else 0)
    y0 = SSIM_MARGIN if window.y0 > 0 else 0
    y1 = window.height - (SSIM_MARGIN if window.y0 + window.height < H else 0)
    inner[y0:y1, x0:x1] = True
    scale = float(whole.abs().max())
    assert torch.allclose(whole[inner], part[inner], rtol=0, atol=1e-4 * scale)
