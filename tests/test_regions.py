"""Moving regions grow the same way in both phases, across the 0°/360° seam and over a pole."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from pano4d.camera import Camera
from pano4d.config import validate_config
from pano4d.images import write_image
from pano4d.lift.pipeline import moving_region
from pano4d.regions import MARGIN_DEG, active_views, grow, moving_mask
from pano4d.sphere import equirect_to_dir

WIDTH, HEIGHT = 256, 128
# The margin is 2…3 equator pixels here: a pixel two rows or columns away is inside it,
# three are outside.
SEAM_BOX = [250, 60, 6, 68]  # u0 > u1: columns 250…255 and 0…5
POLE_BOX = [60, 0, 80, 4]  # rows 0…3 at the zenith, columns 60…79


def _looking_at(row: int, col: int) -> Camera:
    """A 1° camera at the origin looking at the centre of pixel (row, col)."""
    u, v = torch.tensor([col + 0.5], dtype=torch.float64), torch.tensor([row + 0.5])
    direction = equirect_to_dir(u, v.double(), WIDTH, HEIGHT)[0]
    return Camera.from_fov(1.0, 8, 8, forward=direction)


def test_seam_and_pole_regions_grow_the_same_in_both_phases(tmp_path: Path) -> None:
    write_image(tmp_path / "pano.png", np.zeros((HEIGHT, WIDTH, 3), np.float32))
    regions = [{"box": SEAM_BOX}, {"box": POLE_BOX}]
    cfg = validate_config({"panorama": "pano.png", "regions": regions}, tmp_path)
    mask = moving_mask(cfg, WIDTH, HEIGHT)
    grown = grow(mask)
    assert 2 <= MARGIN_DEG * WIDTH / 360 < 3

    # Across the seam: two columns beyond either edge, not three.
    assert grown[64, 6:8].all() and grown[64, 248:250].all()
    assert not grown[64, 8] and not grown[64, 247]
    # Over the pole: the top rows half a turn round (columns 188…207) join through the
    # zenith; the third row there is three rows from the region and does not.
    assert grown[0].all() and grown[1, 188:208].all() and not grown[2, 188:208].any()

    # Lifting phase: on a video where nothing else changes, its moving region is that.
    still = torch.zeros(3, HEIGHT, WIDTH, 3)
    assert torch.equal(moving_region(cfg, still, (WIDTH, HEIGHT)), grown)

    # Animating phase: it denoises the views that see the grown region, and only those.
    inside = [(1, 197), (64, 7), (64, 248)]  # over the pole, beyond either side of the seam
    outside = [(2, 197), (64, 8), (64, 247), (64, 128)]
    cameras = [_looking_at(r, c) for r, c in inside + outside]
    assert active_views(cameras, mask) == list(range(len(inside)))
