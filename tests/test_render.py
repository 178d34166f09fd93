"""The wgpu rasteriser against the pure-torch reference (values, gradients and footprints),
the reference against finite differences, extreme inputs, and a real 3DGS scene."""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from pano4d.camera import Camera
from pano4d.gaussians import Gaussians
from pano4d.renderer import adapter_info, footprints, render

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
TOL = 1e-4


def random_scene(
    n: int, seed: int, centre: tuple[float, float, float] = (4.0, 0.0, 0.0),
    spread: float = 1.5, sh_degree: int = 1, log_scale: tuple[float, float] = (-3.0, -1.0),
) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)

    def rand(*shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=gen)

    k = (sh_degree + 1) ** 2
    return Gaussians(
        means=torch.tensor(centre) + spread * (2 * rand(n, 3) - 1),
        log_scales=log_scale[0] + (log_scale[1] - log_scale[0]) * rand(n, 3),
        quats=2 * rand(n, 4) - 1,
        opacity_logits=4 * rand(n) - 2,
        sh=0.6 * (2 * rand(n, k, 3) - 1),
    )


def camera(width: int, height: int, position=(0.0, 0.0, 0.0), forward=(1.0, 0.0, 0.0)) -> Camera:
    return Camera.from_fov(70.0, width, height, position, forward)


def both(g: Gaussians, cam: Camera, **kw) -> tuple:
    with torch.no_grad():
        return render(g, cam, backend="wgpu", **kw), render(g, cam, backend="torch", **kw)


def assert_outputs_close(a, b, tol: float = TOL) -> None:
    assert torch.isfinite(a.rgb).all() and torch.isfinite(a.depth).all()
    assert (a.rgb - b.rgb).abs().max() <= tol
    assert (a.alpha - b.alpha).abs().max() <= tol
    # Accumulated depth Σ z·α·T, scaled by the scene's depth range.
    scale = max(1.0, float(b.depth.abs().max()))
    assert (a.depth * a.alpha - b.depth * b.alpha).abs().max() <= tol * scale


@pytest.mark.parametrize("size", [(1, 1), (17, 13), (64, 64), (256, 256)])
@pytest.mark.parametrize("inside", [False, True])
def test_forward_matches_reference(size: tuple[int, int], inside: bool) -> None:
    w, h = size
    if inside:
        # The camera sits inside the cloud: Gaussians all around, some behind it.
        g = random_scene(400, seed=w + h, centre=(0.0, 0.0, 0.0), spread=3.0)
    else:
        g = random_scene(400, seed=w * h + 1)
    cam = camera(w, h)
    bg = torch.tensor([0.1, 0.2, 0.3])
    for antialiased in (False, True):
        a, b = both(g, cam, background=bg, antialiased=antialiased)
        assert a.rgb.shape == (h, w, 3) and a.alpha.shape == (h, w) and a.depth.shape == (h, w)
        assert a.rgb.dtype == torch.float32
        assert_outputs_close(a, b)
    assert float(a.alpha.max()) > 0.1  # the scene is actually in view


def test_sh_degrees_and_off_centre_principal_point() -> None:
    for degree in range(4):
        g = random_scene(150, seed=degree, sh_degree=degree)
        cam = camera(40, 30)
        cam.K[0, 2] += 5.5
        cam.K[1, 2] -= 3.25
        a, b = both(g, cam)
        assert_outputs_close(a, b)


# --- closed forms -----------------------------------------------------------------------
# Both backends follow one written spec, so a convention error shared by both (quaternion
# order, R against its transpose, the antialiasing factor) would pass their comparison.
# These footprints are derived by hand instead. The camera sits at the origin looking
# along +x with +z up: image x (right) is world -y, image y (down) is world -z. On the
# optical axis the EWA Jacobian is diag(f/z, f/z), so a Gaussian's image covariance is
# (f/z)² times the (y, z) block of its world covariance, plus the mode's screen-space filter
# (classic 0.3 px², antialiased 0.1 px², written out here, not imported). An odd
# image size puts the axis on a pixel centre, where the footprint peaks.
CLOSED_FORM_SIZE = (63, 47)


def closed_form_camera() -> Camera:
    return Camera.from_fov(70.0, *CLOSED_FORM_SIZE)


def footprint(mean2d: tuple[float, float], cov: torch.Tensor, opacity: float,
              antialiased: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """Per pixel (H, W): alpha of a footprint of image covariance ``cov`` (before the
    low-pass) and its power, by the spec's rules (3σ and 1/255 cuts, 0.999 clamp)."""
    w, h = CLOSED_FORM_SIZE
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float64) + 0.5,
                            torch.arange(w, dtype=torch.float64) + 0.5, indexing="ij")
    d = torch.stack([xs - mean2d[0], ys - mean2d[1]], dim=-1)
    blurred = cov + (0.1 if antialiased else 0.3) * torch.eye(2, dtype=torch.float64)
    power = -0.5 * torch.einsum("...i,ij,...j->...", d, torch.linalg.inv(blurred), d)
    if antialiased:
        opacity *= math.sqrt(float(torch.linalg.det(cov) / torch.linalg.det(blurred)))
    alpha = torch.clamp(opacity * torch.exp(power), max=0.999)
    alpha = torch.where((power >= -4.5) & (alpha >= 1 / 255), alpha, torch.zeros_like(alpha))
    return alpha, power


def near_a_cut(alpha: torch.Tensor, power: torch.Tensor, opacity: float) -> torch.Tensor:
    """Pixels whose cut could go either way by float32 rounding (left out of checks)."""
    raw = opacity * torch.exp(power)
    return ((power + 4.5).abs() < 1e-4) | ((raw - 1 / 255).abs() < 1e-5)


def rotation(axis: str, degrees: float) -> tuple[tuple[float, float, float, float], torch.Tensor]:
    """A quaternion (w, x, y, z) about a world axis and the rotation matrix it stands for,
    written out by hand for that axis."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    half = (math.cos(a / 2), math.sin(a / 2))
    quat, matrix = {
        "x": ((half[0], half[1], 0.0, 0.0), [[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": ((half[0], 0.0, half[1], 0.0), [[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": ((half[0], 0.0, 0.0, half[1]), [[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]
    return quat, torch.tensor(matrix, dtype=torch.float64)


@pytest.mark.parametrize("antialiased", [False, True])
@pytest.mark.parametrize("axis", ["x", "y", "z"])
@pytest.mark.parametrize("backend", ["wgpu", "torch"])
def test_rotated_anisotropic_gaussian_renders_its_closed_form_footprint(
        backend: str, axis: str, antialiased: bool) -> None:
    # Turned about the viewing axis (x): its image axes turn by the same angle, towards +y
    # (down) for a positive turn; about up (z) or the camera's right (y): one image axis
    # mixes two world scales. Each quaternion component is exercised.
    z, opacity, dc = 4.0, 0.85, (0.8, -0.3, 0.1)
    log_scale = (-1.9, -1.0, -1.6)
    quat, rot = rotation(axis, {"x": 35.0, "y": 25.0, "z": 50.0}[axis])
    g = Gaussians(
        means=torch.tensor([[z, 0.0, 0.0]]), log_scales=torch.tensor([log_scale]),
        quats=torch.tensor([quat]),
        opacity_logits=torch.tensor([math.log(opacity / (1 - opacity))]),
        sh=torch.tensor([[dc]]),
    )
    cam = closed_form_camera()
    f = float(cam.K[0, 0])
    world = rot @ torch.diag(torch.tensor(log_scale, dtype=torch.float64).exp() ** 2) @ rot.T
    # Image (x, y) = world (-y, -z): the (y, z) block, both signs flipped (which cancel).
    cov = (f / z) ** 2 * world[1:, 1:]
    centre = (float(cam.K[0, 2]), float(cam.K[1, 2]))
    alpha, power = footprint(centre, cov, opacity, antialiased)
    bg = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)
    with torch.no_grad():
        out = render(g, cam, background=bg.float(), backend=backend, antialiased=antialiased)
    check = ~near_a_cut(alpha, power, opacity)
    assert check.sum() > 0.95 * check.numel()
    assert (out.alpha.double() - alpha)[check].abs().max() <= 1e-5
    colour = 0.5 + 0.28209479177387814 * torch.tensor(dc, dtype=torch.float64)
    want_rgb = alpha[..., None] * colour + (1 - alpha[..., None]) * bg
    assert (out.rgb.double() - want_rgb)[check].abs().max() <= 1e-5
    drawn = check & (alpha > 0.01)
    assert (out.depth.double() - z)[drawn].abs().max() <= 1e-4
    # Every pixel within 1e-5 pins the footprint's axes and extents to the closed form's
    # (a turn the other way, or a swapped quaternion, moves the long axis by 50–100°). The
    # peak is on the axis' pixel, at the (antialiased) opacity.
    peak = (int(centre[1]), int(centre[0]))
    assert float(out.alpha[peak]) == float(out.alpha.max())
    assert abs(float(out.alpha[peak]) - float(alpha.max())) <= 1e-5


@pytest.mark.parametrize("front_first", [True, False])
@pytest.mark.parametrize("backend", ["wgpu", "torch"])
def test_two_overlapping_gaussians_composite_in_closed_form(backend: str,
                                                            front_first: bool) -> None:
    # Two isotropic Gaussians off the axis at camera (x, y, z): the Jacobian
    # (f/z)[[1, 0, -x/z], [0, 1, -y/z]] makes their image covariance
    # s² (f/z)² [[1 + u², uv], [uv, 1 + v²]] with u = x/z, v = y/z, centred at
    # (f u + cx, f v + cy). Front to back: C = c1 a1 + c2 a2 (1 - a1) + bg (1 - a1)(1 - a2),
    # alpha = 1 - (1 - a1)(1 - a2), D = z1 a1 + z2 a2 (1 - a1), whatever the input order.
    front = {"world": (4.0, 0.3, -0.1), "log_scale": -1.2, "opacity": 0.7, "dc": (0.9, -0.5, -0.4)}
    back = {"world": (6.0, -0.2, 0.15), "log_scale": -0.8, "opacity": 0.8, "dc": (-0.6, 0.1, 0.9)}
    pair = [front, back] if front_first else [back, front]
    g = Gaussians(
        means=torch.tensor([p["world"] for p in pair]),
        log_scales=torch.tensor([[p["log_scale"]] * 3 for p in pair]),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2),
        opacity_logits=torch.tensor([math.log(p["opacity"] / (1 - p["opacity"])) for p in pair]),
        sh=torch.tensor([[p["dc"]] for p in pair]),
    )
    cam = closed_form_camera()
    f, cx, cy = float(cam.K[0, 0]), float(cam.K[0, 2]), float(cam.K[1, 2])
    layers = []
    for p in (front, back):
        wx, wy, wz = p["world"]
        x, y, z = -wy, -wz, wx
        u, v = x / z, y / z
        cov = math.exp(2 * p["log_scale"]) * (f / z) ** 2 * torch.tensor(
            [[1 + u * u, u * v], [u * v, 1 + v * v]], dtype=torch.float64)
        alpha, power = footprint((f * u + cx, f * v + cy), cov, p["opacity"], False)
        colour = 0.5 + 0.28209479177387814 * torch.tensor(p["dc"], dtype=torch.float64)
        layers.append((alpha, power, colour.clamp(min=0), z, p["opacity"]))
    (a1, p1, c1, z1, o1), (a2, p2, c2, z2, o2) = layers
    bg = torch.tensor([0.2, 0.1, 0.3], dtype=torch.float64)
    want_alpha = 1 - (1 - a1) * (1 - a2)
    want_rgb = (c1 * a1[..., None] + c2 * (a2 * (1 - a1))[..., None]
                + bg * ((1 - a1) * (1 - a2))[..., None])
    want_accum_depth = z1 * a1 + z2 * a2 * (1 - a1)
    with torch.no_grad():
        out = render(g, cam, background=bg.float(), backend=backend)
    check = ~(near_a_cut(a1, p1, o1) | near_a_cut(a2, p2, o2))
    both_drawn = check & (a1 > 0.05) & (a2 > 0.05)
    assert both_drawn.sum() > 50, "the two footprints overlap"
    assert (out.alpha.double() - want_alpha)[check].abs().max() <= 1e-5
    assert (out.rgb.double() - want_rgb)[check].abs().max() <= 1e-5
    got_accum_depth = out.depth.double() * out.alpha.double()
    assert (got_accum_depth - want_accum_depth)[check].abs().max() <= 1e-4


def weighted_loss(out, weights: list[torch.Tensor]) -> torch.Tensor:
    accum_depth = out.depth * out.alpha
    return (
        (out.rgb * weights[0]).sum() + (out.alpha * weights[1]).sum()
        + (accum_depth * weights[2]).sum()
    )


def gradients(g: Gaussians, cam: Camera, backend: str, weights, **kw) -> dict[str, torch.Tensor]:
    g = g.map(lambda t: t.clone().requires_grad_(True))
    weighted_loss(render(g, cam, backend=backend, **kw), weights).backward()
    return {k: v.grad for k, v in g.tensors().items()}


# A float32 rasteriser cannot match the float64 reference more closely than a float32
# evaluation of the same maths does. Each gradient check measures that: the torch backend
# in float32 against itself in float64, per Gaussian, and allows the wgpu gradients
# GRADIENT_SLACK times the worst of those errors (different operation orders round
# differently; at 256² the two are within 2x of each other). An error is relative to the
# Gaussian's own gradient, or to RELATIVE_FLOOR of the largest Gaussian's where its own is
# smaller (whose gradient nearly cancels over its pixels).
GRADIENT_SLACK = 8.0
RELATIVE_FLOOR = 1e-3


def per_gaussian_errors(got: dict[str, torch.Tensor],
                        ref: dict[str, torch.Tensor]) -> dict[str, tuple[float, int]]:
    """Per parameter: the worst Gaussian's relative error and its index."""
    worst = {}
    for name, r in ref.items():
        r = r.double().reshape(r.shape[0], -1)
        g = got[name].double().reshape(r.shape)
        norms = torch.linalg.norm(r, dim=1)
        floor = RELATIVE_FLOOR * float(norms.max()) if len(norms) else 0.0
        if floor == 0.0:
            # No gradient at all in the reference: only exact zeros match it.
            size = g.abs().sum(dim=1)
            worst[name] = (math.inf if bool((size > 0).any()) else 0.0,
                           int(size.argmax()) if len(size) else 0)
            continue
        err = torch.linalg.norm(g - r, dim=1) / torch.clamp(norms, min=floor)
        worst[name] = (float(err.max()), int(err.argmax()))
    return worst


Grads = dict[str, torch.Tensor]


def references(g: Gaussians, cam: Camera, weights, **kw) -> tuple[Grads, Grads]:
    """The torch reference's gradients in float64 and in float32."""
    return (gradients(g.to(torch.float64), cam, "torch", weights, **kw),
            gradients(g, cam, "torch", weights, **kw))


def assert_as_accurate_as_float32(got: Grads, refs: tuple[Grads, Grads], what: str) -> None:
    """Checks wgpu gradients ``got`` per Gaussian against the float64 reference."""
    ref, ref32 = refs
    f32 = per_gaussian_errors(ref32, ref)
    for name, (err, i) in per_gaussian_errors(got, ref).items():
        allowed = GRADIENT_SLACK * f32[name][0] + 1e-6
        assert err <= allowed, (
            f"{what}, {name}: Gaussian {i} off by {err:.2e} of its gradient (a float32 "
            f"reference is off by {f32[name][0]:.2e} at worst): {got[name][i].tolist()} vs "
            f"{ref[name][i].tolist()}"
        )
    # Zeros by construction (clamps, culling: exact in both the reference's precisions)
    # stay exact.
    for name, r in ref.items():
        zero = (r == 0) & (ref32[name] == 0)
        assert (got[name][zero] == 0).all(), f"{what}, {name}: nonzero where the reference is 0"


@pytest.mark.parametrize("antialiased", [False, True])
@pytest.mark.parametrize("inside", [False, True])
def test_gradients_match_reference_per_gaussian(antialiased: bool, inside: bool) -> None:
    if inside:
        # Gaussians all around the camera: Jacobian clamps, culling behind, termination.
        g = random_scene(200, seed=17, sh_degree=3, centre=(0.0, 0.0, 0.0), spread=3.0,
                         log_scale=(-2.0, -0.5))
    else:
        g = random_scene(60, seed=7, sh_degree=3, log_scale=(-2.5, -1.0))
    cam = camera(32, 24)
    weights = loss_weights(32, 24, seed=3)
    kw = {"background": torch.tensor([0.3, 0.5, 0.2]), "antialiased": antialiased}
    got = gradients(g, cam, "wgpu", weights, **kw)
    assert all(torch.linalg.norm(v) > 0 for v in got.values())
    assert_as_accurate_as_float32(got, references(g, cam, weights, **kw), "32x24")


def loss_weights(width: int, height: int, seed: int) -> list[torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return [torch.rand(height, width, 3, generator=gen), torch.rand(height, width, generator=gen),
            0.1 * torch.rand(height, width, generator=gen)]


# The backward's paths, chosen when the renderer is created (once per process): tile sums
# over a subgroup first or per pixel, Gaussian sums by native float atomics or by
# compare-exchange (docs/rasterizer.md). Each runs in its own process.
GRADIENT_PATHS = {
    "subgroups, float atomics": {"PANO4D_SUBGROUPS": "1", "PANO4D_FLOAT_ATOMICS": "1"},
    "plain, compare-exchange": {"PANO4D_SUBGROUPS": "0", "PANO4D_FLOAT_ATOMICS": "0"},
}
_PATH_SCRIPT = """
import sys
import torch
sys.path.insert(0, sys.argv[1])
from test_render import gradients
from pano4d.renderer import adapter_info
args = torch.load(sys.argv[2], weights_only=False)
torch.save((adapter_info(), gradients(*args["args"], **args["kw"])), sys.argv[3])
"""


def gradients_on_path(path: str, tmp_path: Path, *args, **kw) -> dict[str, torch.Tensor]:
    """``gradients(*args, **kw)`` with the wgpu backend on ``path``; skips where the
    adapter lacks the path's features."""
    env = {**os.environ, **GRADIENT_PATHS[path]}
    inputs, outputs = tmp_path / "inputs.pt", tmp_path / "outputs.pt"
    torch.save({"args": args, "kw": kw}, inputs)
    subprocess.run([sys.executable, "-c", _PATH_SCRIPT, str(Path(__file__).parent), str(inputs),
                    str(outputs)], env=env, check=True, timeout=600)
    info, got = torch.load(outputs, weights_only=False)
    wanted = {"subgroups": env["PANO4D_SUBGROUPS"], "float_atomics": env["PANO4D_FLOAT_ATOMICS"]}
    for feature, on in wanted.items():
        if info[feature] != ("yes" if on == "1" else "no"):
            pytest.skip(f"{info['name']} has no {feature.replace('_', ' ')}: path {path!r} "
                        "cannot run on it")
    return got


@functools.cache
def scene_256() -> tuple[Gaussians, Camera, list[torch.Tensor], dict, tuple[Grads, Grads]]:
    """A 256² scene, its loss weights, render options and reference gradients (shared by
    the paths' tests: the dense float64 reference takes most of their time)."""
    g = random_scene(150, seed=5, sh_degree=2, log_scale=(-3.0, -1.5))
    cam = camera(256, 256)
    weights = loss_weights(256, 256, seed=3)
    kw = {"background": torch.tensor([0.3, 0.5, 0.2]), "antialiased": True}
    return g, cam, weights, kw, references(g, cam, weights, **kw)


@pytest.mark.parametrize("path", list(GRADIENT_PATHS))
def test_gradients_per_gaussian_at_256(path: str, tmp_path: Path) -> None:
    g, cam, weights, kw, refs = scene_256()
    got = gradients_on_path(path, tmp_path, g, cam, "wgpu", weights, **kw)
    assert all(torch.linalg.norm(v) > 0 for v in got.values())
    assert_as_accurate_as_float32(got, refs, f"256x256, {path}")


def gaussians(rows: list[dict]) -> Gaussians:
    """Gaussians with SH degree 0 from rows of mean, log_scale (3), quat, opacity, rgb_dc."""
    def column(key: str, default) -> torch.Tensor:
        return torch.tensor([row.get(key, default) for row in rows], dtype=torch.float32)

    opacity = column("opacity", 0.8)
    # Anisotropic and turned by default: an isotropic Gaussian's rotation gradient is zero
    # only by cancellation, float32 noise against an exact float64 zero.
    return Gaussians(
        means=column("mean", None), log_scales=column("log_scale", (-1.5, -1.8, -1.3)),
        quats=column("quat", (0.96, 0.1, -0.2, 0.15)),
        opacity_logits=torch.log(opacity / (1 - opacity)),
        sh=column("rgb_dc", (0.5, -0.2, 0.1))[:, None, :],
    )


# Each extreme Gaussian with two ordinary ones beside and behind it.
ORDINARY = [{"mean": (4.0, 0.35, 0.0), "rgb_dc": (-0.4, 0.6, 0.2)},
            {"mean": (6.0, -0.3, 0.1), "log_scale": (-1.0, -1.3, -0.9), "opacity": 0.6,
             "quat": (0.9, 0.2, -0.3, 0.1)}]
EXTREMES = {
    # Two axes past the log-scale clamps [-12, 8]: no gradient for those two.
    "clamped log-scales": [{"mean": (5.0, 0.0, 0.0), "log_scale": (9.0, -1.2, -13.0),
                            "quat": (0.95, 0.1, 0.2, 0.1)}],
    # In front of the near plane, extending behind it, seen at x/z past the Jacobian clamp.
    "straddling the near plane": [{"mean": (0.05, -0.06, 0.01), "log_scale": (-1.0, -1.3, -0.8)}],
    # Just above the 1/255 opacity cut, and one below it (culled: zero gradient).
    "opacity near 0": [{"mean": (5.0, 0.0, 0.0), "opacity": 0.006},
                       {"mean": (5.0, 0.1, 0.0), "opacity": 0.003}],
    # Alpha clamps at 0.999 over its core (a few pixels: ~50 px wide, it is within 0.1 %
    # of its peak only there): no gradient through the clamped pixels.
    "opacity near 1": [{"mean": (5.0, 0.0, 0.0), "opacity": 1 - 1e-5,
                        "log_scale": (1.8, 1.6, 2.0)}],
    # Screen-filling and opaque enough to end the pixels' walks.
    "huge": [{"mean": (3.0, 0.0, 0.0), "log_scale": (2.5, 3.0, 2.0), "opacity": 0.99}],
    # Far below a pixel: the screen-space filter is its footprint (and, antialiased, its
    # opacity falls under the cut).
    "sub-pixel": [{"mean": (5.0, 0.1, 0.05), "log_scale": (-7.0, -7.5, -6.5), "opacity": 0.9}],
}


@pytest.mark.parametrize("antialiased", [False, True])
@pytest.mark.parametrize("case", list(EXTREMES))
def test_gradients_per_gaussian_at_the_extremes(case: str, antialiased: bool) -> None:
    g = gaussians(EXTREMES[case] + ORDINARY)
    cam = Camera.from_fov(70.0, 64, 48)
    weights = loss_weights(64, 48, seed=7)
    kw = {"background": torch.tensor([0.2, 0.3, 0.4]), "antialiased": antialiased}
    got = gradients(g, cam, "wgpu", weights, **kw)
    assert_as_accurate_as_float32(got, references(g, cam, weights, **kw), case)
    extreme = len(EXTREMES[case])
    if case == "clamped log-scales":
        assert (got["log_scales"][0, [0, 2]] == 0).all() and got["log_scales"][0, 1] != 0
    if case == "opacity near 0":
        assert all((v[1] == 0).all() for v in got.values())  # the culled one
    if not (case == "sub-pixel" and antialiased):
        assert float(torch.linalg.norm(got["means"][:extreme])) > 0, "the extreme one is seen"


@pytest.mark.parametrize("case", list(EXTREMES))
def test_reference_gradients_at_the_extremes_match_finite_differences(case: str) -> None:
    # The float64 reference's autograd is the exact derivative of its forward; checked
    # here against finite differences where the extremes bend the maths (clamps, cuts).
    g = gaussians(EXTREMES[case] + ORDINARY[:1]).to(torch.float64)
    cam = Camera.from_fov(70.0, 16, 12)
    weights = [w.double() for w in loss_weights(16, 12, seed=9)]
    names = list(g.tensors())

    def loss(*tensors: torch.Tensor) -> torch.Tensor:
        gs = Gaussians(**dict(zip(names, tensors, strict=True)))
        return weighted_loss(render(gs, cam, backend="torch", antialiased=True), weights)

    inputs = tuple(t.clone().requires_grad_(True) for t in g.tensors().values())
    # A scale of e^8 puts ~1e9 px² in the covariance: the float64 forward's rounding then
    # swamps differences of a 1e-6 step (they drift by 1e-3 at 1e-6, by 1e-5 at 1e-4).
    eps = 1e-4 if case == "clamped log-scales" else 1e-6
    assert torch.autograd.gradcheck(loss, inputs, eps=eps, atol=1e-5, rtol=1e-3)


def test_reference_gradients_match_finite_differences() -> None:
    g = random_scene(3, seed=11, sh_degree=1, log_scale=(-1.5, -1.0), spread=0.6)
    g = g.to(torch.float64)
    cam = camera(9, 7)
    gen = torch.Generator().manual_seed(5)
    weights = [torch.rand(7, 9, 3, generator=gen, dtype=torch.float64),
               torch.rand(7, 9, generator=gen, dtype=torch.float64),
               0.1 * torch.rand(7, 9, generator=gen, dtype=torch.float64)]
    names = list(g.tensors())

    def loss(*tensors: torch.Tensor) -> torch.Tensor:
        gs = Gaussians(**dict(zip(names, tensors, strict=True)))
        return weighted_loss(render(gs, cam, backend="torch", antialiased=True), weights)

    inputs = tuple(t.clone().requires_grad_(True) for t in g.tensors().values())
    assert torch.autograd.gradcheck(loss, inputs, eps=1e-6, atol=1e-5, rtol=1e-3)


# --- extremes ---------------------------------------------------------------------------

def one(mean, log_scale=-1.0, opacity=0.9, quat=(1.0, 0.0, 0.0, 0.0), rgb_dc=0.5) -> Gaussians:
    return Gaussians(
        means=torch.tensor([mean], dtype=torch.float32),
        log_scales=torch.full((1, 3), float(log_scale)),
        quats=torch.tensor([quat], dtype=torch.float32),
        opacity_logits=torch.tensor([math.log(opacity / (1 - opacity))], dtype=torch.float32),
        sh=torch.full((1, 1, 3), rgb_dc),
    )


def test_extremes_stay_finite_and_agree() -> None:
    cam = camera(33, 21)
    cases = [
        one((-3.0, 0.0, 0.0)),                          # behind the camera
        one((0.005, 0.0, 0.0), log_scale=0.0),          # mean behind the near plane
        one((0.05, 0.0, 0.0), log_scale=-1.0),          # crossing the near plane
        one((5.0, 0.1, 0.0), log_scale=-12.0),          # sub-pixel
        one((5.0, 0.0, 0.0), log_scale=-40.0),          # zero scale (clamped)
        one((5.0, 0.0, 0.0), log_scale=40.0),           # huge scale (clamped)
        one((5.0, 0.0, 0.0), opacity=1e-6),
        one((5.0, 0.0, 0.0), opacity=1 - 1e-6),
        one((5.0, 0.0, 0.0), quat=(0.0, 0.0, 0.0, 0.0)),   # zero quaternion → identity
        one((5.0, 0.0, 0.0), quat=(30.0, 4.0, -2.0, 7.0)),  # unnormalised
        one((0.1, 0.0, 0.0), log_scale=-4.0),           # depth 0.1
        one((1e4, 0.0, 0.0), log_scale=5.0),            # depth 1e4
        one((5.0, float("nan"), 0.0)),                  # non-finite: culled
        one((5.0, 0.0, 0.0), log_scale=float("inf")),   # non-finite: culled
    ]
    for g in cases:
        a, b = both(g, cam, background=torch.tensor([0.2, 0.2, 0.2]))
        assert torch.isfinite(a.rgb).all() and torch.isfinite(a.alpha).all()
        assert torch.isfinite(a.depth).all()
        assert (a.alpha >= 0).all() and (a.alpha <= 1).all()
        assert_outputs_close(a, b)


def test_screen_filling_opaque_gaussian_covers_the_screen() -> None:
    g = one((2.0, 0.0, 0.0), log_scale=3.0, opacity=1 - 1e-6, rgb_dc=1.0)
    out = render(g, camera(64, 48))
    assert (out.alpha > 0.99).all()
    assert torch.allclose(out.depth, torch.full_like(out.depth, 2.0), atol=1e-3)


def test_near_plane_and_behind_camera_are_empty_and_have_zero_gradient() -> None:
    g = Gaussians.cat([one((-3.0, 0.0, 0.0)), one((0.005, 0.0, 0.0), log_scale=0.0)])
    g = g.map(lambda t: t.clone().requires_grad_(True))
    out = render(g, camera(16, 16), background=torch.tensor([0.5, 0.5, 0.5]))
    assert (out.alpha == 0).all() and torch.allclose(out.rgb, torch.full_like(out.rgb, 0.5))
    out.rgb.sum().backward()
    assert all((t.grad == 0).all() for t in g.tensors().values())


def test_zero_one_and_a_million_gaussians() -> None:
    cam = camera(64, 48)
    empty = render(Gaussians.empty(sh_degree=2), cam, background=torch.tensor([0.1, 0.2, 0.3]))
    assert (empty.alpha == 0).all()
    assert torch.allclose(empty.rgb[0, 0], torch.tensor([0.1, 0.2, 0.3]))
    single = render(one((3.0, 0.0, 0.0)), cam)
    assert float(single.alpha.max()) > 0.5
    many = random_scene(1_000_000, seed=1, sh_degree=0, spread=2.0, log_scale=(-5.0, -3.0))
    out = render(many, cam)
    assert torch.isfinite(out.rgb).all() and (out.alpha > 0.9).float().mean() > 0.5


# --- footprints --------------------------------------------------------------------------

def footprint_scene() -> Gaussians:
    """Random Gaussians all around the camera (some behind it, some off screen), from a
    fraction of a pixel to the whole screen, and the extremes one by one. Their axes stay
    within e of each other: a needle's antialiased opacity is a difference of float32
    products, so whether it passes the 1/255 cut is rounding, on either side."""
    spread = random_scene(800, seed=21, centre=(0.0, 0.0, 0.0), spread=6.0)
    order = torch.randperm(len(spread), generator=torch.Generator().manual_seed(23))
    level = torch.linspace(-9.0, 1.0, len(spread))[order]
    spread = dataclasses.replace(spread, log_scales=level[:, None] + spread.log_scales + 2.0)
    return Gaussians.cat([spread, *(one(*case) for case in FOOTPRINT_EXTREMES)])


# (mean, log_scale, opacity) of one Gaussian each.
FOOTPRINT_EXTREMES = [
    ((-3.0, 0.0, 0.0), -1.0, 0.9),             # behind the camera
    ((0.005, 0.0, 0.0), 0.0, 0.9),             # mean behind the near plane
    ((0.05, 0.0, 0.0), -1.0, 0.9),             # crossing the near plane
    ((0.02, 0.001, 0.0), -6.0, 0.9),           # just past the near plane, small
    ((5.0, 0.1, 0.0), -12.0, 0.9),             # sub-pixel: the low-pass is its footprint
    ((5.0, 0.0, 0.0), 40.0, 0.9),              # huge scale (clamped), screen-filling
    ((2.0, 0.0, 0.0), 3.0, 0.99),              # screen-filling
    ((5.0, 0.0, 0.0), -1.0, 1e-6),             # under the opacity cut
    ((5.0, -9.0, 0.0), -3.0, 0.9),             # beside the screen
    ((1e4, 0.0, 0.0), 5.0, 0.9),               # depth 1e4
    ((5.0, float("nan"), 0.0), -1.0, 0.9),     # non-finite
    ((5.0, 0.0, 0.0), float("inf"), 0.9),      # non-finite
]


@pytest.mark.parametrize("antialiased", [False, True])
def test_footprints_of_the_kernel_are_the_references(antialiased: bool) -> None:
    """The wgpu projection's footprints are the torch reference's: the same centres, radii
    within a pixel (float32 rounding under the ceil), and the same Gaussians culled except
    those the kernel culls for reaching no tile of the image."""
    g, cam = footprint_scene(), camera(96, 64)
    a = footprints(g, cam, "wgpu", antialiased)
    b = footprints(g, cam, "torch", antialiased)
    assert a.centre.shape == (len(g), 2) and a.radius.shape == (len(g),)
    both_drawn = (a.radius >= 0) & (b.radius >= 0)
    assert (a.radius[both_drawn] - b.radius[both_drawn]).abs().max() <= 1
    scale = 1 + b.centre[both_drawn].abs()
    assert ((a.centre[both_drawn] - b.centre[both_drawn]).abs() / scale).max() < 1e-4
    x, y, r = b.centre[:, 0], b.centre[:, 1], b.radius
    off_screen = (x + r < 0) | (x - r > cam.width) | (y + r < 0) | (y - r > cam.height)
    assert ((a.radius < 0) == (b.radius < 0))[~off_screen].all()
    assert ((a.radius < 0) & (b.radius >= 0) & ~off_screen).sum() == 0
    assert ((a.radius >= 0) & (b.radius < 0)).sum() == 0
    extremes = a.radius[-len(FOOTPRINT_EXTREMES):].tolist()
    culled = [0, 1, 7, 8, 10, 11]  # behind, near plane, opacity, off screen, non-finite
    assert all(extremes[i] == -1 for i in culled)
    # Sub-pixel: the low-pass alone, ceil(3·sqrt(0.3 + sqrt(0.1))); antialiased, its opacity
    # falls under the cut.
    assert extremes[4] == (-1 if antialiased else 3)
    assert extremes[6] > cam.width  # screen-filling
    assert int(both_drawn.sum()) > 100 and int((a.radius < 0).sum()) > 50


@pytest.mark.parametrize("backend", ["wgpu", "torch"])
def test_a_gaussian_changes_no_pixel_beyond_its_footprint(backend: str) -> None:
    """Rendered with and without each Gaussian, the pixels that differ lie within its
    reported footprint, and a culled one changes none."""
    g = Gaussians.cat([random_scene(40, seed=22, spread=2.0, log_scale=(-5.0, -0.5)),
                       *(one(*case) for case in FOOTPRINT_EXTREMES)])  # fmt: skip
    cam = camera(48, 32)
    f = footprints(g, cam, backend)
    pixels = cam.pixel_grid()
    with torch.no_grad():
        whole = render(g, cam, backend=backend)
        for i in range(len(g)):
            rest = g[torch.arange(len(g)) != i]
            out = render(rest, cam, backend=backend)
            changed = ((out.rgb != whole.rgb).any(-1) | (out.alpha != whole.alpha)
                       | (out.depth != whole.depth))  # fmt: skip
            if f.radius[i] < 0:
                assert not changed.any(), f"culled Gaussian {i} changed pixels"
                continue
            distance = torch.linalg.norm(pixels[changed] - f.centre[i], dim=-1)
            assert (distance <= f.radius[i]).all(), (
                f"Gaussian {i} changed a pixel {float(distance.max()):.2f} px from its centre, "
                f"beyond its radius {float(f.radius[i])}"
            )


def test_invalid_input_raises() -> None:
    g = random_scene(3, seed=0)
    with pytest.raises(ValueError):
        render(g, camera(8, 8), backend="vulkan")
    with pytest.raises(ValueError):
        render(g, camera(8, 8), background=torch.tensor([0.0, float("nan"), 0.0]))
    with pytest.raises(ValueError):
        footprints(g, camera(8, 8), backend="vulkan")


def test_adapter_info_names_the_adapter() -> None:
    info = adapter_info()
    assert set(info) == {"name", "backend", "device_type", "driver", "subgroups", "float_atomics"}
    assert info["name"]
    assert info["subgroups"] in ("yes", "no") and info["float_atomics"] in ("yes", "no")


def test_adapter_preference_that_matches_nothing_is_a_clear_error() -> None:
    # The renderer is process-wide, so the preference is tried in a fresh process.
    code = (
        "from pano4d.renderer import adapter_info\n"
        "try:\n    adapter_info()\nexcept RuntimeError as e:\n    print(e)\n"
    )
    env = {**os.environ, "PANO4D_ADAPTER": "no-such-adapter"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=120, check=True)
    assert "matches no adapter" in out.stdout and "mesa-vulkan-drivers" in out.stdout


def test_gradients_come_back_in_the_input_dtype() -> None:
    g = random_scene(20, seed=2).to(torch.float64).map(lambda t: t.requires_grad_(True))
    out = render(g, camera(16, 12))
    assert out.rgb.dtype == torch.float32
    out.rgb.sum().backward()
    assert g.means.grad is not None and g.means.grad.dtype == torch.float64


# --- a real scene -----------------------------------------------------------------------

def read_3dgs_ply(path: Path) -> Gaussians:
    """Minimal reader for the standard binary little-endian 3DGS layout (float32 only)."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    header = raw[:end].decode("ascii").splitlines()
    count = next(int(line.split()[2]) for line in header if line.startswith("element vertex"))
    names = [line.split()[2] for line in header if line.startswith("property float")]
    data = np.frombuffer(raw[end:], dtype="<f4", count=count * len(names)).reshape(count, -1)
    col = {name: data[:, i] for i, name in enumerate(names)}

    def stack(keys: list[str]) -> torch.Tensor:
        return torch.from_numpy(np.stack([col[k] for k in keys], axis=-1).copy())

    rest = sorted((k for k in col if k.startswith("f_rest_")), key=lambda k: int(k[7:]))
    k = 1 + len(rest) // 3
    dc = stack(["f_dc_0", "f_dc_1", "f_dc_2"])[:, None, :]
    # f_rest is channel-major in the file: (3, k - 1) per Gaussian.
    sh_rest = stack(rest).reshape(count, 3, k - 1).transpose(1, 2)
    return Gaussians(
        means=stack(["x", "y", "z"]),
        log_scales=stack(["scale_0", "scale_1", "scale_2"]),
        quats=stack(["rot_0", "rot_1", "rot_2", "rot_3"]),
        opacity_logits=torch.from_numpy(col["opacity"].copy()),
        sh=torch.cat([dc, sh_rest], dim=1),
    )


def test_real_scene_both_backends_agree() -> None:
    g = read_3dgs_ply(DATA / "gs_train1000.ply")
    assert len(g) == 1000 and g.sh_degree == 3
    centre = g.means.median(dim=0).values
    # COLMAP frame: y points down, so "up" is -y.
    cam = Camera.from_fov(90.0, 96, 64, centre - torch.tensor([0.0, 0.0, 8.0]), (0.0, 0.0, 1.0),
                          up=(0.0, -1.0, 0.0))
    a, b = both(g, cam)
    assert float(a.alpha.max()) > 0.1
    assert_outputs_close(a, b)
