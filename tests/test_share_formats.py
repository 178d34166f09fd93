"""`pano4d export --format ply|compressed-ply|spz|sog|splat [--time T | --sequence]`: each
format read back by a reader that is not its writer and rendered against the .ply4d at the
same camera.

Readers: plyfile (.ply), pano4d's Rust reader (SuperSplat .compressed.ply; gaussforge wrote
it), gsply (SPZ), and for SOG and .splat small decoders here that follow the published
layouts (PlayCanvas's SOG spec, meta.json + lossless WebP read by Pillow; antimatter15's
32-byte .splat records): no SOG reader exists without npm.

An antialiased scene is exported baked for viewers that draw classic (issue #40): its files
drawn classic must look like the scene drawn antialiased at the training views' density.
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from pathlib import Path

import gsply
import numpy as np
import plyfile
import pytest
import torch
from pano4d_process import pano4d
from PIL import Image

from pano4d import ply4d, share_formats
from pano4d.camera import Camera
from pano4d.gaussians import Gaussians, sh_coeffs_for_degree
from pano4d.metrics import psnr
from pano4d.renderer import render
from pano4d.share_formats import TRANSPARENT_LOGIT, bake_antialiasing, for_classic_viewers

C0 = 0.28209479177387814


def discs(n: int, degree: int, seed: int) -> Gaussians:
    """Flat, randomly turned, half-transparent discs in front of the origin (+x): a wrong
    rotation, scale or opacity changes what the camera sees."""
    gen = torch.Generator().manual_seed(seed)

    def rand(*shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=gen)

    sh = torch.zeros(n, sh_coeffs_for_degree(degree), 3)
    sh[:, 0] = (0.15 + 0.7 * rand(n, 3) - 0.5) / C0
    sh[:, 1:] = 0.3 * (2 * rand(n, sh.shape[1] - 1, 3) - 1)
    log_scales = torch.log(0.05 + 0.25 * rand(n, 3))
    log_scales[:, 2] = math.log(0.01)
    return Gaussians(
        means=torch.tensor([4.0, 0.0, 0.0]) + 1.5 * (2 * rand(n, 3) - 1),
        log_scales=log_scales,
        quats=torch.nn.functional.normalize(2 * rand(n, 4) - 1, dim=-1),
        opacity_logits=4 * rand(n) - 1,
        sh=sh,
    )


def scene_file(folder: Path, degree: int) -> tuple[ply4d.Scene4D, Path]:
    scene = ply4d.Scene4D(
        static=discs(300, degree, seed=1),
        dynamic=[discs(60, degree, seed=2), discs(60, degree, seed=3)],
        timestamps=[0.0, 0.125],
        fps=8.0,
    )
    path = folder / "scene.ply4d"
    ply4d.write(path, scene)
    return scene, path


def exported(path: Path, out: Path, *args: str) -> Path:
    result = pano4d("export", path, out, *args)
    assert result.returncode == 0, result.stderr
    return out


# --- readers that are not the writers ------------------------------------------------------
def read_with_plyfile(path: Path) -> Gaussians:
    v = plyfile.PlyData.read(str(path))["vertex"].data
    names = v.dtype.names

    def fields(*keys: str) -> torch.Tensor:
        return torch.from_numpy(np.stack([v[k] for k in keys], axis=-1).astype(np.float32))

    rest = sorted((k for k in names if k.startswith("f_rest_")), key=lambda k: int(k[7:]))
    sh = fields("f_dc_0", "f_dc_1", "f_dc_2")[:, None, :]
    if rest:  # channel-major: all of red's coefficients, then green's, then blue's
        sh = torch.cat([sh, fields(*rest).reshape(len(v), 3, -1).transpose(1, 2)], dim=1)
    return Gaussians(
        fields("x", "y", "z"), fields("scale_0", "scale_1", "scale_2"),
        fields("rot_0", "rot_1", "rot_2", "rot_3"), fields("opacity")[:, 0], sh,
    )  # fmt: skip


def read_with_gsply(path: Path) -> Gaussians:
    d = gsply.read_spz(path)
    n = len(d.means)
    sh = d.sh0.reshape(n, 1, 3)
    if d.get_sh_degree() > 0:
        sh = np.concatenate([sh, np.asarray(d.shN).reshape(n, -1, 3)], axis=1)
    arrays = [d.means, d.scales, d.quats, d.opacities.reshape(n), sh]
    return Gaussians(*(torch.from_numpy(np.ascontiguousarray(a, np.float32)) for a in arrays))


def logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(p, 1e-6, 1 - 1e-6)
    return np.log(p / (1 - p))


def read_splat(path: Path) -> Gaussians:
    """antimatter15's .splat: per Gaussian position and linear scale (float32 × 3 each), RGBA
    (uint8: base colour, sigmoid of opacity) and the rotation (w, x, y, z) as q·128 + 128."""
    record = np.dtype([("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4),
                       ("rot", "u1", 4)])  # fmt: skip
    raw = np.frombuffer(path.read_bytes(), dtype=record)
    rgba = raw["rgba"] / 255.0
    return Gaussians(
        torch.from_numpy(raw["pos"].copy()),
        torch.from_numpy(np.log(raw["scale"])),
        torch.from_numpy((raw["rot"] - 128.0) / 128.0).float(),
        torch.from_numpy(logit(rgba[:, 3])).float(),
        torch.from_numpy((rgba[:, None, :3] - 0.5) / C0).float(),
    )


def read_sog(path: Path) -> Gaussians:
    """A bundled SOG (version 2) as PlayCanvas's spec lays it out: every per-Gaussian image
    holds Gaussian i at pixel i (row-major); positions are 16 bits (means_l, means_u) between
    meta's mins and maxs of sign(x)·ln(|x| + 1); rotations the three smallest components
    (·√2, from [0, 255] to [−1, 1]) with 252 + the largest one's index in alpha; scales and
    colours indices into 256-entry codebooks, opacity the sigmoid in sh0's alpha; higher SH
    a palette (shN_centroids, 64 entries a row, one pixel a coefficient) chosen by a 16-bit
    label (shN_labels)."""
    with zipfile.ZipFile(path) as bundle:
        meta = json.loads(bundle.read("meta.json"))
        assert meta["version"] == 2
        n = meta["count"]

        def pixels(name: str, count: int | None = n) -> np.ndarray:
            image = Image.open(io.BytesIO(bundle.read(name))).convert("RGBA")
            return np.asarray(image).reshape(-1, 4)[:count].astype(np.int64)

        lo, hi = (pixels(name) for name in meta["means"]["files"])
        q = (lo[:, :3] | (hi[:, :3] << 8)) / 65535.0
        mins, maxs = np.array(meta["means"]["mins"]), np.array(meta["means"]["maxs"])
        t = mins + (maxs - mins) * q
        means = np.sign(t) * np.expm1(np.abs(t))

        packed = pixels(meta["quats"]["files"][0])
        largest = packed[:, 3] - 252
        assert ((largest >= 0) & (largest <= 3)).all()
        small = (packed[:, :3] / 255.0 * 2 - 1) / math.sqrt(2)
        quats = np.zeros((n, 4))
        for k in range(4):
            rows = largest == k
            quats[np.ix_(rows, [i for i in range(4) if i != k])] = small[rows]
            quats[rows, k] = np.sqrt(np.clip(1 - (small[rows] ** 2).sum(-1), 0, None))

        scales = np.array(meta["scales"]["codebook"])[pixels(meta["scales"]["files"][0])[:, :3]]
        sh0 = pixels(meta["sh0"]["files"][0])
        colour_book = np.array(meta["sh0"]["codebook"])
        sh = [colour_book[sh0[:, None, :3]]]
        if "shN" in meta:
            coeffs = sh_coeffs_for_degree(meta["shN"]["bands"]) - 1
            centroids = pixels(meta["shN"]["files"][0], None)
            width = 64 * coeffs
            labels = pixels(meta["shN"]["files"][1])
            label = labels[:, 0] | (labels[:, 1] << 8)
            at = (label // 64)[:, None] * width + (label % 64)[:, None] * coeffs + np.arange(coeffs)
            sh.append(np.array(meta["shN"]["codebook"])[centroids[at][..., :3]])
        arrays = [means, scales, quats, logit(sh0[:, 3] / 255.0), np.concatenate(sh, axis=1)]
    return Gaussians(*(torch.from_numpy(a.astype(np.float32)) for a in arrays))


READERS = {
    "ply": read_with_plyfile,
    "compressed-ply": ply4d.read_ply,
    "spz": read_with_gsply,
    "sog": read_sog,
    "splat": read_splat,
}
SUFFIX = {"ply": ".ply", "compressed-ply": ".compressed.ply", "spz": ".spz", "sog": ".sog",
          "splat": ".splat"}  # fmt: skip


def views(g: Gaussians) -> list[torch.Tensor]:
    """``g`` seen from the panorama's viewpoint and from one step aside (SH shows)."""
    cams = [Camera.from_fov(70, 128, 96), Camera.from_fov(70, 128, 96, (0, 1.5, 0.5), (1, -0.4, 0))]
    return [render(g, cam).rgb for cam in cams]


def assert_renders_like(decoded: Gaussians, truth: Gaussians, least_db: float = 30.0) -> None:
    assert len(decoded) == len(truth)
    for got, want in zip(views(decoded), views(truth), strict=True):
        assert psnr(got, want) >= least_db, psnr(got, want)


@pytest.mark.parametrize(("fmt", "degree"), [
    ("ply", 0), ("ply", 1), ("compressed-ply", 0), ("compressed-ply", 1), ("spz", 0),
    ("spz", 1), ("sog", 0), ("sog", 1), ("splat", 0),
])  # fmt: skip
def test_each_format_renders_as_the_scene(tmp_path: Path, fmt: str, degree: int) -> None:
    scene, path = scene_file(tmp_path, degree)
    out = exported(path, tmp_path / f"t1{SUFFIX[fmt]}", "--format", fmt, "--time", "1")
    decoded, truth = READERS[fmt](out), scene.at(1)
    assert_renders_like(decoded, truth)
    if fmt == "ply":  # lossless: every value as stored
        for name, value in truth.tensors().items():
            assert torch.equal(decoded.tensors()[name], value), name


def test_lossy_formats_keep_each_value_within_their_quantisation(tmp_path: Path) -> None:
    """Positions to a 16-bit step of the range in SOG (which reorders the Gaussians in
    space: each is matched to its nearest) and a 12-bit fixed point in SPZ, the .splat's
    colour and opacity to one 8-bit step (gaussforge truncates)."""
    scene, path = scene_file(tmp_path, 0)
    truth = scene.at(0)
    sog = read_sog(exported(path, tmp_path / "t.sog"))
    log_range = np.log1p(truth.means.abs().max().item())
    step = math.expm1(log_range) - math.expm1(log_range - 2 * log_range / 65535)
    distance, nearest = torch.cdist(sog.means.double(), truth.means.double()).min(dim=1)
    assert distance.max() <= step * math.sqrt(3)
    assert len(set(nearest.tolist())) == len(truth)  # one decoded Gaussian for each
    spz = read_with_gsply(exported(path, tmp_path / "t.spz"))
    assert (spz.means - truth.means).abs().max() <= 2.0**-12
    splat = read_splat(exported(path, tmp_path / "t.splat"))
    assert torch.equal(splat.means, truth.means)
    base = (0.5 + C0 * truth.sh[:, 0]).clamp(0, 1)
    assert ((0.5 + C0 * splat.sh[:, 0]) - base).abs().max() <= 1 / 255 + 1e-6
    alpha = torch.sigmoid(truth.opacity_logits)
    assert (torch.sigmoid(splat.opacity_logits) - alpha).abs().max() <= 1 / 255 + 1e-6


def test_a_compressed_ply_keeps_near_gaussians_near_beside_a_far_sky(tmp_path: Path) -> None:
    """A panorama's scene: discs a few units from the viewpoint and a sky shell a thousand
    away, in an order that mixes them (as training leaves them). A .compressed.ply quantises
    each run of 256 within the run's box: unless the export groups Gaussians by distance, a
    near disc sharing a run with the sky moves by a tenth of its distance. 600 near discs fill
    no whole runs: the export pads them with transparent ones rather than mix in the sky."""
    near = discs(600, 0, seed=4)
    sky = discs(600, 0, seed=5)
    direction = torch.nn.functional.normalize(
        2 * torch.rand(600, 3, generator=torch.Generator().manual_seed(6)) - 1, dim=-1
    )
    sky.means = 1000.0 * direction
    both = Gaussians.cat([near, sky])
    both = both[torch.randperm(len(both), generator=torch.Generator().manual_seed(7))]
    path = tmp_path / "scene.ply4d"
    ply4d.write(
        path, ply4d.Scene4D(static=both, dynamic=[Gaussians.empty(0)], timestamps=[0.0], fps=8.0)
    )
    decoded = ply4d.read_ply(exported(path, tmp_path / "t.compressed.ply"))
    distance, _ = torch.cdist(decoded.means.double(), both.means.double()).min(dim=1)
    relative = distance / decoded.means.double().norm(dim=1)
    assert relative.max() <= 0.01, relative.max()
    visible = torch.sigmoid(decoded.opacity_logits) > 1 / 510  # over half an 8-bit step
    assert visible.sum() == len(both)  # the padding is transparent: opacity 0 in 8 bits
    assert_renders_like(decoded[visible], both)


def test_the_format_follows_the_ending_of_the_file(tmp_path: Path) -> None:
    scene, path = scene_file(tmp_path, 0)
    assert zipfile.is_zipfile(exported(path, tmp_path / "t.sog"))
    header = exported(path, tmp_path / "t.compressed.ply").read_bytes()[:200]
    assert header.startswith(b"ply\n") and b"\nelement chunk " in header
    assert exported(path, tmp_path / "t.spz").read_bytes()[:4] == b"NGSP"  # SPZ version 4
    assert_renders_like(read_with_plyfile(exported(path, tmp_path / "t.bin")), scene.at(0))


def test_a_sequence_is_a_folder_of_every_timestamp(tmp_path: Path) -> None:
    scene, path = scene_file(tmp_path, 1)
    out = exported(path, tmp_path / "frames", "--format", "sog", "--sequence")
    assert sorted(p.name for p in out.iterdir()) == ["frame_0000.sog", "frame_0001.sog"]
    for t in range(2):
        assert_renders_like(read_sog(out / f"frame_{t:04d}.sog"), scene.at(t))
    # A second run would mix two sequences: it refuses, and the first stays as it was.
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    again = pano4d("export", path, out, "--format", "ply", "--sequence")
    assert again.returncode == 2 and "not an empty folder" in again.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


# --- an antialiased scene, baked for the viewers that draw classic ----------------------------
VIEW_SIZE, FOV_DEG = 512, 80.0  # the training views' (camera.params of a trained scene)
FOCAL = VIEW_SIZE / (2 * math.tan(math.radians(FOV_DEG) / 2))
VIEWPOINT = (0.5, -1.0, 2.0)  # the panorama's position: anywhere, not only the origin
CONE_DEG = 6.0  # how far off a view's axis the test Gaussians lie (the bake is exact on it)


def around(axis: tuple[float, float, float], n: int, seed: int, distances: tuple[float, float],
           pixels: tuple[float, float]) -> Gaussians:  # fmt: skip
    """``n`` Gaussians within CONE_DEG of ``axis`` seen from VIEWPOINT, at distances and with
    axes (in pixels at the training density) log-uniform in those ranges, randomly turned,
    with opacities from 5·10⁻⁵ to 1 − 5·10⁻⁵."""
    gen = torch.Generator().manual_seed(seed)

    def log_uniform(lo: float, hi: float, *shape: int) -> torch.Tensor:
        return lo * (hi / lo) ** torch.rand(*shape, generator=gen)

    forward = torch.nn.functional.normalize(torch.tensor(axis), dim=0)
    camera = Camera.from_fov(FOV_DEG, 2, 2, VIEWPOINT, forward)
    right, down = camera.R[0].float(), camera.R[1].float()
    spread = (2 * torch.rand(n, 2, generator=gen) - 1) * math.tan(math.radians(CONE_DEG))
    sight = torch.nn.functional.normalize(
        forward + spread[:, :1] * right + spread[:, 1:] * down, dim=-1
    )
    distance = log_uniform(*distances, n)
    return Gaussians(
        means=torch.tensor(VIEWPOINT) + distance[:, None] * sight,
        log_scales=torch.log(distance[:, None] / FOCAL * log_uniform(*pixels, n, 3)),
        quats=2 * torch.rand(n, 4, generator=gen) - 1,
        opacity_logits=20 * torch.rand(n, generator=gen) - 10,
        sh=(0.1 + 0.8 * torch.rand(n, 1, 3, generator=gen) - 0.5) / C0,
    )


def middle_of_a_training_view(axis: tuple[float, float, float]) -> Camera:
    """96 × 96 pixels around the centre of a training view from VIEWPOINT along ``axis``."""
    fov = math.degrees(2 * math.atan(48 / FOCAL))
    return Camera.from_fov(fov, 96, 96, VIEWPOINT, axis)


def antialiased_scene_file(folder: Path, g: Gaussians) -> Path:
    path = folder / "antialiased.ply4d"
    camera = {"position": list(VIEWPOINT), "params": {"fov_deg": FOV_DEG, "view_size": VIEW_SIZE}}
    scene = ply4d.Scene4D(static=g, dynamic=[Gaussians.empty(0)], timestamps=[0.0], fps=8.0,
                          camera=camera, antialiased=True)  # fmt: skip
    ply4d.write(path, scene)
    return path


@pytest.mark.parametrize("axis", [(1.0, 0.0, 0.0), (0.3, 0.1, 1.0)])  # the second: near +z
def test_the_baked_set_drawn_classic_is_the_antialiased_render(
    axis: tuple[float, float, float],
) -> None:
    """From the panorama's position at the training density, the classic render of the baked
    set draws the light the antialiased render of the trained one draws: Gaussians from 0.1
    to 10⁴ away, a twentieth of a pixel to ten across, nearly transparent to nearly opaque.
    Unbaked, the classic render is far off (sub-pixel Gaussians come out too opaque)."""
    g = around(axis, 600, seed=11, distances=(0.1, 1e4), pixels=(0.05, 10.0))
    camera = middle_of_a_training_view(axis)
    want = render(g, camera, antialiased=True).rgb
    baked = render(bake_antialiasing(g, VIEWPOINT, FOCAL), camera, antialiased=False).rgb
    unbaked = render(g, camera, antialiased=False).rgb
    # The bake keeps each Gaussian's integral, not its shape: classic draws Σ2D + 0.3 I where
    # the antialiased mode draws Σ2D + 0.1 I, so a sub-pixel Gaussian comes out wider and
    # fainter (0.12 at most per pixel) while the image's total light stays (measured 39.7
    # and 40.5 dB, totals within 0.02 %; unbaked 29.0 and 29.4 dB, 5–6 % too bright).
    assert psnr(baked, want) >= 35.0, psnr(baked, want)
    assert abs(float(baked.sum() / want.sum()) - 1) <= 1e-3
    assert psnr(unbaked, want) < 35.0, psnr(unbaked, want)
    assert abs(float(unbaked.sum() / want.sum()) - 1) > 0.02


def test_a_classic_scene_exports_the_same_bytes_as_before(tmp_path: Path) -> None:
    """The sets as stored, nothing recomputed: what each format wrote before the bake."""
    _, path = scene_file(tmp_path, 1)
    source = ply4d.open(path)
    assert not source.antialiased
    g = source.at(1)
    assert for_classic_viewers(g, source) is g
    for fmt, suffix in SUFFIX.items():
        out = exported(path, tmp_path / f"t1{suffix}", "--format", fmt, "--time", "1")
        before = tmp_path / f"before{suffix}"
        share_formats.write(g, before, share_formats.FORMATS[fmt])
        assert out.read_bytes() == before.read_bytes(), fmt
    ply4d.export(path, 1, tmp_path / "copied.ply")  # the stored bytes, copied
    assert (tmp_path / "copied.ply").read_bytes() == (tmp_path / "before.ply").read_bytes()


def test_an_antialiased_scene_exports_baked_in_every_format(tmp_path: Path) -> None:
    """Each format's file, drawn classic as other viewers draw it, looks like the scene drawn
    antialiased (within the format's own losses); the plain .ply holds the baked opacities
    exactly, and every other value as stored."""
    g = around((1.0, 0.0, 0.0), 500, seed=12, distances=(1.0, 100.0), pixels=(0.05, 2.0))
    path = antialiased_scene_file(tmp_path, g)
    camera = middle_of_a_training_view((1.0, 0.0, 0.0))
    want = render(g, camera, antialiased=True).rgb
    # Measured 23.0 dB unbaked; baked, 36.9 (.compressed.ply) to 37.3 dB (.ply, .spz) but
    # SOG's 33.5 (its scale codebook): the bake keeps each Gaussian's light, not its
    # shape (the two modes' filters differ), hence no more than ~37 dB on these sub-pixel
    # Gaussians even for the lossless .ply.
    assert psnr(render(g, camera).rgb, want) < 25.0
    for fmt, suffix in SUFFIX.items():
        decoded = READERS[fmt](exported(path, tmp_path / f"t{suffix}", "--format", fmt))
        got = render(decoded, camera).rgb
        assert psnr(got, want) >= 33.0, (fmt, psnr(got, want))
    baked = bake_antialiasing(g, VIEWPOINT, FOCAL)
    assert not torch.equal(baked.opacity_logits, g.opacity_logits)
    ply4d.export(path, 0, tmp_path / "copied.ply")  # no byte copy for an antialiased scene
    for plain in (tmp_path / "t.ply", tmp_path / "copied.ply"):
        decoded = read_with_plyfile(plain)
        for name, value in baked.tensors().items():
            assert torch.equal(decoded.tensors()[name], value), (plain.name, name)


def test_the_bake_keeps_what_it_cannot_bake_and_erases_what_has_no_area() -> None:
    """One rule each. Kept as they are: a non-finite parameter (every render culls it), a
    Gaussian at the viewpoint or nearer than the near plane (no camera there draws it).
    Transparent: a needle whose footprint rounds to no area. Clamped as the rasteriser
    clamps: a log-scale of −100 is baked as −12. Every other logit finite, never above the
    one it was (the factor is at most 1), opaque or not."""
    g = around((1.0, 0.0, 0.0), 13, seed=13, distances=(1.0, 10.0), pixels=(0.3, 3.0))
    nan, inf = float("nan"), float("inf")
    g.means[0, 0] = nan
    g.log_scales[1, 0] = -inf  # a zero scale
    g.quats[2, 1] = inf
    g.opacity_logits[3] = inf
    g.opacity_logits[4] = -inf
    g.sh[5, 0, 0] = nan
    g.means[6] = torch.tensor(VIEWPOINT)
    g.means[7] = torch.tensor(VIEWPOINT) + torch.tensor([0.006, 0.0, 0.0])
    # A needle 3000 long and 6·10⁻⁶ thick across the sight line, turned 30° in the image:
    # its det Σ2D is below the float64 rounding of its terms.
    g.means[8] = torch.tensor(VIEWPOINT) + torch.tensor([5.0, 0.0, 0.0])
    g.log_scales[8] = torch.tensor([-12.0, 8.0, -12.0])
    g.quats[8] = torch.tensor([math.cos(math.pi / 12), math.sin(math.pi / 12), 0.0, 0.0])
    for name in ("means", "quats", "opacity_logits"):
        g.tensors()[name][10] = g.tensors()[name][9]
    g.log_scales[9] = torch.tensor([-100.0, 0.0, -3.0])
    g.log_scales[10] = torch.tensor([-12.0, 0.0, -3.0])
    g.opacity_logits[11] = 1000.0  # opacity 1 in float64
    g.opacity_logits[12] = -1000.0
    baked = bake_antialiasing(g, VIEWPOINT, FOCAL)
    kept = slice(0, 8)
    assert torch.equal(baked.opacity_logits[kept].view(torch.int32),
                       g.opacity_logits[kept].view(torch.int32))  # fmt: skip
    assert baked.opacity_logits[8] == TRANSPARENT_LOGIT
    assert baked.opacity_logits[9] == baked.opacity_logits[10]
    rest = baked.opacity_logits[9:]
    assert torch.isfinite(rest).all() and (rest <= g.opacity_logits[9:]).all()
    for name in ("means", "log_scales", "quats", "sh"):
        assert baked.tensors()[name] is g.tensors()[name]  # only opacities change
    rgb = render(baked, middle_of_a_training_view((1.0, 0.0, 0.0))).rgb
    assert torch.isfinite(rgb).all()


def test_an_antialiased_scene_without_its_training_views_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "no-params.ply4d"
    g = around((1.0, 0.0, 0.0), 4, seed=14, distances=(1.0, 10.0), pixels=(0.3, 3.0))
    ply4d.write(path, ply4d.Scene4D(static=g, dynamic=[Gaussians.empty(0)], timestamps=[0.0],
                                    fps=8.0, antialiased=True))  # fmt: skip
    result = pano4d("export", path, tmp_path / "t.ply")
    assert result.returncode == 2, result.stderr
    assert str(path) in result.stderr and "view_size" in result.stderr
    assert not (tmp_path / "t.ply").exists()
