"""How the room looks: materials, lights and the screen's video.

Textures are fine but band-limited: every pattern is filtered over the pixel footprint of a
1024-wide panorama at the hit (``REF_PIXEL_RAD``: thin lines box-filtered exactly,
``pulse_coverage``; finer detail faded to its mean, ``detail_fade``), so the scene holds
detail down to what such a panorama resolves and no aliasing beyond. The room is lit by
an ambient term and two point lights (the ceiling lamp, the window) with exact shadows
(``Room.lit_from``); the ball is glossy, so what it shows depends on where it is seen from.
Outside, the sun lights the plain, the buildings and the trees.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import torch

from pano4d.smoothstep import smoothstep
from pano4d.synth.room_geometry import (
    LABEL_CEILING,
    LABEL_FLOOR,
    LABEL_FURNITURE,
    LABEL_GROUND,
    LABEL_OUTSIDE,
    LABEL_WALL,
    WALLS,
    Furniture,
)
from pano4d.synth.shading import fog, lighting
from pano4d.synth.textures import (
    cell_blend,
    detail_fade,
    fft_noise,
    lerp,
    normalize,
    periodic,
    pulse_coverage,
    rgb,
    sample,
)
from pano4d.synth.world import Hits

if TYPE_CHECKING:
    from pano4d.synth.room import Room

REF_PIXEL_RAD = 2 * math.pi / 1024  # the pixel whose footprint textures are filtered over
HASH_SIZE = 4096
AMBIENT = rgb(0.24, 0.23, 0.22)
BOOK_COLOURS = torch.tensor(
    [
        [0.55, 0.10, 0.08], [0.10, 0.22, 0.45], [0.85, 0.75, 0.45], [0.12, 0.35, 0.18],
        [0.75, 0.40, 0.12], [0.30, 0.12, 0.35], [0.90, 0.88, 0.82], [0.20, 0.20, 0.22],
    ]
)  # fmt: skip


class RoomLook:
    """The materials of one room (drawn from ``gen`` after the room's layout)."""

    def __init__(self, room: Room, gen: torch.Generator) -> None:
        self.room = room
        rand = lambda lo, hi: lo + (hi - lo) * float(torch.rand((), generator=gen))  # noqa: E731
        self.hash = torch.rand(HASH_SIZE, generator=gen)
        self.wall_tints = 0.62 + 0.25 * torch.rand(4, 3, generator=gen)
        self.plank_width = rand(0.12, 0.2)
        lo, hi = room.box.lo, room.box.hi
        cx, cy = rand(lo[0] + 1.2, hi[0] - 1.2), rand(lo[1] + 1.0, hi[1] - 1.0)
        half = (rand(0.8, 1.2), rand(0.6, 0.9))
        self.rug = (cx - half[0], cy - half[1], cx + half[0], cy + half[1])
        self.rug_colours = (rgb(rand(0.4, 0.7), 0.12, 0.10), rgb(0.85, 0.78, 0.6))
        self.fabric = rgb(rand(0.2, 0.5), rand(0.25, 0.45), rand(0.35, 0.6))
        self.ball = rgb(0.85, rand(0.1, 0.5), 0.1)
        # A painting above the sofa: a smooth random image in a gold frame.
        image = torch.stack([fft_noise(gen, 48, 64, 1.6, largest=32.0) for _ in range(3)])
        self.painting = periodic((0.5 + 0.22 * image).clamp(0, 1))
        sofa = next(f for f in room.furniture if f.material == "fabric")
        assert sofa.wall is not None
        s_centre = self._along_wall(sofa.wall, torch.tensor([sofa.shape.centre]))[0]
        width, height = rand(0.8, 1.2), rand(0.55, 0.75)
        z0 = -room.camera_height + 1.15
        self.painting_rect = (sofa.wall, float(s_centre) - width / 2, z0,
                              float(s_centre) + width / 2, z0 + height)  # fmt: skip

    # --- helpers -----------------------------------------------------------------------------
    def _hash(self, *index: torch.Tensor) -> torch.Tensor:
        key = torch.zeros_like(index[0], dtype=torch.int64)
        for i, k in enumerate(index):
            key = key + k.to(torch.int64) * (1 + 7919 * i + 104729 * i * i)
        return self.hash[key.remainder(HASH_SIZE)]

    def _along_wall(self, wall: int, p: torch.Tensor) -> torch.Tensor:
        """The room-frame horizontal coordinate along wall ``wall`` of world points p."""
        return self.room.box.to_local(p)[:, 1 - WALLS[wall][0]]

    @staticmethod
    def footprint(dist: torch.Tensor, d: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
        """A pixel's size on the surface (metres), widened at grazing incidence."""
        cos = (d * normal).sum(-1).abs().clamp_min(0.25)
        return dist * REF_PIXEL_RAD / cos

    # --- static shading ----------------------------------------------------------------------
    def static(self, o: torch.Tensor, d: torch.Tensor, hits: Hits) -> torch.Tensor:
        """Colour (N, 3) of rays that hit what does not move."""
        p = o + hits.depth[:, None] * d
        fp = self.footprint(hits.depth, d, hits.normal)
        label = hits.label
        out = torch.zeros_like(p)
        outside = label == LABEL_GROUND
        for j in range(len(self.room.outside)):
            outside |= label == LABEL_OUTSIDE + j
        idx = outside.nonzero()[:, 0]
        out[idx] = self._outside(p[idx], hits.depth[idx], hits.normal[idx], label[idx], fp[idx])

        inside = (~outside).nonzero()[:, 0]
        p_in, n_in, fp_in, lab = p[inside], hits.normal[inside], fp[inside], label[inside]
        albedo = torch.zeros_like(p_in)
        emissive = torch.zeros(len(inside), dtype=torch.bool)
        gloss = torch.zeros(len(inside))
        local = self.room.box.to_local(p_in)
        sel = lab == LABEL_FLOOR
        albedo[sel] = self._floor(local[sel], fp_in[sel])
        sel = lab == LABEL_CEILING
        albedo[sel] = rgb(0.86, 0.85, 0.82) * (1 + 0.03 * self.room.detail.at(
            local[sel, 0], local[sel, 1], 6.0, 0))[:, None]  # fmt: skip
        sel = lab == LABEL_WALL
        albedo[sel] = self._walls(local[sel], n_in[sel], fp_in[sel])
        for i, f in enumerate(self.room.furniture):
            sel = lab == LABEL_FURNITURE + i
            if not sel.any():
                continue
            albedo[sel] = self._furniture(f, p_in[sel], n_in[sel], fp_in[sel])
            emissive[sel] = f.material in ("lamp", "shade")
            gloss[sel] = 1.0 if f.material == "ball" else 0.0
        light = AMBIENT.expand_as(p_in).clone()
        highlight = torch.zeros_like(p_in)
        view = -d[inside]
        for lamp in self.room.lights:
            to_light = lamp.position - p_in
            r2 = (to_light * to_light).sum(-1).clamp_min(0.05)
            ldir = to_light / r2.sqrt()[:, None]
            reach = self.room.lit_from(lamp.position, p_in) * lamp.emission(-ldir) / r2
            colour = rgb(*lamp.colour)
            light += ((n_in * ldir).sum(-1).clamp_min(0) * reach)[:, None] * colour
            # Blinn-Phong highlight on glossy surfaces: it moves with the viewer.
            half = normalize(ldir + view)
            shine = (n_in * half).sum(-1).clamp_min(0) ** 60 * gloss * reach
            highlight += 0.6 * shine[:, None] * colour
        shaded = albedo * light + highlight
        shaded[emissive] = albedo[emissive]
        out[inside] = shaded
        return out.clamp(0.0, 1.0)

    def _floor(self, local: torch.Tensor, fp: torch.Tensor) -> torch.Tensor:
        """Wooden planks along the room's x axis (rows of boards, each row's joints shifted),
        and the rug; plank and rug edges are filtered like the textures."""
        x, y = local[:, 0], local[:, 1]
        pw = self.plank_width

        def row_look(r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            """Row r's board tint and board-joint coverage at x, filtered along the row."""
            along = x + 1.3 * self._hash(r)
            lower, upper, share = cell_blend(along, 1.3, fp)
            tint = torch.lerp(self._hash(r, lower), self._hash(r, upper), share)
            return tint, pulse_coverage(along, 1.3, 0.004, fp)

        lower, upper, share = cell_blend(y, pw, fp)
        (tint_lo, joint_lo), (tint_hi, joint_hi) = row_look(lower), row_look(upper)
        tint = 0.8 + 0.4 * torch.lerp(tint_lo, tint_hi, share)
        joints = torch.maximum(
            pulse_coverage(y, pw, 0.004, fp), torch.lerp(joint_lo, joint_hi, share)
        )
        grain = self.room.detail.at(x / 8.0, y, 5.0, 1) * detail_fade(fp, 0.03)
        wood = rgb(0.52, 0.34, 0.19) * (tint * (1 + 0.12 * grain) * (1 - 0.55 * joints))[:, None]

        x0, y0, x1, y1 = self.rug
        inside = torch.minimum(torch.minimum(x - x0, x1 - x), torch.minimum(y - y0, y1 - y))
        cover = (inside / fp.clamp_min(1e-5) + 0.5).clamp(0.0, 1.0)  # box-filtered rug edge
        on_rug = (cover > 0).nonzero()[:, 0]
        rx, ry, f = x[on_rug], y[on_rug], fp[on_rug]
        border = pulse_coverage(inside[on_rug], 1e3, 0.15, f)  # the band along its edge
        lattice = torch.maximum(pulse_coverage(rx + ry, 0.25, 0.035, f),
                                pulse_coverage(rx - ry, 0.25, 0.035, f))  # fmt: skip
        weave = self.room.detail.at(rx, ry, 4.0, 0) * detail_fade(f, 0.02)
        dark, light = (c.expand(len(rx), 3) for c in self.rug_colours)
        rug = lerp(dark, light, torch.maximum(lattice, border)) * (1 + 0.1 * weave)[:, None]
        wood[on_rug] = lerp(wood[on_rug], rug, cover[on_rug])
        return wood

    def _walls(self, local: torch.Tensor, normal: torch.Tensor, fp: torch.Tensor) -> torch.Tensor:
        """Wallpaper (stripes and a dot grid), the window's white frame, the painting."""
        n_local = self.room.box.to_local(normal)
        out = torch.zeros_like(local)
        win = self.room.window
        for k, (axis, sign) in enumerate(WALLS):
            sel = (n_local[:, axis] * -sign) > 0.5
            s, z, f = local[sel, 1 - axis], local[sel, 2], fp[sel]
            stripes = pulse_coverage(s, 0.18, 0.09, f)
            dots = pulse_coverage(s, 0.06, 0.02, f) * pulse_coverage(z, 0.06, 0.02, f)
            stains = self.room.detail.at(s, z + 3.0 * k, 3.0, 0)
            paper = self.wall_tints[k] * (1 - 0.07 * stripes - 0.18 * dots + 0.03 * stains)[:, None]
            if k == win.wall:
                frame = (s > win.s0) & (s < win.s1) & (z > win.z0) & (z < win.z1)
                paper[frame] = rgb(0.93, 0.93, 0.91)
            wall, s0, z0, s1, z1 = self.painting_rect
            if k == wall:
                inside = (s > s0) & (s < s1) & (z > z0) & (z < z1)
                gx = (s[inside] - s0) / (s1 - s0) * 2 - 1
                gy = 1 - (z[inside] - z0) / (z1 - z0) * 2
                picture = sample(self.painting, gx, gy)
                rim = torch.minimum(torch.minimum(s[inside] - s0, s1 - s[inside]),
                                    torch.minimum(z[inside] - z0, z1 - z[inside]))  # fmt: skip
                gold = rgb(0.75, 0.6, 0.25).expand_as(picture)
                paper[inside] = lerp(gold, picture, smoothstep(0.035, 0.045, rim))
            out[sel] = paper
        return out

    def _furniture(
        self, f: Furniture, p: torch.Tensor, normal: torch.Tensor, fp: torch.Tensor
    ) -> torch.Tensor:
        local = f.shape.to_local(p)
        n = len(p)
        if f.material == "books":
            return self._books(f, p, normal, fp)
        if f.material == "fabric":
            weave = self.room.detail.at(local[:, 0] + local[:, 2], local[:, 1], 8.0, 1)
            return self.fabric * (1 + 0.12 * weave * detail_fade(fp, 0.03))[:, None]
        if f.material == "wood":
            grain = self.room.detail.at(local[:, 0] / 8.0, local[:, 1] + local[:, 2], 5.0, 1)
            return rgb(0.45, 0.28, 0.15) * (1 + 0.15 * grain * detail_fade(fp, 0.03))[:, None]
        if f.material == "metal":
            return rgb(0.55, 0.56, 0.58).expand(n, 3)
        if f.material == "lamp":
            return rgb(1.0, 0.95, 0.82).expand(n, 3)
        if f.material == "shade":
            return rgb(0.98, 0.85, 0.6).expand(n, 3)
        if f.material == "pot":
            bands = pulse_coverage(local[:, 2], 0.1, 0.02, fp)
            return rgb(0.7, 0.35, 0.2) * (1 - 0.3 * bands)[:, None]
        if f.material == "leaves":
            leaf = self.room.detail.at(local[:, 0] + local[:, 2], local[:, 1] - local[:, 2], 3.0, 0)
            return lerp(rgb(0.1, 0.3, 0.08).expand(n, 3), rgb(0.3, 0.55, 0.15).expand(n, 3),
                        smoothstep(-1.0, 1.0, leaf * detail_fade(fp, 0.02)))  # fmt: skip
        if f.material == "ball":  # six coloured segments around its vertical axis
            sector = torch.floor(torch.atan2(local[:, 1], local[:, 0]) / (math.pi / 3))
            white = sector.remainder(2) > 0
            return torch.where(white[:, None], rgb(0.92, 0.92, 0.9).expand(n, 3), self.ball)
        raise ValueError(f"unknown material {f.material!r}")

    def _books(
        self, f: Furniture, p: torch.Tensor, normal: torch.Tensor, fp: torch.Tensor
    ) -> torch.Tensor:
        """A bookshelf: wood, and rows of book spines on its front."""
        assert f.wall is not None
        axis, sign = WALLS[f.wall]
        n_local = self.room.box.to_local(normal)
        front = (n_local[:, axis] * -sign) > 0.9
        wood = rgb(0.4, 0.26, 0.14).expand(len(p), 3).clone()
        s = self._along_wall(f.wall, p[front])
        z = p[front, 2] - (f.shape.centre[2] - f.shape.size[2])  # height above the shelf's foot
        fpf = fp[front]
        shelf = torch.floor(z / 0.36)
        in_shelf = z - shelf * 0.36
        lower, upper, share = cell_blend(s + 0.04 * 3.7 * self._hash(shelf), 0.04, fpf)

        def spine(book: torch.Tensor) -> torch.Tensor:
            index = (self._hash(book, shelf) * len(BOOK_COLOURS)).long().clamp(max=7)
            return BOOK_COLOURS[index]

        colour = torch.lerp(spine(lower), spine(upper), share[:, None])
        book = torch.where(share > 0.5, upper, lower)
        height = 0.22 + 0.1 * self._hash(book, shelf + 100)
        gaps = pulse_coverage(s + 0.04 * 3.7 * self._hash(shelf), 0.04, 0.004, fpf)
        spines = colour * (1 - 0.5 * gaps)[:, None]
        mean = BOOK_COLOURS.mean(0)
        spines = lerp(mean.expand_as(spines), spines, detail_fade(fpf, 0.08))
        board = in_shelf < 0.025
        above = in_shelf > 0.025 + height
        out = torch.where(above[:, None], rgb(0.08, 0.06, 0.05).expand_as(spines), spines)
        out = torch.where(board[:, None], rgb(0.4, 0.26, 0.14).expand_as(spines), out)
        wood[front] = out
        return wood

    def _outside(
        self, p: torch.Tensor, dist: torch.Tensor, normal: torch.Tensor, label: torch.Tensor,
        fp: torch.Tensor,
    ) -> torch.Tensor:  # fmt: skip
        """The plain, the buildings and the trees in sunlight."""
        n = len(p)
        detail = self.room.detail
        coarse = detail.at(p[:, 0], p[:, 1], 60.0, 0)
        fine = detail.at(p[:, 0], p[:, 1], 8.0, 1) * detail_fade(fp, 0.1)
        albedo = lerp(rgb(0.2, 0.33, 0.1).expand(n, 3), rgb(0.45, 0.45, 0.2).expand(n, 3),
                      smoothstep(-1.2, 1.5, coarse)) * (1 + 0.15 * fine)[:, None]  # fmt: skip
        for j, obj in enumerate(self.room.outside):
            sel = label == LABEL_OUTSIDE + j
            if not sel.any():
                continue
            if obj.kind == "sphere":
                leaf = detail.at(p[sel, 0] + p[sel, 2], p[sel, 1], 12.0, 1)
                albedo[sel] = (
                    rgb(*obj.colour) * (1 + 0.25 * leaf * detail_fade(fp[sel], 0.3))[:, None]
                )
                continue
            local = obj.to_local(p[sel])
            n_local = obj.to_local(normal[sel], direction=True)
            across = torch.where(n_local[:, 0].abs() > 0.5, local[:, 1], local[:, 0])
            height = local[:, 2] + obj.size[2]
            glass = pulse_coverage(height, 3.2, 1.5, fp[sel]) * pulse_coverage(
                across, 2.6, 1.3, fp[sel]
            )
            roof = n_local[:, 2] > 0.5
            glass = torch.where(roof, torch.zeros_like(glass), glass)
            albedo[sel] = lerp(rgb(*obj.colour).expand(int(sel.sum()), 3),
                               rgb(0.15, 0.2, 0.28).expand(int(sel.sum()), 3), glass)  # fmt: skip
        lit = lighting(normal, torch.ones(n), self.room.sun)
        return fog(albedo * lit, dist)

    # --- the screen --------------------------------------------------------------------------
    def screen(
        self, p: torch.Tensor, dist: torch.Tensor, normal: torch.Tensor
    ) -> Callable[[float], torch.Tensor]:
        """phase -> colour of screen points p (N, 3): a looping video inside a black bezel
        on the face towards the room, black plastic elsewhere."""
        del dist
        f = self.room.screen
        assert f.wall is not None
        axis, sign = WALLS[f.wall]
        n_local = self.room.box.to_local(normal)
        front = (n_local[:, axis] * -sign) > 0.9
        local = self.room.box.to_local(p - torch.tensor(f.shape.centre))
        half_w, half_h = f.shape.size[1 - axis], f.shape.size[2]
        u = (local[:, 1 - axis] + half_w) / (2 * half_w)
        v = (local[:, 2] + half_h) / (2 * half_h)
        bezel = 0.04 / (2 * half_w), 0.04 / (2 * half_h)
        picture = front & (u > bezel[0]) & (u < 1 - bezel[0]) & (v > bezel[1]) & (v < 1 - bezel[1])
        plastic = rgb(0.03, 0.03, 0.035)

        def at(phase: float) -> torch.Tensor:
            a = 2 * math.pi * phase
            red = 0.45 + 0.3 * torch.sin(2 * math.pi * 2 * u - a)
            green = 0.45 + 0.3 * torch.sin(2 * math.pi * (3 * v + u) - 2 * a + 1.0)
            blue = 0.5 + 0.3 * torch.sin(2 * math.pi * (u + 2 * v) + a + 2.0)
            frame = torch.stack([red, green, blue], -1)
            cu, cv = 0.5 + 0.28 * math.cos(a), 0.5 + 0.28 * math.sin(a)
            disc = 1 - smoothstep(0.1, 0.12, torch.hypot((u - cu) * half_w / half_h, v - cv))
            frame = lerp(frame, rgb(0.98, 0.97, 0.9).expand_as(frame), disc)
            return torch.where(picture[:, None], frame, plastic.expand_as(frame))

        return at
