"""Resampling between equirect images, icosphere points and perspective views.

Every resampler is a precomputed sparse linear map (index/weight table): build it once per
layout, move it to the device, and apply it to any batch of signals, float32 or float16.
Its adjoint (weighted splatting) is what the panoramic denoiser's fusion needs:
``fuse = adjoint(values) / adjoint(ones)``.

Layouts: images are channel-first, (..., H, W); sphere signals are (..., N).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from pano4d.camera import Camera
from pano4d.sphere import Icosphere, dir_to_equirect, equirect_directions


@dataclass
class Resampler:
    """out[..., m] = Σ_k weight[m, k] · src[..., index[m, k]] over a flattened source.

    ``valid[m]`` is False where the target has no support in the source (outside a view);
    those targets read 0 and are skipped by the adjoint.
    """

    index: torch.Tensor  # (M, k) int64
    weight: torch.Tensor  # (M, k) float32
    valid: torch.Tensor  # (M,) bool
    source_shape: tuple[int, ...]
    target_shape: tuple[int, ...]

    @property
    def source_size(self) -> int:
        return int(torch.tensor(self.source_shape).prod())

    def to(self, device: torch.device | str) -> Resampler:
        return Resampler(
            self.index.to(device),
            self.weight.to(device),
            self.valid.to(device),
            self.source_shape,
            self.target_shape,
        )

    def apply(self, src: torch.Tensor) -> torch.Tensor:
        """Sample ``src`` (..., *source_shape) → (..., *target_shape), in src's dtype.

        Accumulates in float32 so float16 inputs lose nothing beyond their own rounding.
        """
        nd = len(self.source_shape)
        if tuple(src.shape[src.ndim - nd :]) != self.source_shape:
            raise ValueError(
                f"resampler expects trailing shape {self.source_shape}, got {tuple(src.shape)}"
            )
        lead = src.shape[: src.ndim - nd]
        flat = src.reshape(*lead, -1)
        gathered = flat[..., self.index].to(torch.float32)
        out = (gathered * self.weight).sum(dim=-1)
        return out.to(src.dtype).reshape(*lead, *self.target_shape)

    def adjoint(self, values: torch.Tensor) -> torch.Tensor:
        """Transpose of ``apply``: splat (..., *target_shape) back onto (..., *source_shape)."""
        nt = len(self.target_shape)
        lead = values.shape[: values.ndim - nt]
        flat = values.reshape(-1, values.shape[values.ndim - nt :].numel()).to(torch.float32)
        contrib = flat[:, :, None] * self.weight  # (B, M, k)
        out = torch.zeros(flat.shape[0], self.source_size, device=values.device)
        out.index_add_(1, self.index.reshape(-1), contrib.reshape(flat.shape[0], -1))
        return out.to(values.dtype).reshape(*lead, *self.source_shape)

    def coverage_weight(self) -> torch.Tensor:
        """``adjoint`` of ones: how much target weight lands on each source sample."""
        ones = torch.ones(self.target_shape, device=self.weight.device)
        return self.adjoint(ones)


# --- builders -----------------------------------------------------------------------------
def equirect_sampler(dirs: torch.Tensor, width: int, height: int) -> Resampler:
    """Bilinear lookup of directions (..., 3) in a width×height equirect image.

    Columns wrap around the seam; a row beyond a pole continues on the far side of the
    pole (the same row, half a turn round), which is what the sphere does there.
    """
    target_shape = tuple(dirs.shape[:-1])
    u, v = dir_to_equirect(dirs.reshape(-1, 3).to(torch.float64), width, height)
    x, y = u - 0.5, v - 0.5
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = x - x0, y - y0
    x0, y0 = x0.long(), y0.long()

    def tap(col: torch.Tensor, row: torch.Tensor) -> torch.Tensor:
        over_top, under_bottom = row < 0, row >= height
        col = torch.where(over_top | under_bottom, col + width // 2, col)
        row = torch.where(over_top, -1 - row, row)
        row = torch.where(under_bottom, 2 * height - 1 - row, row)
        return row.clamp(0, height - 1) * width + torch.remainder(col, width)

    index = torch.stack([tap(x0, y0), tap(x0 + 1, y0), tap(x0, y0 + 1), tap(x0 + 1, y0 + 1)], -1)
    weight = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], -1)
    valid = torch.ones(index.shape[0], dtype=torch.bool)
    return Resampler(index, weight.float(), valid, (height, width), target_shape)


def sphere_sampler(dirs: torch.Tensor, ico: Icosphere) -> Resampler:
    """Barycentric lookup of directions (..., 3) among icosphere points.

    The direction is centrally projected onto the icosahedron face it crosses (the face
    whose centre it is closest to), where the lattice is flat, so the interpolation is
    exact barycentric interpolation between the three lattice points around it.
    """
    target_shape = tuple(dirs.shape[:-1])
    d = dirs.reshape(-1, 3).to(torch.float64)
    f = ico.frequency
    corners = ico.points[ico.lattice[:, [0, f, 0], [0, 0, f]]]  # (20, 3 corners, 3)
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    normal = a + b + c
    normal = normal / torch.linalg.norm(normal, dim=-1, keepdim=True)
    face = torch.argmax(d @ normal.T, dim=-1)

    # Hit point on the face plane, then solve p - a = s (b - a) + t (c - a).
    n, fa, fb, fc = normal[face], a[face], b[face], c[face]
    p = d * ((fa * n).sum(-1) / (d * n).sum(-1))[:, None]
    e1, e2, q = fb - fa, fc - fa, p - fa
    d11, d12, d22 = (e1 * e1).sum(-1), (e1 * e2).sum(-1), (e2 * e2).sum(-1)
    q1, q2 = (q * e1).sum(-1), (q * e2).sum(-1)
    det = d11 * d22 - d12 * d12
    s = (d22 * q1 - d12 * q2) / det
    t = (d11 * q2 - d12 * q1) / det

    x, y = (s * f).clamp(0, f), (t * f).clamp(0, f)
    i0 = torch.floor(x).long().clamp(0, f - 1)
    j0 = torch.minimum(torch.floor(y).long().clamp(min=0), f - 1 - i0)
    fx, fy = x - i0, y - j0
    upper = (fx + fy > 1) & (i0 + j0 + 2 <= f)
    lat = ico.lattice
    p00, p10, p01 = lat[face, i0, j0], lat[face, i0 + 1, j0], lat[face, i0, j0 + 1]
    p11 = lat[face, (i0 + 1).clamp(max=f), (j0 + 1).clamp(max=f)]
    index = torch.where(
        upper[:, None], torch.stack([p11, p01, p10], -1), torch.stack([p00, p10, p01], -1)
    )
    weight = torch.where(
        upper[:, None],
        torch.stack([fx + fy - 1, 1 - fx, 1 - fy], -1),
        torch.stack([1 - fx - fy, fx, fy], -1),
    ).clamp(min=0)
    weight = weight / weight.sum(-1, keepdim=True)
    valid = torch.ones(index.shape[0], dtype=torch.bool)
    return Resampler(index, weight.float(), valid, (len(ico),), target_shape)


def perspective_sampler(dirs: torch.Tensor, camera: Camera) -> Resampler:
    """Bilinear lookup of world directions (..., 3), seen from the camera's centre, in its image.

    Directions behind the camera or outside the image are not valid. Samples between the
    outermost pixel centre and the image border clamp to the border pixel.
    """
    target_shape = tuple(dirs.shape[:-1])
    d = dirs.reshape(-1, 3).to(torch.float64)
    uv, z = camera.project(camera.position + d)
    w, h = camera.width, camera.height
    valid = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= w) & (uv[:, 1] >= 0) & (uv[:, 1] <= h)
    uv = torch.where(valid[:, None], uv, torch.zeros_like(uv))
    x = (uv[:, 0] - 0.5).clamp(0, w - 1)
    y = (uv[:, 1] - 0.5).clamp(0, h - 1)
    x0 = torch.floor(x).long().clamp(max=max(w - 2, 0))
    y0 = torch.floor(y).long().clamp(max=max(h - 2, 0))
    fx, fy = x - x0, y - y0
    x1, y1 = (x0 + 1).clamp(max=w - 1), (y0 + 1).clamp(max=h - 1)
    index = torch.stack([y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1], -1)
    weight = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], -1)
    weight = weight * valid[:, None]
    return Resampler(index, weight.float(), valid, (h, w), target_shape)


# --- conveniences for the common pairs ----------------------------------------------------
def equirect_to_perspective(image: torch.Tensor, camera: Camera) -> torch.Tensor:
    """Equirect (..., H, W) → the camera's view (..., h, w)."""
    h, w = image.shape[-2:]
    return (
        equirect_sampler(camera.world_directions(torch.float64), w, h).to(image.device).apply(image)
    )


def perspective_to_equirect(
    image: torch.Tensor, camera: Camera, width: int, height: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """A view (..., h, w) → equirect (..., H, W) and the bool mask (H, W) of pixels it covers."""
    s = perspective_sampler(equirect_directions(width, height, torch.float64), camera)
    s = s.to(image.device)
    return s.apply(image), s.valid.reshape(height, width)


def equirect_to_sphere(image: torch.Tensor, ico: Icosphere) -> torch.Tensor:
    """Equirect (..., H, W) → icosphere samples (..., N)."""
    h, w = image.shape[-2:]
    return equirect_sampler(ico.points, w, h).to(image.device).apply(image)


def sphere_to_equirect(
    values: torch.Tensor, ico: Icosphere, width: int, height: int
) -> torch.Tensor:
    """Icosphere samples (..., N) → equirect (..., H, W)."""
    s = sphere_sampler(equirect_directions(width, height, torch.float64), ico)
    return s.to(values.device).apply(values)
