"""Sphere geometry shared by every stage (docs/design.md, "Conventions").

Equirect W×H (W = 2H), continuous pixel coordinates with pixel centres at +0.5:
    φ = 2π(u/W − 0.5),  θ = π(0.5 − v/H),  d = (cos θ cos φ, −cos θ sin φ, sin θ).
Columns wrap (u = W is u = 0); v = 0 is the zenith, v = H the nadir.

Also here: the perspective view layout (icosahedron face centres), near-uniform icosphere
points and a coverage report. Resampling between the three representations lives in
``pano4d.resample``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import torch

from pano4d.camera import Camera

_GOLDEN = (1.0 + math.sqrt(5.0)) / 2.0

# Icosahedron vertices and faces: the 20 face centres are the default view layout.
_ICOSAHEDRON_VERTICES = (
    (-1.0, _GOLDEN, 0.0), (1.0, _GOLDEN, 0.0), (-1.0, -_GOLDEN, 0.0), (1.0, -_GOLDEN, 0.0),
    (0.0, -1.0, _GOLDEN), (0.0, 1.0, _GOLDEN), (0.0, -1.0, -_GOLDEN), (0.0, 1.0, -_GOLDEN),
    (_GOLDEN, 0.0, -1.0), (_GOLDEN, 0.0, 1.0), (-_GOLDEN, 0.0, -1.0), (-_GOLDEN, 0.0, 1.0),
)  # fmt: skip
ICOSAHEDRON_FACES = (
    (0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11),
    (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6), (7, 1, 8),
    (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9),
    (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1),
)  # fmt: skip


def icosahedron_vertices(dtype: torch.dtype = torch.float64) -> torch.Tensor:
    v = torch.tensor(_ICOSAHEDRON_VERTICES, dtype=torch.float64)
    return (v / torch.linalg.norm(v, dim=-1, keepdim=True)).to(dtype)


# --- equirect <-> direction -------------------------------------------------------------
def equirect_to_dir(
    u: torch.Tensor | float, v: torch.Tensor | float, width: int, height: int
) -> torch.Tensor:
    """Unit directions (..., 3) for continuous equirect pixel coordinates (u, v)."""
    u = torch.as_tensor(u)
    v = torch.as_tensor(v)
    if not u.is_floating_point():
        u = u.to(torch.float64)
    if not v.is_floating_point():
        v = v.to(torch.float64)
    phi = 2.0 * math.pi * (u / width - 0.5)
    theta = math.pi * (0.5 - v / height)
    cos_t = torch.cos(theta)
    return torch.stack([cos_t * torch.cos(phi), -cos_t * torch.sin(phi), torch.sin(theta)], -1)


def dir_to_equirect(d: torch.Tensor, width: int, height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Equirect pixel coordinates (u in [0, W), v in [0, H]) of directions (..., 3).

    The directions need not be unit length. atan2 on both angles keeps the poles and the
    seam finite: (0, 0, ±1) maps to u = W/2, v = 0 or H.
    """
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    phi = torch.atan2(-y, x)
    theta = torch.atan2(z, torch.hypot(x, y))
    u = width * (phi / (2.0 * math.pi) + 0.5)
    u = torch.remainder(u, width)
    u = torch.where(u >= width, torch.zeros_like(u), u)  # remainder can round up to W
    v = height * (0.5 - theta / math.pi)
    return u, v


def equirect_directions(
    width: int, height: int, dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu"
) -> torch.Tensor:
    """Unit direction (H, W, 3) of every equirect pixel centre."""
    us = torch.arange(width, dtype=torch.float64, device=device) + 0.5
    vs = torch.arange(height, dtype=torch.float64, device=device) + 0.5
    vv, uu = torch.meshgrid(vs, us, indexing="ij")
    return equirect_to_dir(uu, vv, width, height).to(dtype)


def equirect_pixel_solid_angle(width: int, height: int) -> torch.Tensor:
    """Solid angle (H,) of one pixel in each row: the cos-latitude weight, exactly integrated."""
    edges = math.pi * (0.5 - torch.arange(height + 1, dtype=torch.float64) / height)
    return (2 * math.pi / width) * (torch.sin(edges[:-1]) - torch.sin(edges[1:]))


def check_panorama_size(width: int, height: int) -> None:
    if width != 2 * height:
        raise ValueError(f"an equirect panorama must be 2:1, got {width}x{height}")


# --- perspective view layout ------------------------------------------------------------
def icosahedron_face_centres(dtype: torch.dtype = torch.float64) -> torch.Tensor:
    v = icosahedron_vertices()
    c = v[torch.tensor(ICOSAHEDRON_FACES)].sum(dim=1)
    return (c / torch.linalg.norm(c, dim=-1, keepdim=True)).to(dtype)


def fibonacci_directions(n: int, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """n near-uniform directions on the sphere (Fibonacci lattice)."""
    i = torch.arange(n, dtype=torch.float64)
    z = 1.0 - 2.0 * (i + 0.5) / n
    r = torch.sqrt(1.0 - z * z)
    a = math.pi * (3.0 - math.sqrt(5.0)) * i
    return torch.stack([r * torch.cos(a), r * torch.sin(a), z], dim=-1).to(dtype)


def view_directions(n: int = 20) -> torch.Tensor:
    """Forward directions (n, 3) of the layout: face centres for n = 20, else Fibonacci."""
    if n < 1:
        raise ValueError(f"the view layout needs at least one view, got n={n}")
    return icosahedron_face_centres() if n == 20 else fibonacci_directions(n)


def view_layout(n: int = 20, fov_deg: float = 80.0, size: int = 512) -> list[Camera]:
    """The n square perspective views of the panorama, all at the origin, with no roll."""
    return [Camera.from_fov(fov_deg, size, size, (0.0, 0.0, 0.0), d) for d in view_directions(n)]


def matched_view_size(width: int, fov_deg: float, multiple: int = 16) -> int:
    """Square view side (pixels) whose pixels, averaged over the view, span one pixel of a
    ``width``-wide panorama, rounded to ``multiple``: larger views only resample its pixels."""
    matched = width * fov_deg / 360.0
    return max(multiple, round(matched / multiple) * multiple)


def views_seeing(cameras: list[Camera], dirs: torch.Tensor) -> torch.Tensor:
    """Bool (n_views, ...) : which cameras see each direction (..., 3) inside their image."""
    out = []
    for cam in cameras:
        uv, z = cam.project(dirs.to(torch.float64))
        inside = (
            (z > 0)
            & (uv[..., 0] >= 0)
            & (uv[..., 0] <= cam.width)
            & (uv[..., 1] >= 0)
            & (uv[..., 1] <= cam.height)
        )
        out.append(inside)
    return torch.stack(out)


@dataclass
class Coverage:
    """How a view layout covers the sphere, measured on an equirect grid."""

    overlap: torch.Tensor  # (H, W) int: number of views that see each pixel's direction
    min_views: int
    max_views: int
    uncovered_fraction: float  # solid-angle fraction seen by no view

    def summary(self) -> str:
        return (
            f"every direction seen by >= {self.min_views} view(s), at most {self.max_views}; "
            f"uncovered: {100 * self.uncovered_fraction:.3f}% of the sphere"
        )


def coverage(cameras: list[Camera], width: int = 512, height: int = 256) -> Coverage:
    """Overlap-count map of a view layout on a width×height equirect grid."""
    dirs = equirect_directions(width, height, torch.float64)
    overlap = views_seeing(cameras, dirs).sum(dim=0)
    weight = equirect_pixel_solid_angle(width, height)[:, None].expand(height, width)
    uncovered = float((weight * (overlap == 0)).sum() / weight.sum())
    return Coverage(overlap, int(overlap.min()), int(overlap.max()), uncovered)


# --- icosphere --------------------------------------------------------------------------
@dataclass(frozen=True)
class Icosphere:
    """Geodesic points of frequency f: each icosahedron face carries the triangular lattice
    a + (i/f)(b − a) + (j/f)(c − a), i + j ≤ f, pushed onto the sphere. N = 10 f² + 2.

    ``points`` (N, 3) unit float64; ``lattice`` (20, f+1, f+1) int64 maps (face, i, j) to the
    point index (−1 where i + j > f). Central projection of a direction onto its face plane
    inverts the push onto the sphere, so interpolation inside a lattice triangle is exact
    barycentric interpolation (see ``pano4d.resample``).
    """

    frequency: int
    points: torch.Tensor
    lattice: torch.Tensor

    def __len__(self) -> int:
        return self.points.shape[0]

    @property
    def spacing_rad(self) -> float:
        """Mean angular distance between neighbouring points (triangular lattice)."""
        return icosphere_spacing(self.frequency)


def icosphere_spacing(frequency: int) -> float:
    n = 10 * frequency**2 + 2
    return math.sqrt(4 * math.pi / (n * math.sqrt(3) / 2))


def icosphere_frequency_for_spacing(spacing_rad: float) -> int:
    """Smallest lattice frequency whose mean point spacing is at most ``spacing_rad``."""
    if not spacing_rad > 0:
        raise ValueError(f"spacing must be positive, got {spacing_rad}")
    n = 4 * math.pi / (spacing_rad**2 * math.sqrt(3) / 2)
    f = max(1, math.ceil(math.sqrt(max(n - 2, 0) / 10)))
    while icosphere_spacing(f) > spacing_rad:
        f += 1
    return f


def icosphere_for_equirect(width: int) -> Icosphere:
    """About one point per equirect pixel at the equator of a ``width``-wide panorama."""
    return icosphere(icosphere_frequency_for_spacing(2 * math.pi / width))


@lru_cache(maxsize=8)
def icosphere(frequency: int) -> Icosphere:
    """Near-uniform points from the icosahedron subdivided with lattice frequency f."""
    f = int(frequency)
    if f < 1:
        raise ValueError(f"icosphere frequency must be >= 1, got {frequency}")
    faces = torch.tensor(ICOSAHEDRON_FACES)
    ii, jj = torch.meshgrid(torch.arange(f + 1), torch.arange(f + 1), indexing="ij")
    valid = (ii + jj) <= f
    i, j = ii[valid], jj[valid]
    n_lattice = i.shape[0]

    # A lattice vertex on an edge or corner is shared by several faces. Give each one id by
    # keying it on its integer barycentric weights over the 12 icosahedron vertices, written
    # as up to three (vertex, weight) pairs sorted by vertex (12 = unused slot).
    vertex = faces[:, None, :].expand(20, n_lattice, 3)
    weight = torch.stack([f - i - j, i, j], dim=-1)[None].expand(20, n_lattice, 3)
    vertex = torch.where(weight > 0, vertex, torch.full_like(vertex, 12))
    vertex, order = torch.sort(vertex, dim=-1)
    weight = torch.gather(weight, -1, order)
    code = vertex * (f + 1) + weight
    base = 13 * (f + 1)
    key = (code[..., 0] * base + code[..., 1]) * base + code[..., 2]
    unique_keys, inverse = torch.unique(key.reshape(-1), return_inverse=True)
    lattice = torch.full((20, f + 1, f + 1), -1, dtype=torch.int64)
    lattice[:, i, j] = inverse.view(20, n_lattice)

    # Same sorted weights for every copy of a point, so every copy computes the same bits.
    verts = torch.cat([icosahedron_vertices(), torch.zeros(1, 3, dtype=torch.float64)])
    pos = (weight[..., None].to(torch.float64) * verts[vertex]).sum(dim=-2).reshape(-1, 3)
    pts = torch.empty(unique_keys.shape[0], 3, dtype=torch.float64)
    pts[inverse] = pos
    pts = pts / torch.linalg.norm(pts, dim=-1, keepdim=True)
    return Icosphere(f, pts, lattice)
