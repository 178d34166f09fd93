"""Initial Gaussians from the aligned depth, and the static/dynamic split.

One Gaussian per icosphere sample (near-uniform on the sphere, unlike equirect pixels that
crowd at the poles) at the aligned ray length along its direction, coloured from the frame,
a flat disc facing the panorama's centre whose radius is the sample's footprint at that
depth. A sample whose direction falls in the dilated moving mask belongs to the dynamic set;
the rest form the static set, optimised once and shared by every timestamp. A later
timestamp starts from the set the timestamp before it fitted, its colours moved by how much
the frame changed where each Gaussian looks (``follow_frame_change``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from pano4d.gaussians import SH_C0, Gaussians, rgb_to_sh_dc, sh_coeffs_for_degree
from pano4d.resample import equirect_sampler
from pano4d.spacetime import SpacetimeGaussians, TimeModel
from pano4d.sphere import Icosphere, dir_to_equirect, icosphere, icosphere_frequency_for_spacing

INITIAL_OPACITY = 0.9
FOOTPRINT_FACTOR = 0.7  # tangent σ as a fraction of the sample spacing at its depth
THICKNESS = 0.1  # radial σ as a fraction of the tangent σ


def init_sphere(width: int, init_stride: int) -> Icosphere:
    """Icosphere whose spacing is ``init_stride`` pixels of a ``width``-wide panorama's equator."""
    if init_stride < 1:
        raise ValueError(f"init_stride must be ≥ 1, got {init_stride}")
    return icosphere(icosphere_frequency_for_spacing(init_stride * 2 * math.pi / width))


def points_in_mask(points: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(N,) bool: whether each unit direction (N, 3) lands on a True pixel of ``mask`` (H, W)."""
    height, width = mask.shape
    u, v = dir_to_equirect(points.to(torch.float64), width, height)
    col = u.floor().long().clamp(0, width - 1)
    row = v.floor().long().clamp(0, height - 1)
    return mask.to(points.device)[row, col]


def _quaternion_from_matrix(m: torch.Tensor) -> torch.Tensor:
    """(N, 3, 3) rotation matrices → (N, 4) quaternions (w, x, y, z), robust on every branch."""
    w = torch.sqrt((1 + m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]).clamp(min=0)) / 2
    x = torch.sqrt((1 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2]).clamp(min=0)) / 2
    y = torch.sqrt((1 - m[:, 0, 0] + m[:, 1, 1] - m[:, 2, 2]).clamp(min=0)) / 2
    z = torch.sqrt((1 - m[:, 0, 0] - m[:, 1, 1] + m[:, 2, 2]).clamp(min=0)) / 2
    x = torch.copysign(x, m[:, 2, 1] - m[:, 1, 2])
    y = torch.copysign(y, m[:, 0, 2] - m[:, 2, 0])
    z = torch.copysign(z, m[:, 1, 0] - m[:, 0, 1])
    q = torch.stack([w, x, y, z], dim=-1)
    return q / torch.linalg.norm(q, dim=-1, keepdim=True)


def facing_rotations(dirs: torch.Tensor) -> torch.Tensor:
    """Quaternions whose local z axis is the direction (N, 3) (discs face the origin)."""
    d = dirs / torch.linalg.norm(dirs, dim=-1, keepdim=True)
    helper = torch.where(
        d[:, 2:3].abs() < 0.9,
        torch.tensor([0.0, 0.0, 1.0], dtype=d.dtype).expand_as(d),
        torch.tensor([1.0, 0.0, 0.0], dtype=d.dtype).expand_as(d),
    )
    t1 = torch.linalg.cross(helper, d)
    t1 = t1 / torch.linalg.norm(t1, dim=-1, keepdim=True)
    t2 = torch.linalg.cross(d, t1)
    return _quaternion_from_matrix(torch.stack([t1, t2, d], dim=-1))


def init_gaussians(
    points: torch.Tensor,
    spacing_rad: float,
    depth: torch.Tensor,
    frame: torch.Tensor,
    sh_degree: int = 0,
) -> Gaussians:
    """Gaussians at directions ``points`` (N, 3) placed at the equirect ray length ``depth``
    (H, W) and coloured from ``frame`` (H, W, 3). Float32, on ``depth``'s device."""
    height, width = depth.shape
    device = depth.device
    dirs = points.to(torch.float64)
    sampler = equirect_sampler(dirs, width, height).to(device)
    radius = sampler.apply(depth.clamp(min=1e-3).log()).exp()
    colour = sampler.apply(frame.permute(2, 0, 1).to(torch.float32)).T.clamp(0, 1)
    means = (dirs.to(device) * radius[:, None].to(torch.float64)).to(torch.float32)
    tangent = FOOTPRINT_FACTOR * spacing_rad * radius
    log_scales = torch.stack(
        [tangent.log(), tangent.log(), (THICKNESS * tangent).log()], dim=-1
    ).to(torch.float32)
    quats = facing_rotations(dirs).to(device, torch.float32)
    opacity = torch.full((len(points),), math.log(INITIAL_OPACITY / (1 - INITIAL_OPACITY)))
    sh = torch.zeros(len(points), sh_coeffs_for_degree(sh_degree), 3, device=device)
    sh[:, 0] = rgb_to_sh_dc(colour)
    return Gaussians(means, log_scales, quats, opacity.to(device), sh)


def follow_frame_change(
    gaussians: Gaussians, before: torch.Tensor, after: torch.Tensor
) -> Gaussians:
    """Where a later timestamp starts: the set fitted to frame ``before`` with each
    Gaussian's base colour moved by how much the frame changed where it looks (``after`` −
    ``before``, (H, W, 3) frames, sampled bilinearly at the Gaussian's direction as its
    initial colour was); pixels that did not change leave their Gaussians as they are.

    Why: the animated part of a panorama mostly changes colour in place (water, a screen,
    drifting clouds) and Adam moves a colour by about its learning rate a step (0.3 % of the
    range at lr_color = 10⁻²), so a timestamp that starts from the previous colours spends
    its steps walking them to the new frame (bench/RESULTS.md, "how many steps a later
    timestamp needs")."""
    height, width = before.shape[:2]
    look = equirect_sampler(gaussians.means.detach().cpu().to(torch.float64), width, height)
    change = look.to(before.device).apply((after - before).permute(2, 0, 1).float()).T
    sh = gaussians.sh.clone()
    sh[:, 0] += (change / SH_C0).to(sh.device, sh.dtype)
    return replace(gaussians, sh=sh)


def spacetime_start(
    gaussians: Gaussians, frames: torch.Tensor, model: TimeModel
) -> SpacetimeGaussians:
    """Where the spacetime stage starts: ``gaussians`` (frame 0's, at its depth) present
    throughout, each one's SH DC and colour terms the Fourier series of the colour its
    direction sees in every frame (``frames``: (L, H, W, 3), L = ``model.period``).

    Why: what moves in these panoramas mostly changes colour in place (water, a screen,
    drifting clouds), so the series of each direction's colours is most of the answer, and
    its lowest Fourier terms are the closest a Gaussian with ``model.colour_harmonics``
    terms can start to it (least squares over the frames, which the discrete transform is
    for evenly spaced samples of one period)."""
    count, height, width = frames.shape[:3]
    if count != model.period:
        raise ValueError(f"{count} frames for a loop of {model.period}")
    look = equirect_sampler(gaussians.means.detach().cpu().to(torch.float64), width, height)
    look = look.to(frames.device)
    series = torch.stack([look.apply(f.permute(2, 0, 1).float()).T for f in frames])  # (L, N, 3)
    dc, terms = model.fitted(rgb_to_sh_dc(series.clamp(0, 1)), model.colour_harmonics)
    sh = gaussians.sh.clone()
    sh[:, 0] = dc.to(sh.device, sh.dtype)
    start = SpacetimeGaussians.still(model, replace(gaussians, sh=sh))
    start.colour_terms.copy_(terms.to(start.colour_terms))
    return start
