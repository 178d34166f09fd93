"""A synthetic scene of any kind: the panorama, its depth and motion mask, the animation and
the ground-truth views, rendered from one seed (``make_scene``)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import torch

from pano4d.progress import Task
from pano4d.synth.landscape import Landscape
from pano4d.synth.room import Room
from pano4d.synth.views import SynthView, make_views, render_panorama
from pano4d.synth.world import Hits, World

# The scene kinds make_scene can build: a constructor (seed, frames[, camera_height]) each,
# whose camera_height defaults to the kind's own.
SCENE_KINDS: dict[str, Callable[..., World]] = {"landscape": Landscape, "room": Room}


class SynthFrames:
    """The L animation frames, rendered on access: the static part is the panorama's,
    only the moving pixels are shaded again. Indexing gives one (H, W, 3) float32 tensor;
    ``to_tensor()`` stacks all of them (L·H·W·3 floats: 1.4 GB at 4096×2048×14)."""

    def __init__(
        self, world: World, panorama: torch.Tensor, moving: torch.Tensor,
        dirs: torch.Tensor, hits: Hits,
    ) -> None:  # fmt: skip
        self._world = world
        self._panorama = panorama
        self._moving = moving  # flat indices of the moving pixels
        self._shade_moving = world.moving_shader(torch.zeros(3), dirs, hits)

    def __len__(self) -> int:
        return self._world.frames

    @property
    def shape(self) -> tuple[int, int, int, int]:
        return (len(self), *self._panorama.shape)

    def __getitem__(self, time: int) -> torch.Tensor:
        if not -len(self) <= time < len(self):
            raise IndexError(f"frame {time} out of range for {len(self)} frames")
        time %= len(self)
        if time == 0:
            return self._panorama.clone()
        frame = self._panorama.clone()
        frame.view(-1, 3)[self._moving] = self._shade_moving(time)
        return frame

    def __iter__(self) -> Iterator[torch.Tensor]:
        return (self[t] for t in range(len(self)))

    def to_tensor(self) -> torch.Tensor:
        return torch.stack(list(self))


@dataclass
class SynthScene:
    """A synthetic panorama with its exact ground truth."""

    panorama: torch.Tensor  # (H, W, 3) float32 in [0, 1], frame 0
    depth: torch.Tensor  # (H, W) float32 ray length; the sky at SKY_DEPTH
    mask: torch.Tensor  # (H, W) bool, True where pixels move (World.moves)
    frames: SynthFrames  # L frames (H, W, 3), frame 0 equals the panorama
    views: list[SynthView]
    labels: torch.Tensor  # (H, W) uint8: what each pixel hit (LABEL_SKY or the kind's labels)
    kind: str  # its key in SCENE_KINDS
    world: World = field(repr=False)

    @property
    def seed(self) -> int:
        return self.world.seed


def make_scene(
    seed: int,
    width: int,
    height: int,
    frames: int,
    *,
    views: int = 8,
    view_size: int = 256,
    camera_height: float | None = None,
    kind: str = "landscape",
    progress: Task | None = None,
) -> SynthScene:
    """Render the synthetic scene of ``seed``: panorama, depth, mask, frames and views.

    Deterministic: the same arguments give bit-identical tensors. The frames are rendered
    lazily (see ``SynthFrames``). ``kind`` names the world in SCENE_KINDS; ``camera_height``
    (metres above the ground or floor) defaults to the kind's own. ``progress``
    advances one step per stage, saying what was done.
    """
    if views < 0 or view_size < 1:
        raise ValueError(f"need views >= 0 and view_size >= 1, got {views} and {view_size}")
    report = (progress or Task()).advance
    if kind not in SCENE_KINDS:
        raise ValueError(f"unknown scene kind {kind!r}; known: {', '.join(SCENE_KINDS)}")
    build = SCENE_KINDS[kind]
    world = build(seed, frames) if camera_height is None else build(seed, frames, camera_height)
    report(f"built the {kind}")
    panorama, depth, labels, hits, dirs = render_panorama(world, width, height)
    report("rendered the panorama")
    mask = world.moves(labels)
    moving = mask.view(-1).nonzero()[:, 0]
    animation = SynthFrames(world, panorama, moving, dirs[moving], hits.subset(moving))
    view_list = make_views(world, views, view_size)
    report("rendered the views")
    return SynthScene(panorama, depth, mask, animation, view_list, labels, kind, world)
