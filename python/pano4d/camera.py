"""Perspective pinhole cameras in the OpenCV convention (see docs/design.md, "Conventions").

x right, y down, z forward; world-to-camera ``[R | t]``; intrinsics in pixels with pixel
centres at +0.5, so a camera centred on its image has ``cx = width / 2``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

WORLD_UP = (0.0, 0.0, 1.0)

# OpenCV camera axes (x right, y down, z forward) to OpenGL ones (x right, y up, z back): the
# axes of nerfstudio's transform_matrix and camera_to_world (its own inverse).
CV_TO_GL = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))


def _as_vec3(v: Sequence[float] | torch.Tensor) -> torch.Tensor:
    t = torch.as_tensor(v, dtype=torch.float64).reshape(3)
    if not torch.isfinite(t).all():
        raise ValueError(f"expected a finite 3-vector, got {t.tolist()}")
    return t


def look_rotation(
    forward: Sequence[float] | torch.Tensor, up: Sequence[float] | torch.Tensor = WORLD_UP
) -> torch.Tensor:
    """World-to-camera rotation (3, 3), float64, for a camera looking along ``forward``.

    The image's up is ``up`` projected onto the image plane (no roll). Looking straight
    along ``up`` leaves that undefined; then the image top points the way a head tilted
    back from +x would see it (towards -x looking up, towards +x looking down).
    """
    f = _as_vec3(forward)
    norm = torch.linalg.norm(f)
    if norm < 1e-12:
        raise ValueError("camera forward vector has zero length")
    f = f / norm
    u = _as_vec3(up)
    right = torch.linalg.cross(f, u)
    if torch.linalg.norm(right) < 1e-9 * max(1.0, float(torch.linalg.norm(u))):
        fallback = torch.tensor([-1.0, 0.0, 0.0], dtype=torch.float64)
        if float(torch.dot(f, u)) < 0:
            fallback = -fallback
        right = torch.linalg.cross(f, fallback)
    right = right / torch.linalg.norm(right)
    down = torch.linalg.cross(f, right)
    return torch.stack([right, down, f])


def focal_length(fov_deg: float, width: float) -> float:
    """Pixels per unit of tan: the focal length of a centred pinhole ``width`` pixels across
    ``fov_deg`` degrees."""
    return 0.5 * width / math.tan(math.radians(fov_deg) / 2.0)


@dataclass
class Camera:
    """A pinhole camera: ``K`` (3, 3) and ``world_to_cam`` (4, 4), both float64 tensors."""

    K: torch.Tensor
    world_to_cam: torch.Tensor
    width: int
    height: int
    # tan of the half field of view of the view this camera is a window of (``window``);
    # None for a whole view. The EWA Jacobian's clamp reads it (``half_fov_tan``).
    view_half_fov_tan: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        self.K = torch.as_tensor(self.K, dtype=torch.float64).reshape(3, 3)
        w2c = torch.as_tensor(self.world_to_cam, dtype=torch.float64)
        if w2c.shape == (3, 4):
            w2c = torch.cat([w2c, torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=torch.float64)])
        if w2c.shape != (4, 4):
            raise ValueError(f"world_to_cam must be 3x4 or 4x4, got {tuple(w2c.shape)}")
        self.world_to_cam = w2c
        self.width, self.height = int(self.width), int(self.height)
        if self.width < 1 or self.height < 1:
            raise ValueError(f"camera size must be positive, got {self.width}x{self.height}")

    @classmethod
    def from_fov(
        cls,
        fov_deg: float,
        width: int,
        height: int,
        position: Sequence[float] | torch.Tensor = (0.0, 0.0, 0.0),
        forward: Sequence[float] | torch.Tensor = (1.0, 0.0, 0.0),
        up: Sequence[float] | torch.Tensor = WORLD_UP,
    ) -> Camera:
        """A camera with horizontal field of view ``fov_deg``, square pixels, centred."""
        if not 0.0 < fov_deg < 180.0:
            raise ValueError(f"fov_deg must be in (0, 180), got {fov_deg}")
        fx = focal_length(fov_deg, width)
        K = torch.tensor(
            [[fx, 0.0, width / 2.0], [0.0, fx, height / 2.0], [0.0, 0.0, 1.0]],
            dtype=torch.float64,
        )
        R = look_rotation(forward, up)
        t = -R @ _as_vec3(position)
        w2c = torch.eye(4, dtype=torch.float64)
        w2c[:3, :3], w2c[:3, 3] = R, t
        return cls(K, w2c, width, height)

    # --- derived quantities -------------------------------------------------------------
    @property
    def R(self) -> torch.Tensor:
        return self.world_to_cam[:3, :3]

    @property
    def t(self) -> torch.Tensor:
        return self.world_to_cam[:3, 3]

    @property
    def position(self) -> torch.Tensor:
        """Camera centre in world coordinates (float64, (3,))."""
        return -self.R.T @ self.t

    @property
    def forward(self) -> torch.Tensor:
        return self.R[2]

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def half_fov_tan(self) -> tuple[float, float]:
        """tan of the half field of view (x, y) of the whole view: a window keeps its
        view's, so that it renders the view's pixels, not those of a narrower camera."""
        if self.view_half_fov_tan is not None:
            return self.view_half_fov_tan
        return (0.5 * self.width / self.fx, 0.5 * self.height / self.fy)

    def window(self, x0: int, y0: int, width: int, height: int) -> Camera:
        """The ``width``×``height`` pixels of this camera's image from pixel (``x0``, ``y0``)
        on, as a camera of their own: the same pixels (the principal point moves)."""
        K = self.K.clone()
        K[0, 2] -= x0
        K[1, 2] -= y0
        return Camera(K, self.world_to_cam, width, height, self.half_fov_tan)

    def fov_deg(self) -> tuple[float, float]:
        """Horizontal and vertical field of view in degrees."""
        return (
            math.degrees(2 * math.atan(self.width / (2 * self.fx))),
            math.degrees(2 * math.atan(self.height / (2 * self.fy))),
        )

    # --- projection ---------------------------------------------------------------------
    def world_to_camera(self, points: torch.Tensor) -> torch.Tensor:
        """Points (..., 3) in world space to camera space, in the points' dtype."""
        R = self.R.to(points)
        return points @ R.T + self.t.to(points)

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World points (..., 3) to pixel coordinates (..., 2) and z-depth (...).

        Points at or behind the camera plane get non-finite pixel coordinates; callers
        mask them with ``z > 0``.
        """
        pc = self.world_to_camera(points)
        z = pc[..., 2]
        x = self.fx * pc[..., 0] / z + self.cx
        y = self.fy * pc[..., 1] / z + self.cy
        return torch.stack([x, y], dim=-1), z

    def pixel_rays(self, uv: torch.Tensor) -> torch.Tensor:
        """Camera-space ray directions (..., 3) with z = 1 for pixel coordinates (..., 2)."""
        x = (uv[..., 0] - self.cx) / self.fx
        y = (uv[..., 1] - self.cy) / self.fy
        return torch.stack([x, y, torch.ones_like(x)], dim=-1)

    def unproject(self, uv: torch.Tensor, depth: torch.Tensor, kind: str = "z") -> torch.Tensor:
        """Pixel coordinates (..., 2) and depth (...) to world points (..., 3).

        ``kind="z"``: depth is distance along the camera's z; ``kind="ray"``: ray length.
        """
        rays = self.pixel_rays(uv)
        if kind == "ray":
            rays = rays / torch.linalg.norm(rays, dim=-1, keepdim=True)
        elif kind != "z":
            raise ValueError(f"kind must be 'z' or 'ray', got {kind!r}")
        pc = rays * depth[..., None]
        R = self.R.to(pc)
        return (pc - self.t.to(pc)) @ R

    def pixel_grid(self, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """Pixel-centre coordinates (H, W, 2): (i + 0.5, j + 0.5)."""
        xs = torch.arange(self.width, dtype=dtype) + 0.5
        ys = torch.arange(self.height, dtype=dtype) + 0.5
        yy, xx = torch.meshgrid(ys, xs, indexing="ij")
        return torch.stack([xx, yy], dim=-1)

    def world_directions(self, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """Unit world-space direction (H, W, 3) of every pixel centre."""
        rays = self.pixel_rays(self.pixel_grid(torch.float64))
        rays = rays / torch.linalg.norm(rays, dim=-1, keepdim=True)
        return (rays @ self.R).to(dtype)

    def z_to_ray_factor(self, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """Per-pixel factor (H, W) that turns z-depth into ray length."""
        rays = self.pixel_rays(self.pixel_grid(torch.float64))
        return torch.linalg.norm(rays, dim=-1).to(dtype)

    # --- OpenGL camera-to-world (nerfstudio's transforms.json and camera paths) ----------
    def camera_to_world_gl(self) -> torch.Tensor:
        """Camera-to-world (4, 4), float64, with OpenGL camera axes (x right, y up, z back)."""
        return torch.linalg.inv(self.world_to_cam) @ CV_TO_GL

    @classmethod
    def from_camera_to_world_gl(
        cls, camera_to_world: torch.Tensor, K: torch.Tensor, width: int, height: int
    ) -> Camera:
        """The camera whose ``camera_to_world_gl()`` is ``camera_to_world`` (4, 4)."""
        c2w = torch.as_tensor(camera_to_world, dtype=torch.float64) @ CV_TO_GL
        return cls(K, torch.linalg.inv(c2w), width, height)

    # --- serialisation (gt/views.json, viewer poses) ------------------------------------
    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "K": self.K.tolist(),
            "world_to_cam": self.world_to_cam[:3].tolist(),
            "width": self.width,
            "height": self.height,
        }
        if self.view_half_fov_tan is not None:
            d["view_half_fov_tan"] = list(self.view_half_fov_tan)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Camera:
        missing = {"K", "world_to_cam", "width", "height"} - set(d)
        if missing:
            raise ValueError(f"camera is missing keys {sorted(missing)}")
        tan = d.get("view_half_fov_tan")
        return cls(
            d["K"], d["world_to_cam"], d["width"], d["height"],
            None if tan is None else (float(tan[0]), float(tan[1])),
        )  # fmt: skip
