"""The indoor scene kind: a furnished room with a window onto a far exterior and a screen.

A procedural room, deterministic from a seed: a box of walls 2–6 m from the camera, floor
and ceiling (``RoomBox``), furniture standing in it (bookshelf, sofa, cabinet with a wall
screen above it, a table, a floor lamp, a plant, a ball: the ``objects`` primitives), and a
window in one wall through which rays leave the room for a far exterior: a plain with
buildings and trees tens of metres away, and the landscape's sky with drifting clouds.
Surfaces carry fine, band-limited textures (``room_shading``); two point lights (the ceiling
lamp and the window) cast exact shadows, found by casting rays from each light.

World frame (docs/design.md): +z up, the panorama's camera at the origin, the floor at
z = −camera_height; the room is turned by a random yaw. Motion: the screen plays a looping
video and the clouds seen through the window drift, periodically with period L frames;
everything else is static and bit-identical in every frame. Geometry never moves, so depth
is the same in every frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import torch

from pano4d.synth.objects import SceneObject
from pano4d.synth.room_geometry import (
    LABEL_CEILING,
    LABEL_FLOOR,
    LABEL_FURNITURE,
    LABEL_GROUND,
    LABEL_OUTSIDE,
    LABEL_SCREEN,
    LABEL_WALL,
    WALLS,
    Furniture,
    Light,
    RoomBox,
    Window,
)
from pano4d.synth.room_shading import RoomLook
from pano4d.synth.shading import CLOUD_REPEATS, Sky, cloud_texture
from pano4d.synth.textures import TiledNoise, fft_noise, normalize, periodic
from pano4d.synth.world import (
    LABEL_SKY,
    SKY_DEPTH,
    Hits,
    MotionHint,
    shade_split,
    world_metadata,
)

CAMERA_HEIGHT = 1.5
GROUND_RADIUS = 900.0  # the exterior plain ends here (the sky sphere is at SKY_DEPTH)
WALL_GAP = 0.01  # metres between a wall and the furniture standing against it


class Room:
    """The analytic room of one seed: geometry, materials, lights and motion.

    ``frames`` is the loop period L: what moves (the screen's video, the clouds) is a
    periodic function of the time index with period L.
    """

    moving_parts = "the screen and the sky through the window"

    def __init__(self, seed: int, frames: int, camera_height: float = CAMERA_HEIGHT) -> None:
        if frames < 1:
            raise ValueError(f"frames must be >= 1, got {frames}")
        if not 0.3 <= camera_height <= 2.2:
            raise ValueError(
                f"camera_height must be in [0.3, 2.2] m in a room, got {camera_height}"
            )
        self.seed = int(seed)
        self.frames = int(frames)
        self.camera_height = float(camera_height)
        # Every draw comes from this one generator, in this order: a seed is a scene.
        gen = torch.Generator().manual_seed(self.seed)
        self._gen = gen
        h = self.camera_height
        ceiling = max(h + 1.0, self._rand(2.6, 3.3))
        lo = (-self._rand(2.2, 5.0), -self._rand(2.2, 5.0), -h)
        hi = (self._rand(2.4, 6.0), self._rand(2.4, 6.0), ceiling - h)
        self.box = RoomBox(lo, hi, self._rand(0.0, 90.0))
        walls = torch.randperm(4, generator=gen).tolist()
        window_wall, screen_wall, shelf_wall, sofa_wall = walls

        # The window: 1.4–2.2 m wide, its sill 0.7–0.9 m above the floor.
        lo_s, hi_s = self._along(window_wall)
        width = min(self._rand(1.6, 2.6), hi_s - lo_s - 0.8)
        s0 = self._rand(lo_s + 0.4, hi_s - 0.4 - width)
        sill = -h + self._rand(0.6, 0.85)
        top = min(sill + self._rand(1.5, 1.8), ceiling - h - 0.2)
        self.window = Window(window_wall, s0, s0 + width, sill, top)

        sun_azimuth, sun_elevation = self._rand(0.0, 2 * math.pi), math.radians(self._rand(25, 45))
        self.sun = torch.tensor(
            [
                math.cos(sun_elevation) * math.cos(sun_azimuth),
                math.cos(sun_elevation) * math.sin(sun_azimuth),
                math.sin(sun_elevation),
            ],
            dtype=torch.float32,
        )
        detail = torch.stack([fft_noise(gen, 512, 512, e, largest=128.0) for e in (1.1, 0.8)])
        self.detail = TiledNoise(periodic(detail))
        self.sky = Sky(self.sun, cloud_texture(gen), self.detail, cover=self._rand(0.35, 0.6))

        self.furniture = self._furnish(screen_wall, shelf_wall, sofa_wall)
        self.outside = self._exterior()
        # The ceiling lamp hangs in the middle of the room, away from the camera, and shines
        # mostly downwards; the window's light comes from just inside its centre, into the room.
        lamp = next(f for f in self.furniture if f.material == "lamp")
        inward = -self._wall_normal_local(window_wall)
        centre = self._wall_point(window_wall, (s0 + s0 + width) / 2, (sill + top) / 2)
        window_light = self.box.to_world((centre + 0.3 * inward)[None])[0]
        self.lights = (
            Light(torch.tensor(lamp.shape.centre), torch.tensor([0.0, 0.0, -1.0]), 0.85, 4.5,
                  (1.0, 0.9, 0.75)),
            Light(window_light, self.box.to_world(inward[None])[0], 1.0, 3.0, (0.8, 0.9, 1.0)),
        )  # fmt: skip
        self.look = RoomLook(self, gen)

    # --- layout ----------------------------------------------------------------------------
    def _rand(self, lo: float, hi: float) -> float:
        return lo + (hi - lo) * float(torch.rand((), generator=self._gen))

    def _along(self, wall: int) -> tuple[float, float]:
        """The extent of wall ``wall`` along its horizontal axis (room frame)."""
        other = 1 - WALLS[wall][0]
        return self.box.lo[other], self.box.hi[other]

    def _wall_normal_local(self, wall: int) -> torch.Tensor:
        axis, sign = WALLS[wall]
        n = torch.zeros(3)
        n[axis] = sign
        return n

    def _wall_point(self, wall: int, s: float, z: float) -> torch.Tensor:
        """The room-frame point at ``s`` along wall ``wall`` and height z, on the wall."""
        axis, sign = WALLS[wall]
        p = torch.zeros(3)
        p[axis] = self.box.hi[axis] if sign > 0 else self.box.lo[axis]
        p[1 - axis] = s
        p[2] = z
        return p

    def _against(
        self, wall: int, width: float, depth: float, height: float, s: float, z0: float,
        material: str, out: float = 0.0,
    ) -> Furniture:  # fmt: skip
        """A box ``width`` along wall ``wall`` (centred at ``s``), ``depth`` into the room,
        from world z ``z0`` up by ``height``; ``out`` metres further from the wall."""
        axis, sign = WALLS[wall]
        centre = self._wall_point(wall, s, z0 + height / 2)
        centre[axis] -= sign * (WALL_GAP + out + depth / 2)
        half = [width / 2, width / 2, height / 2]
        half[axis] = depth / 2
        world = self.box.to_world(centre[None])[0]
        shape = SceneObject("box", tuple(world.tolist()), tuple(half), self.box.yaw_deg, (0, 0, 0))
        return Furniture(shape, material, wall)

    def _free_spot(self, radius: float, keep_out: list[tuple[float, float, float]]) -> tuple:
        """A room-frame (x, y) at least ``radius`` from the walls and clear of the camera and
        of ``keep_out`` discs (x, y, r)."""
        lo, hi = self.box.lo, self.box.hi
        for _ in range(500):
            x = self._rand(lo[0] + radius + 0.2, hi[0] - radius - 0.2)
            y = self._rand(lo[1] + radius + 0.2, hi[1] - radius - 0.2)
            if math.hypot(x, y) > radius + 1.0 and all(
                math.hypot(x - a, y - b) > radius + r + 0.15 for a, b, r in keep_out
            ):
                return x, y
        raise RuntimeError(f"seed {self.seed}: no room for furniture of radius {radius}")

    def _furnish(self, screen_wall: int, shelf_wall: int, sofa_wall: int) -> list[Furniture]:
        h, ceiling = self.camera_height, self.box.hi[2]
        items: list[Furniture] = []
        keep_out: list[tuple[float, float, float]] = []

        def along(wall: int, width: float) -> tuple[float, float]:
            lo, hi = self._along(wall)
            width = min(width, hi - lo - 0.5)
            return width, self._rand(lo + 0.25 + width / 2, hi - 0.25 - width / 2)

        # A bookshelf, a sofa (seat and back), a cabinet with the screen above it.
        width, s = along(shelf_wall, self._rand(1.0, 1.8))
        items.append(self._against(shelf_wall, width, 0.34, self._rand(1.8, 2.2), s, -h, "books"))
        width, s = along(sofa_wall, self._rand(1.8, 2.4))
        items.append(self._against(sofa_wall, width, 0.2, 0.85, s, -h, "fabric"))
        items.append(self._against(sofa_wall, width, 0.7, 0.42, s, -h, "fabric", out=0.2))
        width, s = along(screen_wall, self._rand(1.2, 1.8))
        items.append(self._against(screen_wall, width, 0.42, 0.5, s, -h, "wood"))
        screen_w = min(width, self._rand(1.2, 1.6))
        screen_z = -h + self._rand(1.0, 1.2)
        screen = self._against(
            screen_wall, screen_w, 0.05, screen_w * 0.5625, s, screen_z, "screen"
        )
        items.append(screen)
        for f in items:
            local = self.box.to_local(torch.tensor([f.shape.centre]))[0]
            keep_out.append((float(local[0]), float(local[1]), math.hypot(*f.shape.size[:2])))

        # A table on four legs.
        x, y = self._free_spot(0.8, keep_out)
        keep_out.append((x, y, 0.8))
        half = (self._rand(0.5, 0.7), self._rand(0.35, 0.45), 0.02)
        top = 0.74
        table = torch.tensor([[x, y, -h + top - half[2]]])
        items.append(self._object("box", table, half, "wood"))
        for sx in (-1, 1):
            for sy in (-1, 1):
                leg = torch.tensor([[x + sx * (half[0] - 0.06), y + sy * (half[1] - 0.06), 0.0]])
                leg_half = (top - 2 * half[2]) / 2
                leg[0, 2] = -h + leg_half
                items.append(self._object("pole", leg, (0.025, 0.025, leg_half), "metal"))
        # A floor lamp (stem and shade), a plant (pot and leaves), a ball.
        x, y = self._free_spot(0.3, keep_out)
        keep_out.append((x, y, 0.3))
        items.append(self._object("pole", torch.tensor([[x, y, -h + 0.75]]), (0.02, 0.02, 0.75),
                                  "metal"))  # fmt: skip
        items.append(self._object("sphere", torch.tensor([[x, y, -h + 1.6]]), (0.2,) * 3,
                                  "shade"))  # fmt: skip
        x, y = self._free_spot(0.45, keep_out)
        keep_out.append((x, y, 0.45))
        items.append(self._object("pole", torch.tensor([[x, y, -h + 0.22]]), (0.18, 0.18, 0.22),
                                  "pot"))  # fmt: skip
        items.append(self._object("sphere", torch.tensor([[x, y, -h + 0.8]]), (0.38,) * 3,
                                  "leaves"))  # fmt: skip
        x, y = self._free_spot(0.25, keep_out)
        radius = self._rand(0.12, 0.22)
        items.append(self._object("sphere", torch.tensor([[x, y, -h + radius]]), (radius,) * 3,
                                  "ball"))  # fmt: skip
        # The ceiling lamp: a glowing globe in the room's middle, 0.7 m below the ceiling.
        mid_x, mid_y = (self.box.lo[0] + self.box.hi[0]) / 2, (self.box.lo[1] + self.box.hi[1]) / 2
        if math.hypot(mid_x, mid_y) < 0.6:  # not straight above the camera
            mid_x += 0.8
        lamp = torch.tensor([[mid_x, mid_y, ceiling - 0.7]])
        items.append(self._object("sphere", lamp, (0.15,) * 3, "lamp"))
        return items

    def _object(
        self, kind: str, local_centre: torch.Tensor, half: tuple[float, ...], material: str
    ) -> Furniture:
        centre = self.box.to_world(local_centre)[0]
        shape = SceneObject(kind, tuple(centre.tolist()), tuple(half), self.box.yaw_deg, (0, 0, 0))
        return Furniture(shape, material)

    def _exterior(self) -> list[SceneObject]:
        """Buildings and trees on the plain beyond the window, 35–150 m away, spread over
        the directions the window opens onto."""
        h = self.camera_height
        centre = self._wall_point(self.window.wall, (self.window.s0 + self.window.s1) / 2, 0.0)
        facing = math.atan2(float(centre[1]), float(centre[0]))  # room frame
        out: list[SceneObject] = []
        for i in range(8):
            azimuth = facing + self._rand(-1.2, 1.2)
            distance = self._rand(35.0, 150.0)
            x, y = distance * math.cos(azimuth), distance * math.sin(azimuth)
            local = torch.tensor([[x, y, 0.0]])
            if i % 3 == 2:  # a tree: a crown on a trunk
                crown = self._rand(2.0, 4.0)
                local[0, 2] = -h + 2.5 + crown
                shade = (0.18, 0.35 + self._rand(0, 0.1), 0.12)
                out.append(self._exterior_object("sphere", local, (crown,) * 3, 0.0, shade))
                trunk = torch.tensor([[x, y, -h + 1.5]])
                bark = (0.3, 0.22, 0.15)
                out.append(self._exterior_object("pole", trunk, (0.3, 0.3, 1.5), 0.0, bark))
            else:
                half = (self._rand(4, 10), self._rand(4, 10), self._rand(2.5, 7))
                local[0, 2] = -h + half[2]
                tint = self._rand(0.45, 0.8)
                colour = (tint, tint * self._rand(0.85, 1.0), tint * self._rand(0.7, 0.95))
                yaw = self._rand(0, 90)
                out.append(self._exterior_object("box", local, half, yaw, colour))
        return out

    def _exterior_object(
        self, kind: str, local: torch.Tensor, half: tuple[float, ...], yaw: float,
        colour: tuple[float, float, float],
    ) -> SceneObject:  # fmt: skip
        centre = self.box.to_world(local)[0]
        return SceneObject(
            kind, tuple(centre.tolist()), tuple(half), self.box.yaw_deg + yaw, colour
        )

    # --- metadata ----------------------------------------------------------------------------
    @property
    def screen(self) -> Furniture:
        return next(f for f in self.furniture if f.material == "screen")

    def motion_hint(self) -> MotionHint:
        # The clouds drift towards +u by one repeat per loop, as the landscape's.
        return MotionHint(0.0, 360.0 / CLOUD_REPEATS / self.frames, "cloud drift and screen")

    def metadata(self) -> dict[str, Any]:
        return world_metadata(
            self,
            room={"lo": list(self.box.lo), "hi": list(self.box.hi), "yaw_deg": self.box.yaw_deg},
            window=self.window.to_dict(),
            lights=[light.to_dict() for light in self.lights],
            furniture=[f.to_dict() for f in self.furniture],
            outside=[o.to_dict() for o in self.outside],
        )

    # --- surfaces ----------------------------------------------------------------------------
    def surface_residual(self, points: torch.Tensor, label: torch.Tensor) -> torch.Tensor:
        """Signed distance-like residual (N,) of world points to the surface named by
        ``label``: zero (to float precision) on it."""
        res = torch.full(label.shape, float("nan"))
        sky = label == LABEL_SKY
        res[sky] = torch.linalg.norm(points[sky], dim=-1) - SKY_DEPTH
        room = (label == LABEL_FLOOR) | (label == LABEL_CEILING) | (label == LABEL_WALL)
        res[room] = self.box.residual(points[room])
        ground = label == LABEL_GROUND
        res[ground] = points[ground, 2] + self.camera_height
        for i, f in enumerate(self.furniture):
            sel = label == (LABEL_SCREEN if f.material == "screen" else LABEL_FURNITURE + i)
            res[sel] = f.shape.residual(points[sel])
        for j, obj in enumerate(self.outside):
            sel = label == LABEL_OUTSIDE + j
            res[sel] = obj.residual(points[sel])
        return res

    # --- ray casting -------------------------------------------------------------------------
    def cast(self, origin: Sequence[float] | torch.Tensor, dirs: torch.Tensor) -> Hits:
        """Intersect rays from one ``origin`` (3,) inside the room along unit ``dirs``
        (N, 3) with the scene."""
        o = torch.as_tensor(origin, dtype=torch.float32).reshape(3)
        if not self.box.contains(self.box.to_local(o[None]), margin=0.05):
            raise ValueError(f"camera position {o.tolist()} is outside the room")
        d = dirs.to(torch.float32).reshape(-1, 3)
        n = d.shape[0]
        ol, dl = self.box.to_local(o[None])[0], self.box.to_local(d)
        depth, face = self.box.exit(ol, dl)
        label = torch.full((n,), LABEL_WALL, dtype=torch.uint8)
        label[face == 4] = LABEL_CEILING
        label[face == 5] = LABEL_FLOOR
        normal_local = torch.zeros(n, 3)
        for f in range(6):
            sel = face == f
            axis, sign = WALLS[f] if f < 4 else (2, 1.0 if f == 4 else -1.0)
            normal_local[sel, axis] = -sign  # facing into the room
        normal = self.box.to_world(normal_local)

        # Rays through the window's panes go on to the exterior.
        axis = WALLS[self.window.wall][0]
        at_wall = ol + depth[:, None] * dl
        through = (face == self.window.wall) & self.window.open_at(
            at_wall[:, 1 - axis], at_wall[:, 2]
        )
        idx = through.nonzero()[:, 0]
        if len(idx):
            t_out, label_out, normal_out = self._cast_outside(o, d[idx])
            depth[idx], label[idx], normal[idx] = t_out, label_out, normal_out

        for i, f in enumerate(self.furniture):
            near = f.shape.rays_near(o, d)
            hit, t_obj, n_obj = f.shape.intersect(o, d[near])
            hit = near[hit]
            closer = t_obj < depth[hit]
            hit = hit[closer]
            depth[hit], normal[hit] = t_obj[closer], n_obj[closer]
            label[hit] = LABEL_SCREEN if f.material == "screen" else LABEL_FURNITURE + i
        return Hits(depth, label, normal)

    def _cast_outside(
        self, o: torch.Tensor, d: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Rays that left through the window: the plain, the exterior objects or the sky."""
        n = d.shape[0]
        b = d @ o
        depth = -b + torch.sqrt(b * b - (float(o @ o) - SKY_DEPTH**2))
        label = torch.full((n,), LABEL_SKY, dtype=torch.uint8)
        normal = -d.clone()
        down = d[:, 2] < 0
        t_plane = torch.where(down, (-self.camera_height - o[2]) / d[:, 2].clamp(max=-1e-12),
                              torch.inf)  # fmt: skip
        px, py = o[0] + t_plane * d[:, 0], o[1] + t_plane * d[:, 1]
        on_plain = down & (px * px + py * py < GROUND_RADIUS**2)
        depth = torch.where(on_plain, t_plane, depth)
        label[on_plain] = LABEL_GROUND
        normal[on_plain] = torch.tensor([0.0, 0.0, 1.0])
        for j, obj in enumerate(self.outside):
            near = obj.rays_near(o, d)
            hit, t_obj, n_obj = obj.intersect(o, d[near])
            hit = near[hit]
            closer = t_obj < depth[hit]
            hit = hit[closer]
            depth[hit], label[hit], normal[hit] = t_obj[closer], LABEL_OUTSIDE + j, n_obj[closer]
        return depth, label, normal

    def lit_from(self, light: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """(N,) 1 where ``light`` (3,) reaches the room points p (N, 3) unblocked, else 0:
        rays cast from the light, a point is lit when nothing is hit before it."""
        to_p = p - light
        dist = torch.linalg.norm(to_p, dim=-1)
        hits = self.cast(light, normalize(to_p))
        return (hits.depth >= dist * (1 - 1e-3) - 2e-3).to(torch.float32)

    # --- shading -----------------------------------------------------------------------------
    def moves(self, label: torch.Tensor) -> torch.Tensor:
        """Which labels change over time: the screen and the sky (clouds)."""
        return (label == LABEL_SKY) | (label == LABEL_SCREEN)

    def shade(self, o: torch.Tensor, d: torch.Tensor, hits: Hits, time: float) -> torch.Tensor:
        """Colour (N, 3) in [0, 1] of every ray at time ``time`` (frames, real-valued)."""
        return shade_split(self, self.look.static, o, d, hits, time)

    def moving_shader(
        self, o: torch.Tensor, d: torch.Tensor, hits: Hits
    ) -> Callable[[float], torch.Tensor]:
        """time -> colour (N, 3) of rays that hit the sky or the screen; what does not depend
        on time is computed once, here."""
        o = torch.as_tensor(o, dtype=torch.float32).reshape(3)
        sky = (hits.label == LABEL_SKY).nonzero()[:, 0]
        screen = (hits.label == LABEL_SCREEN).nonzero()[:, 0]
        sky_rays = self.sky.rays(normalize(o + hits.depth[sky, None] * d[sky]))
        play = self.look.screen(o + hits.depth[screen, None] * d[screen], hits.depth[screen],
                                hits.normal[screen])  # fmt: skip

        def at(time: float) -> torch.Tensor:
            phase = (time % self.frames) / self.frames
            colour = torch.empty_like(d)
            colour[sky] = self.sky.colour(sky_rays, phase)
            colour[screen] = play(phase)
            return colour.clamp(0.0, 1.0)

        return at
