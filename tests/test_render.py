"""The wgpu rasteriser against the pure-torch reference (values and gradients), the
reference against finite differences, extreme inputs, and a real 3DGS scene."""

from __future__ import annotations

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
from pano4d.render import adapter_info, render

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


@pytest.mark.parametrize("antialiased", [False, True])
@pytest.mark.parametrize("inside", [False, True])
def test_gradients_match_reference(antialiased: bool, inside: bool) -> None:
    if inside:
        # Gaussians all around the camera: Jacobian clamps, culling behind, termination.
        g = random_scene(200, seed=17, sh_degree=3, centre=(0.0, 0.0, 0.0), spread=3.0,
                         log_scale=(-2.0, -0.5))
    else:
        g = random_scene(60, seed=7, sh_degree=3, log_scale=(-2.5, -1.0))
    cam = camera(32, 24)
    gen = torch.Generator().manual_seed(3)
    weights = [torch.rand(24, 32, 3, generator=gen), torch.rand(24, 32, generator=gen),
               0.1 * torch.rand(24, 32, generator=gen)]
    bg = torch.tensor([0.3, 0.5, 0.2])
    got = gradients(g, cam, "wgpu", weights, background=bg, antialiased=antialiased)
    ref = gradients(g.to(torch.float64), cam, "torch", weights, background=bg,
                    antialiased=antialiased)
    for name, r in ref.items():
        assert torch.linalg.norm(r) > 0, name
        err = float(torch.linalg.norm(got[name].double() - r) / torch.linalg.norm(r))
        assert err <= 1e-3, f"{name}: relative error {err:.2e}"


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


def test_invalid_input_raises() -> None:
    g = random_scene(3, seed=0)
    with pytest.raises(ValueError):
        render(g, camera(8, 8), backend="vulkan")
    with pytest.raises(ValueError):
        render(g, camera(8, 8), background=torch.tensor([0.0, float("nan"), 0.0]))


def test_adapter_info_names_the_adapter() -> None:
    info = adapter_info()
    assert set(info) == {"name", "backend", "device_type", "driver"}
    assert info["name"]


def test_adapter_preference_that_matches_nothing_is_a_clear_error() -> None:
    # The renderer is process-wide, so the preference is tried in a fresh process.
    code = (
        "from pano4d.render import adapter_info\n"
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
