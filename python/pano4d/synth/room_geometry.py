"""The room's geometry pieces: its labels, the box of walls, floor and ceiling, the window
in one wall, and the furniture records (``room`` lays them out, ``room_shading`` colours
them). All exact: rays meet them analytically and ``residual`` is zero on their surfaces."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from pano4d.synth.objects import SceneObject

# Labels of what a ray hit (after the sky's LABEL_SKY). Furniture i is LABEL_FURNITURE + i,
# exterior object j LABEL_OUTSIDE + j.
LABEL_FLOOR, LABEL_CEILING, LABEL_WALL, LABEL_SCREEN, LABEL_GROUND = 1, 2, 3, 4, 5
LABEL_FURNITURE, LABEL_OUTSIDE = 16, 64

MULLION = 0.06  # width of the window's frame and its cross bars, metres

# The room's walls by outward normal in the room frame: +x, −x, +y, −y.
WALLS = ((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0))


@dataclass(frozen=True)
class Furniture:
    """A piece of furniture: its exact shape and what it is made of (``room_shading``)."""

    shape: SceneObject
    material: str  # books | fabric | wood | metal | lamp | shade | leaves | pot | ball | screen
    wall: int | None = None  # the wall it stands against (index into WALLS)

    def to_dict(self) -> dict[str, Any]:
        return {**self.shape.to_dict(), "material": self.material, "wall": self.wall}


@dataclass(frozen=True)
class Light:
    """A point light: ``power`` is the radiance it gives at 1 m along its ``axis``; a share
    ``focus`` (0–1) of it fades to nothing for directions at right angles to the axis."""

    position: torch.Tensor  # (3,) world
    axis: torch.Tensor  # (3,) unit, world
    focus: float
    power: float
    colour: tuple[float, float, float]

    def emission(self, towards: torch.Tensor) -> torch.Tensor:
        """(N,) what the light sends along unit directions ``towards`` (N, 3)."""
        along = (towards @ self.axis).clamp_min(0)
        return self.power * (1 - self.focus + self.focus * along)

    def to_dict(self) -> dict[str, Any]:
        return {
            "position": self.position.tolist(),
            "axis": self.axis.tolist(),
            "focus": self.focus,
            "power": self.power,
            "colour": list(self.colour),
        }


@dataclass(frozen=True)
class RoomBox:
    """The room's box in its own frame (the world turned by ``yaw_deg`` about z):
    ``lo`` and ``hi`` corners (x, y, z); the panorama's camera is at the frame's origin."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    yaw_deg: float

    def to_local(self, v: torch.Tensor, direction: bool = False) -> torch.Tensor:
        del direction  # the frame shares the world's origin: points and directions alike
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        return torch.stack([c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1], v[:, 2]], -1)

    def to_world(self, v: torch.Tensor) -> torch.Tensor:
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        return torch.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]], -1)

    def contains(self, local: torch.Tensor, margin: float) -> bool:
        lo, hi = torch.tensor(self.lo) + margin, torch.tensor(self.hi) - margin
        return bool(((local > lo) & (local < hi)).all())

    def exit(self, ol: torch.Tensor, dl: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Where rays from the local point ``ol`` (3,) along ``dl`` (N, 3) leave the box: ray
        length and face (0–3 the walls of WALLS, 4 the ceiling, 5 the floor)."""
        lo, hi = torch.tensor(self.lo), torch.tensor(self.hi)
        safe = torch.where(dl.abs() < 1e-12, torch.full_like(dl, 1e-12), dl)
        t = torch.where(dl > 0, (hi - ol) / safe, (lo - ol) / safe)
        t = torch.where(dl.abs() < 1e-12, torch.full_like(t, torch.inf), t)
        t_exit, axis = t.min(dim=-1)
        positive = dl.gather(1, axis[:, None])[:, 0] > 0
        face = torch.where(axis == 2, 5 - positive.long(), 2 * axis + (~positive).long())
        return t_exit, face

    def residual(self, points: torch.Tensor) -> torch.Tensor:
        """Signed distance-like residual (N,) of world points to the box's surface (zero on
        its walls, floor and ceiling, negative inside)."""
        local = self.to_local(points)
        lo, hi = torch.tensor(self.lo), torch.tensor(self.hi)
        return torch.maximum(lo - local, local - hi).amax(dim=-1)


@dataclass(frozen=True)
class Window:
    """An opening in wall ``wall``: along the wall from ``s0`` to ``s1`` (the wall's other
    horizontal axis, room frame), from ``z0`` to ``z1`` (world z). Its frame and a cross of
    bars (MULLION wide) are wall; the panes are open."""

    wall: int
    s0: float
    s1: float
    z0: float
    z1: float

    def open_at(self, s: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """(N,) bool: whether points (s, z) on the window's wall are in an open pane."""
        half = MULLION / 2
        inside = (s > self.s0 + half) & (s < self.s1 - half) & (z > self.z0 + half)
        inside &= z < self.z1 - half
        mid_s, mid_z = (self.s0 + self.s1) / 2, (self.z0 + self.z1) / 2
        return inside & ((s - mid_s).abs() > half) & ((z - mid_z).abs() > half)

    def to_dict(self) -> dict[str, Any]:
        return {"wall": self.wall, "along": [self.s0, self.s1], "z": [self.z0, self.z1]}
