"""Pure-torch reference rasteriser: the same maths as the wgpu one, small and readable.

Dense per pixel over the Gaussians that pass culling, in pixel chunks to bound memory,
and differentiable by autograd; it exists to check ``backend="wgpu"`` (values and
gradients), not for speed. The rules (docs/rasterizer.md) are shared with the WGSL
kernels (``crates/splat-core/src/raster/**/*.wgsl``):

- EWA projection with the Jacobian's x/z, y/z clamped to 1.3·tan(half fov) (the view's,
  ``Camera.half_fov_tan``: a window of a view keeps it), then a screen-space filter F I:
  classic, 3DGS's F = 0.3 px² at full opacity; antialiased, Mip-Splatting's F = 0.1 px²
  with the opacity · sqrt(det Σ / det(Σ + F I));
- culled: any non-finite parameter, camera z < 0.01, det(Σ + F I) <= 0, opacity
  < 1/255, a centre or footprint radius that is not finite; zero quaternions (|q|² <
  1e-12) become the identity; log-scales are clamped to [-12, 8];
- footprint radius: ceil(3·sqrt(λmax)), λmax = m + sqrt(max(0.1, m² − det)) of Σ + F I
  (m its mean eigenvalue): beyond it power < −4.5, so a Gaussian changes no pixel there
  (``pano4d.renderer.footprints`` reports it; this blending, dense, needs no bound);
- colour: SH (degree 0–3) for the direction mean − camera centre, + 0.5, clamped at 0;
- blending front to back in (z, index) order: alpha = min(0.999, o·exp(power)); skip
  power > 0, power < −4.5 or alpha < 1/255; stop before T would drop below 1e-4.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from pano4d.camera import Camera
from pano4d.gaussians import SH_C0, Gaussians

NEAR_PLANE = 0.01
LOW_PASS = 0.3  # the classic mode's screen-space filter, px² (3DGS's dilation)
MIP_FILTER = 0.1  # the antialiased mode's, px² (Mip-Splatting's 2D filter)
MIN_LOG_SCALE = -12.0
MAX_LOG_SCALE = 8.0
QUAT_MIN_NORM2 = 1e-12
JACOBIAN_CLAMP = 1.3
ALPHA_MAX = 0.999
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4
POWER_MIN = -4.5

SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
         -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def sh_basis(dirs: torch.Tensor, num_coeffs: int) -> torch.Tensor:
    """The 3DGS real SH basis (..., num_coeffs) for unit directions (..., 3)."""
    x, y, z = dirs.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    basis = [
        torch.full_like(x, SH_C0),
        -SH_C1 * y, SH_C1 * z, -SH_C1 * x,
        SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * zz - xx - yy), SH_C2[3] * x * z,
        SH_C2[4] * (xx - yy),
        SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z, SH_C3[2] * y * (4 * zz - xx - yy),
        SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy),
        SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3 * yy),
    ]
    return torch.stack(basis[:num_coeffs], dim=-1)


def quat_to_rotation(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (N, 3, 3) of raw quaternions (N, 4) (w, x, y, z)."""
    n2 = (q * q).sum(-1, keepdim=True)
    small = n2 < QUAT_MIN_NORM2
    unit = q / torch.sqrt(torch.where(small, torch.ones_like(n2), n2))
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=q.dtype, device=q.device)
    w, x, y, z = torch.where(small, identity, unit).unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(-1, 3, 3)


@dataclass
class Projected:
    """The Gaussians that pass culling, in (z, index) order."""

    mean2d: torch.Tensor  # (M, 2) pixels
    conic: torch.Tensor  # (M, 3) a, b, c of the inverse 2D covariance
    opacity: torch.Tensor  # (M,)
    depth: torch.Tensor  # (M,) camera z
    rgb: torch.Tensor  # (M, 3)
    radius: torch.Tensor  # (M,) footprint radius in pixels (module docstring), no gradient
    index: torch.Tensor  # (M,) int64: each one's row in the Gaussians


def covariance_factor(log_scales: torch.Tensor, quats: torch.Tensor) -> torch.Tensor:
    """M (N, 3, 3) with the world covariance R S² Rᵀ = M Mᵀ, M = R S: log-scales clamped
    to [MIN_LOG_SCALE, MAX_LOG_SCALE], raw quaternions turned as ``quat_to_rotation`` does."""
    scales = torch.exp(torch.clamp(log_scales, MIN_LOG_SCALE, MAX_LOG_SCALE))
    return quat_to_rotation(quats) * scales[:, None, :]


def ewa_covariance(
    t: torch.Tensor, rz: torch.Tensor, log_scales: torch.Tensor, quats: torch.Tensor,
    camera: Camera,
) -> torch.Tensor:
    """The 2D covariance (N, 2, 2) of Gaussians at camera-space means ``t`` (N, 3) with
    1/z ``rz`` (N,), before the low-pass: J W M Mᵀ Wᵀ Jᵀ with the Jacobian's x/z, y/z
    clamped (module docstring), in ``t``'s dtype."""
    W = camera.R.to(t)
    tan_x, tan_y = camera.half_fov_tan
    lim_x = JACOBIAN_CLAMP * tan_x
    lim_y = JACOBIAN_CLAMP * tan_y
    u = torch.clamp(t[:, 0] * rz, -lim_x, lim_x)
    v = torch.clamp(t[:, 1] * rz, -lim_y, lim_y)
    zero = torch.zeros_like(rz)
    J = torch.stack([
        camera.fx * rz, zero, -camera.fx * u * rz,
        zero, camera.fy * rz, -camera.fy * v * rz,
    ], dim=-1).reshape(-1, 2, 3)
    T = J @ W @ covariance_factor(log_scales, quats)
    return T @ T.transpose(1, 2)


def screen_filter(antialiased: bool) -> float:
    """The variance (px²) the mode adds to every 2D covariance."""
    return MIP_FILTER if antialiased else LOW_PASS


def antialiasing_factor(det: torch.Tensor, det_filtered: torch.Tensor) -> torch.Tensor:
    """The opacity factor sqrt(det Σ / det(Σ + F·I)) that keeps a filtered Gaussian's
    integral, from those two determinants of 2D covariances Σ in pixels²: 0 where either is
    not positive and finite (a footprint with no area, which the mode does not draw)."""
    usable = (det > 0) & (det_filtered > 0) & torch.isfinite(det) & torch.isfinite(det_filtered)
    # Both masked before the division, so that no NaN/Inf enters the autograd graph.
    ratio = torch.where(usable, det, torch.ones_like(det)) / torch.where(
        usable, det_filtered, torch.ones_like(det_filtered)
    )
    return torch.where(usable, torch.sqrt(ratio), torch.zeros_like(ratio))


def project(g: Gaussians, camera: Camera, antialiased: bool, dtype: torch.dtype) -> Projected:
    """EWA projection, SH colour and culling (module docstring) in ``dtype``."""
    params = [t.to(dtype) for t in (g.means, g.log_scales, g.quats, g.opacity_logits, g.sh)]
    finite = torch.stack(
        [torch.isfinite(t.reshape(len(g), -1)).all(-1) for t in params], dim=-1
    ).all(-1)
    # Zero the culled rows first so that no NaN/Inf enters the autograd graph.
    means, log_scales, quats, logits, sh = (
        torch.where(finite.reshape(-1, *[1] * (t.ndim - 1)), t, torch.zeros_like(t))
        for t in params
    )
    device = means.device
    W = camera.R.to(device=device, dtype=dtype)
    t = means @ W.T + camera.t.to(device=device, dtype=dtype)
    z = t[:, 2]
    visible = finite & (z >= NEAR_PLANE)
    rz = 1.0 / torch.where(visible, z, torch.ones_like(z))
    cov = ewa_covariance(t, rz, log_scales, quats, camera)
    a0, b0, c0 = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    det0 = a0 * c0 - b0 * b0
    filter_px2 = screen_filter(antialiased)
    a1, c1 = a0 + filter_px2, c0 + filter_px2
    det1 = a1 * c1 - b0 * b0
    visible = visible & (det1 > 0) & torch.isfinite(det1)
    det1 = torch.where(visible, det1, torch.ones_like(det1))
    opacity = torch.sigmoid(logits)
    if antialiased:
        factor = antialiasing_factor(det0, det1)
        opacity = opacity * torch.where(visible, factor, torch.zeros_like(factor))
    visible = visible & (opacity >= ALPHA_MIN)

    offset = means - camera.position.to(device=device, dtype=dtype)
    dist = torch.linalg.norm(offset, dim=-1, keepdim=True)
    dirs = offset / torch.where(visible[:, None], dist, torch.ones_like(dist))
    basis = sh_basis(dirs, sh.shape[1])
    rgb = torch.clamp((basis[:, :, None] * sh).sum(1) + 0.5, min=0.0)

    mean2d = torch.stack(
        [camera.fx * t[:, 0] * rz + camera.cx, camera.fy * t[:, 1] * rz + camera.cy], dim=-1
    )
    conic = torch.stack([c1 / det1, -b0 / det1, a1 / det1], dim=-1)
    mid = 0.5 * (a1 + c1).detach()
    radius = torch.ceil(3.0 * torch.sqrt(mid + torch.sqrt(
        torch.clamp(mid * mid - det1.detach(), min=0.1))))  # fmt: skip
    visible = visible & torch.isfinite(radius) & torch.isfinite(mean2d.detach()).all(-1)
    index = torch.nonzero(visible).squeeze(1)
    # Front to back by z; the stable sort keeps index order among equal depths.
    index = index[torch.sort(z[index].detach(), stable=True).indices]
    return Projected(
        mean2d[index], conic[index], opacity[index], z[index], rgb[index], radius[index], index
    )


def blend(
    p: Projected, camera: Camera, background: torch.Tensor, chunk_elements: int = 1 << 22
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Front-to-back blending of every pixel over all projected Gaussians.

    Returns rgb (H, W, 3) including the background, alpha (H, W) = 1 − T and the
    accumulated depth (H, W) = Σ z·α·T.
    """
    dtype, device = p.mean2d.dtype, p.mean2d.device
    centres = camera.pixel_grid(dtype).to(device).reshape(-1, 2)
    m = p.mean2d.shape[0]
    chunk = max(1, chunk_elements // max(m, 1))
    colour_depth = torch.cat([p.rgb, p.depth[:, None]], dim=-1)
    outputs = []
    for start in range(0, centres.shape[0], chunk):
        d = p.mean2d[None] - centres[start:start + chunk, None]
        dx, dy = d[..., 0], d[..., 1]
        a, b, c = p.conic.unbind(-1)
        power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
        alpha = torch.clamp(p.opacity * torch.exp(torch.clamp(power, max=0.0)), max=ALPHA_MAX)
        used = (power <= 0) & (power >= POWER_MIN) & (alpha >= ALPHA_MIN)
        alpha = torch.where(used, alpha, torch.zeros_like(alpha))
        # Early termination: drop the first Gaussian that takes T below T_MIN and all after.
        t_after = torch.cumprod(1 - alpha, dim=1)
        alpha = torch.where(t_after.detach() >= T_MIN, alpha, torch.zeros_like(alpha))
        t_after = torch.cumprod(1 - alpha, dim=1)
        t_before = torch.cat([torch.ones_like(t_after[:, :1]), t_after[:, :-1]], dim=1)
        weights = alpha * t_before
        acc = weights @ colour_depth
        t_final = t_after[:, -1] if m > 0 else torch.ones(d.shape[0], dtype=dtype, device=device)
        outputs.append(torch.cat([acc, t_final[:, None]], dim=-1))
    out = torch.cat(outputs).reshape(camera.height, camera.width, 5)
    t_final = out[..., 4]
    rgb = out[..., :3] + t_final[..., None] * background.to(device=device, dtype=dtype)
    return rgb, 1 - t_final, out[..., 3]


def render_torch(
    g: Gaussians,
    camera: Camera,
    background: torch.Tensor,
    antialiased: bool = False,
    dtype: torch.dtype = torch.float32,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """rgb (H, W, 3), alpha (H, W), accumulated depth (H, W) in ``dtype``."""
    return blend(project(g, camera, antialiased, dtype), camera, background)
