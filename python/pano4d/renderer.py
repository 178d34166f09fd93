"""``render``: Gaussians + camera → rgb, alpha, expected depth (docs/design.md, public API,
exported as ``pano4d.render``; this module is ``pano4d.renderer`` so the two names differ),
and ``footprints``: where each Gaussian can draw, as the rasteriser bounds it.

``backend="wgpu"`` runs the Rust compute rasteriser (``pano4d._core``) as a
``torch.autograd.Function``: inputs go to the host as float32, the outputs come back on
the input's device as float32, and the backward pass returns gradients for means,
log-scales, quaternions, opacity logits and SH. One process-wide renderer (device,
pipelines, buffers) is created on first use. ``backend="torch"`` is the pure-torch
reference (``pano4d.raster_torch``); both follow docs/rasterizer.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from pano4d.camera import Camera
from pano4d.extension import core, flat, gaussian_arrays, view
from pano4d.gaussians import Gaussians
from pano4d.raster_torch import project, render_torch

BACKENDS = ("wgpu", "torch")
# Expected depth is D / alpha where alpha exceeds this, else 0.
MIN_ALPHA_FOR_DEPTH = 1e-6


@dataclass
class RenderOutput:
    rgb: torch.Tensor  # (H, W, 3)
    alpha: torch.Tensor  # (H, W)
    depth: torch.Tensor  # (H, W) expected z-depth, 0 where nothing was drawn


@dataclass
class Footprints:
    """Each Gaussian's footprint in a camera's image, as the rasteriser computes it for its
    blending: it changes no pixel whose centre lies farther than ``radius`` from ``centre``
    (3σ of the projected covariance with the 0.3 px² low-pass, rounded up to whole pixels;
    docs/rasterizer.md)."""

    centre: torch.Tensor  # (N, 2) pixels; 0 where culled
    radius: torch.Tensor  # (N,) pixels; −1 where culled: it draws nothing in the image


def adapter_info() -> dict[str, str]:
    """The GPU adapter the wgpu backend uses: name, backend, device_type, driver."""
    return dict(core.adapter_info())


class _WgpuRasterize(torch.autograd.Function):
    """(H, W, 5): r, g, b, alpha, Σ z·α·T, differentiable w.r.t. the five tensors."""

    @staticmethod
    def forward(  # type: ignore[override]
        ctx: Any,
        camera: Camera,
        background: tuple[float, float, float],
        antialiased: bool,
        means: torch.Tensor,
        log_scales: torch.Tensor,
        quats: torch.Tensor,
        opacity_logits: torch.Tensor,
        sh: torch.Tensor,
    ) -> torch.Tensor:
        tensors = (means, log_scales, quats, opacity_logits, sh)
        out = core.render_forward(
            gaussian_arrays(Gaussians(*tensors)),
            view(camera),
            background=background,
            antialiased=antialiased,
        )
        ctx.camera, ctx.background, ctx.antialiased = camera, background, antialiased
        ctx.save_for_backward(*tensors)
        pixels = torch.from_numpy(out.pixels).reshape(camera.height, camera.width, 5)
        return pixels.to(means.device)

    @staticmethod
    def backward(ctx: Any, v_out: torch.Tensor) -> tuple[torch.Tensor | None, ...]:  # type: ignore[override]
        tensors = ctx.saved_tensors
        grads = core.render_backward(
            gaussian_arrays(Gaussians(*tensors)),
            view(ctx.camera),
            background=ctx.background,
            antialiased=ctx.antialiased,
            v_pixels=flat(v_out),
        )
        by_name = (grads.means, grads.log_scales, grads.quats, grads.opacity_logits, grads.sh)
        out = [
            torch.from_numpy(g).to(device=t.device, dtype=t.dtype)
            for g, t in zip(by_name, tensors, strict=True)
        ]
        return (None, None, None, *out)


def render(
    gaussians: Gaussians,
    camera: Camera,
    background: torch.Tensor | None = None,
    backend: str = "wgpu",
    antialiased: bool = False,
) -> RenderOutput:
    """Render ``gaussians`` seen by ``camera``.

    ``background`` is an RGB triple (default black) added as ``T · background``.
    Returns float32 tensors on the Gaussians' device (the torch backend keeps their
    dtype when it is float64, for gradient checks).
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    device = gaussians.device
    bg = torch.zeros(3) if background is None else torch.as_tensor(background).reshape(-1)
    if bg.numel() != 3 or not torch.isfinite(bg).all():
        raise ValueError(f"background must be a finite RGB triple, got {bg.tolist()}")
    if backend == "torch":
        dtype = torch.float64 if gaussians.means.dtype == torch.float64 else torch.float32
        rgb, alpha, accum_depth = render_torch(gaussians, camera, bg, antialiased, dtype)
    else:
        background_rgb = tuple(float(v) for v in bg)
        out = _WgpuRasterize.apply(
            camera, background_rgb, antialiased, *gaussians.tensors().values()
        )
        rgb, alpha, accum_depth = out[..., :3], out[..., 3], out[..., 4]
    drawn = alpha > MIN_ALPHA_FOR_DEPTH
    depth = torch.where(
        drawn, accum_depth / torch.where(drawn, alpha, torch.ones_like(alpha)),
        torch.zeros_like(alpha),
    )
    return RenderOutput(rgb.to(device), alpha.to(device), depth.to(device))


def footprints(
    gaussians: Gaussians, camera: Camera, backend: str = "wgpu", antialiased: bool = False
) -> Footprints:
    """The ``Footprints`` of ``gaussians`` in ``camera``, from the projection alone of the
    rasteriser ``render`` uses with the same ``backend`` and ``antialiased`` (no blending).

    Culled, radius −1: what that projection culls (docs/rasterizer.md); the wgpu kernel
    also culls a Gaussian whose footprint reaches no 16-pixel tile of the image, which the
    dense torch reference has no need to. Float32 on the Gaussians' device (the torch
    backend keeps float64, as ``render``).
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    device = gaussians.device
    if backend == "torch":
        dtype = torch.float64 if gaussians.means.dtype == torch.float64 else torch.float32
        with torch.no_grad():
            p = project(gaussians, camera, antialiased, dtype)
        centre = torch.zeros(len(gaussians), 2, dtype=dtype, device=p.mean2d.device)
        radius = torch.full((len(gaussians),), -1.0, dtype=dtype, device=p.mean2d.device)
        centre[p.index], radius[p.index] = p.mean2d, p.radius
        return Footprints(centre.to(device), radius.to(device))
    out = core.footprints(gaussian_arrays(gaussians), view(camera), antialiased=antialiased)
    xyr = torch.from_numpy(out).reshape(-1, 3)
    # The kernel writes radius 0 for a culled Gaussian; a drawn one's is at least 3.
    radius = torch.where(xyr[:, 2] > 0, xyr[:, 2], torch.full_like(xyr[:, 2], -1.0))
    return Footprints(xyr[:, :2].to(device), radius.to(device))
