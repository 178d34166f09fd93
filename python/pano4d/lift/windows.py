"""What a dynamic step redoes: per view, the window of pixels the dynamic set can reach.

While a timestamp's dynamic set trains, the static set is frozen, so outside the pixels the
dynamic Gaussians reach every step's render is the static set's, the same at every step. A
dynamic step therefore renders only a window of each view (``Camera.window``: the same
pixels), with only the static Gaussians that can touch some window (``touching``), and the
loss keeps the whole view's meaning (``TrainViews.weight_sums`` and ``outside``): the L1,
SSIM and L_temporal sums over the rest of the view and L_geo's statistics there are
computed once from the static set's render (``outside_sums``) and added on the device, and
every term is normalised by the whole view's weight.

Why that is exact (tests/test_windows.py checks one step against the whole view):
- the reach is the moving region seen by the view and the dynamic set's 3σ footprints,
  grown by ``REACH_SLACK`` of the view's side (what the set may move or grow during a
  stage); pixels outside it are the static render at every step;
- an SSIM value at pixel c reads the pixels within r = 5 of c (11 taps), so it can change
  only for c within r of the reach, and its taps lie within 2r of the reach: with the
  window ``SSIM_MARGIN`` ≥ 2r + 1 beyond the reach, those values are computed on the
  view's own pixels, and the values near the window's edge (whose taps reflect at the edge,
  not at the view's) read only pixels that cannot change, so they are constants that
  ``outside_sums`` takes back out (it computes the window's own sums on the static render
  the same way and subtracts them from the whole view's);
- the static Gaussians dropped from a step cannot draw into any window (the footprints
  the rasteriser itself reports, ``pano4d.renderer.footprints``, with the backend the
  stage renders with), so the window's pixels are the whole render's.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from pano4d.camera import Camera
from pano4d.gaussians import Gaussians
from pano4d.lift.losses import OUTSIDE_SUMS, SSIM_WINDOW, ssim_map
from pano4d.lift.trainer import TrainViews
from pano4d.renderer import RenderOutput, footprints

SSIM_MARGIN = SSIM_WINDOW  # 2r + 1 pixels between the reach and the window's edge (above)
# What the dynamic set may move or grow beyond its footprints during a stage, as a share of
# the view's side (4 pixels at draft's 128, 16 at balanced's 512).
REACH_SLACK = 1 / 32
# Pixels added to every footprint, in the reach and in the static Gaussians kept. Exactness
# needs none (the footprints are the rasteriser's own); this pixel keeps the windows and
# the static Gaussians kept those of the float64 bound this module computed before the
# renderer reported footprints (it added a pixel for its own rounding), so that training's
# outputs stayed bit-identical through that change.
FOOTPRINT_MARGIN = 1


@dataclass(frozen=True)
class ViewWindow:
    """Pixels [x0, x0 + width) × [y0, y0 + height) of a view."""

    x0: int
    y0: int
    width: int
    height: int

    def camera(self, view: Camera) -> Camera:
        return view.window(self.x0, self.y0, self.width, self.height)

    def crop(self, image: torch.Tensor) -> torch.Tensor:
        """The window of an (H, W, …) image."""
        return image[self.y0 : self.y0 + self.height, self.x0 : self.x0 + self.width]

    def outside(self, height: int, width: int) -> torch.Tensor:
        """(H, W) bool: the view's pixels outside the window."""
        mask = torch.ones(height, width, dtype=torch.bool)
        mask[self.y0 : self.y0 + self.height, self.x0 : self.x0 + self.width] = False
        return mask

    def share(self, view: Camera) -> float:
        """The window's fraction of the view's pixels."""
        return self.width * self.height / (view.width * view.height)


def drawn_footprints(
    g: Gaussians, camera: Camera, backend: str, antialiased: bool
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(N,) bool: the Gaussians whose footprint (with ``backend``'s rasteriser in the mode
    ``antialiased`` says, grown by
    FOOTPRINT_MARGIN) reaches ``camera``'s image, and every Gaussian's centre (N, 2) and that
    grown radius (N,). The footprints are taken in the image grown by the margin on every
    side, so that the wgpu kernel's cull of what reaches no tile spares a Gaussian whose
    grown footprint reaches the image while its own does not."""
    m = FOOTPRINT_MARGIN
    grown = camera.window(-m, -m, camera.width + 2 * m, camera.height + 2 * m)
    f = footprints(g, grown, backend, antialiased)
    x, y, radius = f.centre[:, 0], f.centre[:, 1], f.radius
    drawn = (
        (radius >= 0)
        & (x + radius >= 0) & (x - radius <= grown.width)
        & (y + radius >= 0) & (y - radius <= grown.height)
    )  # fmt: skip
    return drawn, f.centre - m, radius + m


def touching(
    g: Gaussians, cameras: list[Camera], backend: str, antialiased: bool
) -> torch.Tensor:
    """(N,) bool: the Gaussians that can draw into some camera's image with ``backend``'s
    rasteriser in that mode."""
    keep = torch.zeros(len(g), dtype=torch.bool, device=g.device)
    for camera in cameras:
        keep |= drawn_footprints(g, camera, backend, antialiased)[0]
    return keep


def reach_window(
    camera: Camera, moving: torch.Tensor, dynamic: Gaussians, backend: str, antialiased: bool
) -> ViewWindow:
    """The window of ``camera``'s view that a step must render: the bounding box of the
    pixels the moving region (``moving``: (h, w), > 0 where the view sees it) or the dynamic
    set's footprints with ``backend``'s rasteriser can reach, grown by REACH_SLACK and
    SSIM_MARGIN, within the view."""
    ys, xs = torch.nonzero(moving > 0, as_tuple=True)
    lo = [float(xs.min()), float(ys.min())] if len(xs) else [math.inf, math.inf]
    hi = [float(xs.max()) + 1, float(ys.max()) + 1] if len(xs) else [-math.inf, -math.inf]
    if len(dynamic):
        drawn, centre, radius = drawn_footprints(dynamic, camera, backend, antialiased)
        if bool(drawn.any()):
            c, r = centre[drawn].double(), radius[drawn].double()
            lo = [min(lo[i], float((c[:, i] - r).min())) for i in (0, 1)]
            hi = [max(hi[i], float((c[:, i] + r).max())) for i in (0, 1)]
    size = (camera.width, camera.height)
    if not lo[0] <= hi[0]:  # nothing reaches the view: the smallest window SSIM allows
        side = 2 * SSIM_MARGIN
        return ViewWindow(0, 0, min(size[0], side), min(size[1], side))
    grow = math.ceil(REACH_SLACK * max(size)) + SSIM_MARGIN
    start = [max(0, math.floor(lo[i]) - grow) for i in (0, 1)]
    end = [min(size[i], math.ceil(hi[i]) + grow) for i in (0, 1)]
    return ViewWindow(start[0], start[1], end[0] - start[0], end[1] - start[1])


def previous_in_windows(
    render: Callable[[Gaussians, Camera], RenderOutput],
    windows: list[ViewWindow],
    cameras: list[Camera],
    static_renders: list[RenderOutput],
    static_drawn: Gaussians,
    previous: Gaussians,
) -> torch.Tensor:
    """(V, H, W, 3): the render of the static set and t − 1's dynamic set ``previous`` in
    each view (L_temporal's target), for ``windows`` that hold ``previous``'s footprints:
    each window is rendered from the static Gaussians that can draw into it
    (``static_drawn``) and ``previous``, and pasted into the static set's render of its view
    (``static_renders``), which is the whole render outside the window since ``previous``
    draws nothing there."""
    seen = Gaussians.cat([static_drawn, previous])
    out = []
    for window, camera, whole in zip(windows, cameras, static_renders, strict=True):
        image = whole.rgb.clone()
        window.crop(image)[...] = render(seen, window.camera(camera)).rgb
        out.append(image)
    return torch.stack(out)


def outside_sums(
    window: ViewWindow,
    static: RenderOutput,
    target: torch.Tensor,
    weight: torch.Tensor,
    depth: torch.Tensor,
    previous: torch.Tensor | None,
) -> torch.Tensor:
    """OUTSIDE_SUMS of a view outside ``window`` (float32), from the static render: the whole
    view's L1, SSIM and L_temporal sums less the window's own (computed as a step computes
    them, so that the window's constant edge values cancel), and L_geo's covered weight,
    means and centred sums over the pixels outside the window."""
    x, t, w = static.rgb.double(), target.double(), weight.double()
    p = None if previous is None else previous.double()

    def photometric(
        x: torch.Tensor, t: torch.Tensor, w: torch.Tensor, p: torch.Tensor | None
    ) -> list[torch.Tensor]:
        l1 = ((x - t).abs().mean(-1) * w).sum()
        temporal = torch.zeros_like(l1) if p is None else ((x - p).abs().mean(-1) * w).sum()
        return [l1, (ssim_map(x, t, w) * w).sum(), temporal]

    whole = photometric(x, t, w, p)
    crop = window.crop
    own = photometric(crop(x), crop(t), crop(w), None if p is None else crop(p))
    rest = window.outside(*weight.shape).to(w.device)
    covered = w * (static.alpha.double() > 0.5) * rest
    c = covered.sum()
    a, b = static.depth.double(), depth.double()
    mean_a = (covered * a).sum() / c if c > 0 else torch.zeros((), dtype=torch.float64)
    mean_b = (covered * b).sum() / c if c > 0 else torch.zeros((), dtype=torch.float64)
    da, db = a - mean_a, b - mean_b
    geo = [c, mean_a, mean_b, (covered * da * da).sum(), (covered * db * db).sum(),
           (covered * da * db).sum()]  # fmt: skip
    sums = [wh - ow for wh, ow in zip(whole, own, strict=True)] + geo
    assert len(sums) == len(OUTSIDE_SUMS)
    return torch.stack([s.to(torch.float64) for s in sums]).to(torch.float32)


def windowed(
    views: TrainViews, windows: list[ViewWindow], static: list[RenderOutput]
) -> TrainViews:
    """``views`` (whole views) as their ``windows``, with the whole views' normalisers and
    the sums outside each window (``outside_sums`` on the static set's renders)."""
    outside, sums = [], []
    for i, window in enumerate(windows):
        previous = None if views.previous is None else views.previous[i]
        outside.append(
            outside_sums(
                window, static[i], views.targets[i], views.weights[i], views.depth[i], previous
            )
        )
        sums.append(views.weight_sum(i))
    device = views.weights[0].device
    return TrainViews(
        cameras=[w.camera(c) for w, c in zip(windows, views.cameras, strict=True)],
        targets=[w.crop(views.targets[i]) for i, w in enumerate(windows)],
        weights=[w.crop(views.weights[i]) for i, w in enumerate(windows)],
        depth=[w.crop(views.depth[i]) for i, w in enumerate(windows)],
        previous=(
            None
            if views.previous is None
            else [w.crop(views.previous[i]) for i, w in enumerate(windows)]
        ),
        weight_sums=torch.stack(sums).to(device),
        outside=torch.stack(outside).to(device),
        times=views.times,
    )
