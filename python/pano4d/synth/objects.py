"""Solid objects standing on the landscape's ground: spheres, boxes and poles.

Each object is exact geometry: rays intersect it analytically (``SceneObject.intersect``),
and ``residual`` says how far a point lies from its surface (zero on it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from pano4d.synth.textures import normalize

OBJECT_KINDS = ("sphere", "box", "pole", "sphere", "box", "pole")
OBJECT_COLOURS = (
    (0.75, 0.12, 0.10), (0.90, 0.85, 0.75), (0.85, 0.20, 0.15),
    (0.15, 0.30, 0.70), (0.55, 0.35, 0.20), (0.95, 0.95, 0.92),
)  # fmt: skip


@dataclass(frozen=True)
class SceneObject:
    """A solid object standing on the ground.

    ``size``: sphere (radius, radius, radius); box half extents (x, y, z) before the yaw;
    pole (radius, radius, half height). ``centre`` is the object's centre in world metres.
    """

    kind: str
    centre: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw_deg: float
    colour: tuple[float, float, float]

    def bounding_radius(self) -> float:
        if self.kind == "sphere":
            return self.size[0]
        if self.kind == "pole":
            return math.hypot(self.size[0], self.size[2])
        return math.hypot(*self.size)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "centre": list(self.centre),
            "size": list(self.size),
            "yaw_deg": self.yaw_deg,
            "colour": list(self.colour),
        }

    def to_local(self, v: torch.Tensor, direction: bool = False) -> torch.Tensor:
        """World points (or directions) into the object's frame (centred, yaw undone)."""
        if not direction:
            v = v - torch.tensor(self.centre, dtype=v.dtype)
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        return torch.stack([c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1], v[:, 2]], -1)

    def rays_near(self, o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """Indices of the rays from ``o`` that pass through the object's bounding sphere."""
        oc = o - torch.tensor(self.centre)
        b = d @ oc
        disc = b * b - (float(oc @ oc) - self.bounding_radius() ** 2)
        idx = (disc > 0).nonzero()[:, 0]
        return idx[(-b[idx] + torch.sqrt(disc[idx])) > 0]

    def intersect(
        self, o: torch.Tensor, d: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Rays hitting the object: their indices, ray lengths and world normals.

        ``o`` is one origin (3,) or one per ray (N, 3); ``d`` (N, 3) or one shared (1, 3).
        Callers pass only rays near the object (``rays_near``, ``Landscape.object_shadow``).
        """
        n = o.shape[0] if o.dim() == 2 else d.shape[0]
        o, d = o.expand(n, 3), d.expand(n, 3)
        ol = self.to_local(o)
        dl = self.to_local(d, direction=True)
        sx, sy, sz = self.size
        if self.kind == "sphere":
            bb = (dl * ol).sum(-1)
            disc_s = bb * bb - ((ol * ol).sum(-1) - sx * sx)
            t = -bb - torch.sqrt(disc_s.clamp_min(0))
            t = torch.where((disc_s >= 0) & (t > 0), t, torch.inf)
            local_n = ol + t[:, None].clamp(max=1e9) * dl
        elif self.kind == "box":
            half = torch.tensor([sx, sy, sz])
            inv = 1.0 / torch.where(dl.abs() < 1e-12, torch.full_like(dl, 1e-12), dl)
            t1, t2 = (-half - ol) * inv, (half - ol) * inv
            t_near, axis = torch.minimum(t1, t2).max(dim=-1)
            t_far = torch.maximum(t1, t2).amin(dim=-1)
            t = torch.where((t_near <= t_far) & (t_near > 0), t_near, torch.inf)
            local_n = torch.zeros_like(dl)
            local_n.scatter_(1, axis[:, None], -torch.sign(dl.gather(1, axis[:, None])))
        else:
            # Side of the vertical cylinder, then its top cap (the bottom is underground).
            a = dl[:, 0] ** 2 + dl[:, 1] ** 2
            bb = ol[:, 0] * dl[:, 0] + ol[:, 1] * dl[:, 1]
            disc_c = bb * bb - a * (ol[:, 0] ** 2 + ol[:, 1] ** 2 - sx * sx)
            t_side = (-bb - torch.sqrt(disc_c.clamp_min(0))) / a.clamp_min(1e-12)
            z_side = ol[:, 2] + t_side * dl[:, 2]
            side = (disc_c >= 0) & (t_side > 0) & (z_side.abs() <= sz)
            dz = torch.where(dl[:, 2].abs() < 1e-12, torch.full_like(a, -1e-12), dl[:, 2])
            t_cap = (sz - ol[:, 2]) / dz
            cap_xy = ol[:, :2] + t_cap[:, None] * dl[:, :2]
            cap = (t_cap > 0) & ((cap_xy**2).sum(-1) <= sx * sx) & (dl[:, 2] < 0)
            t = torch.where(side, t_side, torch.where(cap, t_cap, torch.inf))
            p = ol + t[:, None].clamp(max=1e9) * dl
            local_n = torch.where(
                side[:, None],
                torch.stack([p[:, 0], p[:, 1], torch.zeros_like(a)], -1),
                torch.tensor([0.0, 0.0, 1.0]).expand_as(p),
            )
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        world_n = torch.stack(
            [
                c * local_n[:, 0] - s * local_n[:, 1],
                s * local_n[:, 0] + c * local_n[:, 1],
                local_n[:, 2],
            ],
            -1,
        )
        keep = torch.isfinite(t).nonzero()[:, 0]
        return keep, t[keep], normalize(world_n[keep])

    def residual(self, points: torch.Tensor) -> torch.Tensor:
        """Signed distance-like residual (N,) of world points (N, 3) to the object's surface."""
        local = self.to_local(points)
        sx, sy, sz = self.size
        if self.kind == "sphere":
            return torch.linalg.norm(local, dim=-1) - sx
        if self.kind == "box":
            return (local.abs() - torch.tensor([sx, sy, sz])).amax(dim=-1)
        radial = torch.hypot(local[:, 0], local[:, 1]) - sx
        return torch.maximum(radial, local[:, 2].abs() - sz)
