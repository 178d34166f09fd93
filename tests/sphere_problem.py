"""The small training problem the trainer tests share: Gaussians on a sphere of radius 4
around the camera, and four 90° views of a gradient-coloured panorama to fit."""

from __future__ import annotations

import torch

from pano4d.gaussians import Gaussians
from pano4d.lift.initial import init_gaussians, init_sphere
from pano4d.lift.trainer import TrainViews
from pano4d.resample import equirect_to_perspective
from pano4d.sphere import view_layout

RADIUS = 4.0


def sphere_problem(view_size: int, sh_degree: int) -> tuple[Gaussians, TrainViews]:
    """Facing discs at the icosphere's points (dimmed to a fifth of the target's colours, so
    the optimiser has something to do) and ``view_size``² views with every pixel supervised."""
    cams = view_layout(4, 90.0, view_size)
    ico = init_sphere(96, 3)
    depth = torch.full((24, 48), RADIUS)
    v = torch.linspace(0, 1, 24)[:, None, None]
    u = torch.linspace(0, 1, 48)[None, :, None]
    frame = torch.cat([v.expand(24, 48, 1), u.expand(24, 48, 1), (1 - v).expand(24, 48, 1)], -1)
    g = init_gaussians(ico.points, ico.spacing_rad, depth, frame * 0.2, sh_degree)
    image = frame.permute(2, 0, 1)
    targets = torch.stack([equirect_to_perspective(image, c).permute(1, 2, 0) for c in cams])
    size = (4, view_size, view_size)
    return g, TrainViews(cams, targets, torch.ones(size), torch.full(size, RADIUS))
