"""What a scene kind provides: an analytic world that rays are cast into and shaded.

``make_scene`` renders every kind the same way (``views``: the panorama from the origin and
displaced ground-truth views; ``scene.SynthFrames``: the animation, shading again only the
pixels that move) and ``write_scene`` writes the same files for each. The kinds:
``Landscape`` (a meadow, a lake, hills, objects and clouds; ``landscape``) and ``Room`` (a
furnished room with a window onto a far exterior and a playing screen; ``room``); another is
a class with the ``World`` interface, registered in ``pano4d.synth.scene.SCENE_KINDS``.

Shared conventions: the world frame of docs/design.md (+z up, the panorama's camera at the
origin, the ground or floor at z = −camera_height); label 0 (``LABEL_SKY``) is a sky sphere
of radius ``SKY_DEPTH`` around the origin, so every ray has a finite depth; geometry never
moves (depth is the same in every frame), and what changes colour is periodic in the time
index with period ``frames``, so the animation loops.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import torch

SKY_DEPTH = 1000.0  # the sky is a sphere of this radius around the origin (finite far depth)
LABEL_SKY = 0  # what a ray that hits nothing else hits; kinds number their own labels from 1


@dataclass
class Hits:
    """What rays from one origin hit: ray length, label and surface normal per ray."""

    depth: torch.Tensor  # (N,) float32
    label: torch.Tensor  # (N,) uint8
    normal: torch.Tensor  # (N, 3) float32, geometric (water's waves are added when shading)

    def subset(self, index: torch.Tensor) -> Hits:
        return Hits(self.depth[index], self.label[index], self.normal[index])


@dataclass(frozen=True)
class MotionHint:
    """The motion hint scene.yaml gives the moving region: what the animator should do."""

    direction_deg: float  # in the image: 0 = towards +u, 90 = towards the zenith
    speed: float  # degrees of arc per frame
    what: str  # what moves that way, for the comment in scene.yaml


class World(Protocol):
    """A scene kind of one seed. ``frames`` is the loop period L."""

    seed: int
    frames: int
    camera_height: float  # the panorama's camera above the ground (depth.camera_height)
    sun: torch.Tensor  # (3,) unit direction towards the sun
    moving_parts: str  # what the motion mask covers, for the comment in scene.yaml

    def cast(self, origin: Sequence[float] | torch.Tensor, dirs: torch.Tensor) -> Hits:
        """Intersect rays from one ``origin`` (3,) along unit ``dirs`` (N, 3) with the world."""
        ...

    def shade(self, o: torch.Tensor, d: torch.Tensor, hits: Hits, time: float) -> torch.Tensor:
        """Colour (N, 3) in [0, 1] of every ray at time ``time`` (frames, real-valued)."""
        ...

    def moving_shader(
        self, o: torch.Tensor, d: torch.Tensor, hits: Hits
    ) -> Callable[[float], torch.Tensor]:
        """time -> colour (N, 3) of rays that hit what moves (see ``moves``)."""
        ...

    def moves(self, label: torch.Tensor) -> torch.Tensor:
        """Which labels change over time (bool, the shape of ``label``)."""
        ...

    def surface_residual(self, points: torch.Tensor, label: torch.Tensor) -> torch.Tensor:
        """Signed distance-like residual (N,) of world points (N, 3) to the surface named by
        ``label`` (N,): zero, to float precision, for a point on it (the exact-depth check)."""
        ...

    def motion_hint(self) -> MotionHint: ...

    def metadata(self) -> dict[str, Any]:
        """What gt/views.json records about the world (JSON types): ``world_metadata``."""
        ...


def world_metadata(world: World, **own: Any) -> dict[str, Any]:
    """A kind's ``metadata``: what every world records, then the kind's ``own`` keys."""
    return {
        "seed": world.seed,
        "frames": world.frames,
        "camera_height": world.camera_height,
        "sky_depth": SKY_DEPTH,
        "sun_direction": world.sun.tolist(),
        **own,
    }


def shade_split(
    world: World,
    static: Callable[[torch.Tensor, torch.Tensor, Hits], torch.Tensor],
    o: torch.Tensor,
    d: torch.Tensor,
    hits: Hits,
    time: float,
) -> torch.Tensor:
    """``World.shade`` of every kind: rays that hit what does not move coloured by
    ``static(o, d, hits)``, the others by ``world.moving_shader`` at ``time``."""
    o = torch.as_tensor(o, dtype=torch.float32).reshape(3)
    rgb = torch.empty(d.shape[0], 3)
    moving = world.moves(hits.label)
    still = (~moving).nonzero()[:, 0]
    rgb[still] = static(o, d[still], hits.subset(still))
    dyn = moving.nonzero()[:, 0]
    rgb[dyn] = world.moving_shader(o, d[dyn], hits.subset(dyn))(time)
    return rgb
