"""pano4d.ply4d: 3DGS .ply and .ply4d round trips, real files, and clear errors."""

from __future__ import annotations

import functools
import json
import math
import os
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from test_spacetime import assert_bit_equal_spacetime, random_spacetime

from pano4d import ply4d
from pano4d.gaussians import Gaussians, sh_coeffs_for_degree
from pano4d.share_formats import bake_antialiasing
from pano4d.spacetime import SpacetimeGaussians, TimeModel

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
TRAIN = DATA / "gs_train1000.ply"
GUITAR = DATA / "gs_guitar.ply"
GUITAR_COMPRESSED = DATA / "gs_guitar.compressed.ply"


def random_gaussians(n: int, degree: int, seed: int) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)
    k = sh_coeffs_for_degree(degree)

    def r(*shape: int) -> torch.Tensor:
        return torch.randn(*shape, generator=gen) * 3

    g = Gaussians(r(n, 3), r(n, 3), r(n, 4), r(n), r(n, k, 3))
    if n:
        # Values a lossy path would change: subnormal, -0, huge, inf.
        g.means[0] = torch.tensor([1e-45, -0.0, 3.0e38])
        g.opacity_logits[0] = float("inf")
    return g


def assert_bit_equal(a: Gaussians, b: Gaussians) -> None:
    assert len(a) == len(b)
    assert a.sh_degree == b.sh_degree
    for name, ta in a.tensors().items():
        tb = b.tensors()[name]
        assert ta.dtype == tb.dtype == torch.float32, name
        assert torch.equal(ta.view(torch.int32), tb.view(torch.int32)), name


def make_scene(degree: int, counts: list[int]) -> ply4d.Scene4D:
    return ply4d.Scene4D(
        static=random_gaussians(6, degree, seed=1),
        dynamic=[random_gaussians(n, degree, seed=10 + t) for t, n in enumerate(counts)],
        timestamps=[t * 0.1 for t in range(len(counts))],
        fps=10.0,
        camera={"position": [0.5, -1.0, 2.0], "params": {"width": 4096, "height": 2048}},
        provenance={"tool_version": "0.1.0", "config_hash": "deadbeef"},
        extra={"seed": 7, "note": "test ✓"},
    )


# --- plain .ply ----------------------------------------------------------------------


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("n", [0, 1, 300])
def test_ply_round_trip_bit_exact(tmp_path: Path, degree: int, n: int) -> None:
    g = random_gaussians(n, degree, seed=degree * 100 + n)
    path = tmp_path / "g.ply"
    ply4d.write_ply(path, g)
    assert_bit_equal(ply4d.read_ply(str(path)), g)
    assert os.listdir(tmp_path) == ["g.ply"], "the temporary file must be renamed away"


def test_train1000_reads_and_rewrites_byte_identical(tmp_path: Path) -> None:
    g = ply4d.read_ply(TRAIN)
    assert len(g) == 1000
    assert g.sh_degree == 3
    norms = g.quats.norm(dim=1)
    # Raw quaternions are kept as stored: |q| spans about 0.64..1.32 in this file.
    assert norms.min() < 0.7 and norms.max() > 1.3
    assert g.means[:, 0].min() < -12.9 and g.means[:, 2].max() > 13.7
    # The file has the writer's exact layout (normals are 0), so a rewrite is the same bytes.
    out = tmp_path / "train.ply"
    ply4d.write_ply(out, g)
    assert out.read_bytes() == TRAIN.read_bytes()


def test_guitar_reads() -> None:
    g = ply4d.read_ply(GUITAR)
    assert len(g) == 90_854
    assert g.sh_degree == 0
    torch.testing.assert_close(g.quats.norm(dim=1), torch.ones(len(g)), atol=1e-5, rtol=0)


def compressed_chunks(path: Path) -> np.ndarray:
    """The (chunks, 18) float32 chunk table of a SuperSplat compressed .ply."""
    data = path.read_bytes()
    body = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:body].decode()
    n_chunks = int(header.split("element chunk ")[1].split()[0])
    return np.frombuffer(data, dtype="<f4", count=n_chunks * 18, offset=body).reshape(-1, 18)


def test_compressed_guitar_matches_decoded_guitar() -> None:
    packed = ply4d.read_ply(GUITAR_COMPRESSED)
    plain = ply4d.read_ply(GUITAR)
    assert len(packed) == len(plain) == 90_854
    assert packed.sh_degree == 0

    # Positions: within one quantisation step of their chunk (11/10/11 bits over min..max).
    chunks = torch.from_numpy(compressed_chunks(GUITAR_COMPRESSED).copy())
    chunk_of = torch.arange(len(plain)) // 256
    extent = chunks[chunk_of, 3:6] - chunks[chunk_of, 0:3]
    step = extent / torch.tensor([2047.0, 1023.0, 2047.0])
    assert ((packed.means - plain.means).abs() <= step + 1e-6).all()
    # The other attributes went through the same decoder in float64 for the reference file:
    # log-scales and rotations agree to float32 rounding, colours (f_dc ~ rgb / C0) to 1e-4,
    # opacity logits (up to ±13.8 at alpha = 1 - 1e-6) to 1e-3.
    torch.testing.assert_close(packed.log_scales, plain.log_scales, atol=1e-5, rtol=0)
    torch.testing.assert_close(packed.quats, plain.quats, atol=1e-5, rtol=0)
    torch.testing.assert_close(packed.sh, plain.sh, atol=1e-4, rtol=0)
    torch.testing.assert_close(packed.opacity_logits, plain.opacity_logits, atol=1e-3, rtol=0)


# --- .ply4d --------------------------------------------------------------------------


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_ply4d_round_trip_bit_exact(tmp_path: Path, degree: int) -> None:
    scene = make_scene(degree, [4, 0, 9])
    path = tmp_path / "scene.ply4d"
    ply4d.write(str(path), scene)
    back = ply4d.read(path)
    assert back.num_times == 3
    assert back.timestamps == scene.timestamps  # exact f64 through the JSON header
    assert back.fps == scene.fps
    assert back.camera == scene.camera
    assert back.provenance == scene.provenance
    assert back.extra == scene.extra
    assert_bit_equal(back.static, scene.static)
    for a, b in zip(back.dynamic, scene.dynamic, strict=True):
        assert_bit_equal(a, b)
    assert_bit_equal(back.at(2), scene.at(2))
    assert len(back.at(1)) == 6
    assert os.listdir(tmp_path) == ["scene.ply4d"]


@pytest.mark.parametrize("antialiased", [False, True])
def test_the_rasteriser_mode_round_trips_and_older_files_are_classic(
    tmp_path: Path, antialiased: bool
) -> None:
    """The header records the mode a scene was trained in; a file written before the key
    existed (the same header without it) reads as classic."""
    scene = make_scene(1, [2])
    scene.antialiased = antialiased
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, scene)
    assert ply4d.read(path).antialiased is antialiased
    assert ply4d.open(path).header["antialiased"] is antialiased
    # The same file with the key blanked out (spaces: nothing moves) and the header CRC
    # made again, as a writer before the key would have left it.
    data = bytearray(path.read_bytes())
    json_len, sections = struct.unpack_from("<II", data, 12)
    key = f'"antialiased":{str(antialiased).lower()},'.encode()
    start = data.index(key, 32, 32 + json_len)
    data[start : start + len(key)] = b" " * len(key)
    header_and_table = bytes(data[32 : 32 + json_len + 40 * sections])
    struct.pack_into("<I", data, 20, zlib.crc32(header_and_table))
    older = tmp_path / "older.ply4d"
    older.write_bytes(bytes(data))
    assert b'"antialiased"' not in older.read_bytes()
    back = ply4d.read(older)
    assert back.antialiased is False
    assert_bit_equal(back.at(0), scene.at(0))


def test_ply4d_empty_scene(tmp_path: Path) -> None:
    empty = ply4d.Scene4D(Gaussians.empty(2), [], [], fps=24.0)
    path = tmp_path / "empty.ply4d"
    ply4d.write(path, empty)
    back = ply4d.read(path)
    assert back.num_times == 0
    assert len(back.static) == 0 and back.static.sh_degree == 2
    assert back.provenance["tool_version"] == "0.1.0"
    f = ply4d.open(path)
    assert f.header["bounds"] is None
    with pytest.raises(ply4d.TimeError, match="no timestamps"):
        f.at(0)


def test_ply4d_lazy_open(tmp_path: Path) -> None:
    scene = make_scene(1, [3, 5])
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, scene)
    f = ply4d.open(path)
    assert f.num_times == 2
    h = f.header
    assert h["format_version"] == 1
    assert h["sh_degree"] == 1
    assert h["timestamps"] == [0.0, 0.1]
    assert h["provenance"]["config_hash"] == "deadbeef"
    all_means = torch.cat([scene.static.means, *[g.means for g in scene.dynamic]])
    finite = all_means[torch.isfinite(all_means).all(dim=1)]
    assert h["bounds"]["min"] == pytest.approx(finite.min(dim=0).values.tolist())
    assert h["bounds"]["max"] == pytest.approx(finite.max(dim=0).values.tolist())
    f.verify()
    assert_bit_equal(f.static(), scene.static)
    assert_bit_equal(f.dynamic(1), scene.dynamic[1])
    assert_bit_equal(f.at(0), scene.at(0))
    with pytest.raises(ply4d.TimeError):
        f.dynamic(-1)


def test_streaming_writer_matches_write(tmp_path: Path) -> None:
    scene = make_scene(2, [3, 0, 4])
    ply4d.write(tmp_path / "whole.ply4d", scene)
    streamed = tmp_path / "streamed.ply4d"
    with ply4d.Ply4dWriter(streamed, scene.static) as w:
        for g in scene.dynamic:
            w.push(g)
        w.finish(scene.timestamps, scene.fps, scene.camera, scene.provenance, scene.extra)
        with pytest.raises(ValueError, match="already finished"):
            w.push(scene.dynamic[0])
    assert streamed.read_bytes() == (tmp_path / "whole.ply4d").read_bytes()

    # An exception inside the block abandons the file: nothing new appears.
    with (
        pytest.raises(RuntimeError),
        ply4d.Ply4dWriter(tmp_path / "abandoned.ply4d", scene.static) as w,
    ):
        w.push(scene.dynamic[0])
        raise RuntimeError("pipeline failed")
    assert sorted(os.listdir(tmp_path)) == ["streamed.ply4d", "whole.ply4d"]

    with ply4d.Ply4dWriter(tmp_path / "x.ply4d", scene.static) as w:
        with pytest.raises(ValueError, match="SH degree 3, above the static set's 2"):
            w.push(random_gaussians(2, 3, seed=0))
        w.push(scene.dynamic[0])
        with pytest.raises(ValueError, match="2 timestamps but 1 dynamic sets"):
            w.finish([0.0, 1.0], fps=1.0)


def test_ply4d_pads_lower_sh_degrees(tmp_path: Path) -> None:
    scene = make_scene(2, [3])
    scene.dynamic[0] = random_gaussians(3, 0, seed=5)
    path = tmp_path / "mixed.ply4d"
    ply4d.write(path, scene)
    back = ply4d.read(path)
    assert back.dynamic[0].sh_degree == 2
    assert_bit_equal(back.dynamic[0], scene.dynamic[0].with_sh_degree(2))


def test_export_is_a_plain_ply_of_at_t(tmp_path: Path) -> None:
    scene = make_scene(3, [2, 7])
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, scene)
    out = tmp_path / "t1.ply"
    ply4d.export(path, 1, out)
    assert_bit_equal(ply4d.read_ply(out), scene.at(1))
    assert out.read_bytes()[:4] == b"ply\n"


def test_export_of_an_antialiased_scene_is_baked_for_classic_viewers(tmp_path: Path) -> None:
    """Not the stored bytes: the set baked at the training views (share_formats), the
    extreme rows (a mean at 3·10³⁸, an infinite opacity) included."""
    scene = make_scene(3, [2, 7])
    scene.antialiased = True
    scene.camera = {"position": [0.5, -1.0, 2.0], "params": {"fov_deg": 80.0, "view_size": 512}}
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, scene)
    out = tmp_path / "t1.ply"
    ply4d.export(path, 1, out)
    focal = 512 / (2 * math.tan(math.radians(40.0)))
    baked = bake_antialiasing(scene.at(1), [0.5, -1.0, 2.0], focal)
    assert_bit_equal(ply4d.read_ply(out), baked)
    assert not torch.equal(baked.opacity_logits, scene.at(1).opacity_logits)


def test_ply4d_layout_matches_spec(tmp_path: Path) -> None:
    """Parse a file by hand following docs/ply4d.md, and cut one section out by copying."""
    scene = make_scene(1, [3, 0])
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, scene)
    data = path.read_bytes()
    magic, version, json_len, n_sections, header_crc = struct.unpack_from("<8sIIII", data)
    assert magic == b"\x89PLY4D\r\n"
    assert (version, n_sections) == (1, 3)
    table_start = 32 + json_len
    table = data[table_start : table_start + 40 * n_sections]
    assert zlib.crc32(data[32:table_start] + table) == header_crc
    assert json.loads(data[32:table_start])["timestamps"] == [0.0, 0.1]
    entries = [struct.unpack_from("<IIQQQI", table, 40 * i) for i in range(n_sections)]
    assert [(kind, t) for kind, t, *_ in entries] == [(0, 0), (1, 0), (1, 1)]
    for i, (_, _, offset, length, count, crc) in enumerate(entries):
        assert offset % 64 == 0
        blob = data[offset : offset + length]
        assert zlib.crc32(blob) == crc
        cut = tmp_path / f"section{i}.ply"
        cut.write_bytes(blob)
        expected = scene.static if i == 0 else scene.dynamic[i - 1]
        assert count == len(expected)
        assert_bit_equal(ply4d.read_ply(cut), expected)


def test_ply4d_real_scene(tmp_path: Path) -> None:
    train = ply4d.read_ply(TRAIN)
    scene = ply4d.Scene4D(train[:600], [train[600:], train[600:800]], [0.0, 0.5], fps=2.0)
    path = tmp_path / "train.ply4d"
    ply4d.write(path, scene)
    assert_bit_equal(ply4d.open(path).at(0), train)


# --- version 2: one spacetime set ---------------------------------------------------

MODEL = TimeModel(period=5, colour_harmonics=2, position_harmonics=1)


def make_spacetime_scene(degree: int, n: int, model: TimeModel = MODEL) -> ply4d.Scene4D:
    scene = make_scene(degree, [])
    scene.dynamic = random_spacetime(n, degree, model, seed=3)
    scene.timestamps = [t / 8 for t in range(model.period)]
    return scene


@pytest.mark.parametrize("degree", [0, 3])
def test_ply4d_version_2_round_trip_bit_exact(tmp_path: Path, degree: int) -> None:
    scene = make_spacetime_scene(degree, 40)
    assert isinstance(scene.dynamic, SpacetimeGaussians)
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, scene)
    back = ply4d.read(path)
    assert isinstance(back.dynamic, SpacetimeGaussians)
    assert_bit_equal_spacetime(back.dynamic, scene.dynamic)
    assert_bit_equal(back.static, scene.static)
    assert back.num_times == MODEL.period
    assert (back.timestamps, back.fps, back.extra) == (scene.timestamps, scene.fps, scene.extra)
    f = ply4d.open(path)
    assert (f.version, f.num_times) == (2, MODEL.period)
    assert f.header["motion"] == {"period": 5, "colour_harmonics": 2, "position_harmonics": 1}
    f.verify()
    assert f.spacetime() is f.spacetime(), "decoded once"
    for t in range(MODEL.period):
        # The reference evaluation, bit for bit, whichever way the scene is read.
        assert_bit_equal(back.at(t), scene.at(t))
        assert_bit_equal(f.at(t), scene.at(t))
        assert_bit_equal(f.dynamic(t), scene.dynamic.at(t))
    assert_bit_equal(f.at(MODEL.period), scene.at(0))  # the loop's end is its start
    with pytest.raises(ply4d.TimeError, match="≥ 0"):
        back.at(-1)
    assert os.listdir(tmp_path) == ["scene.ply4d"]


def test_ply4d_version_2_pads_lower_sh_degrees(tmp_path: Path) -> None:
    scene = make_spacetime_scene(0, 3)
    scene.static = random_gaussians(4, 2, seed=8)
    path = tmp_path / "mixed.ply4d"
    ply4d.write(path, scene)
    back = ply4d.read(path)
    assert isinstance(back.dynamic, SpacetimeGaussians)
    assert back.dynamic.canonical.sh_degree == 2
    assert_bit_equal(back.dynamic.canonical, scene.dynamic.canonical.with_sh_degree(2))
    with (
        ply4d.Ply4dWriter(tmp_path / "x.ply4d", random_gaussians(1, 0, seed=0)) as w,
        pytest.raises(ValueError, match="SH degree 2, above the static set's 0"),
    ):
        w.push_spacetime(back.dynamic)


@pytest.mark.parametrize("antialiased", [False, True])
def test_export_of_a_version_2_scene_is_the_evaluated_set(
    tmp_path: Path, antialiased: bool
) -> None:
    scene = make_spacetime_scene(1, 9)
    scene.antialiased = antialiased
    scene.camera = {"position": [0.5, -1.0, 2.0], "params": {"fov_deg": 80.0, "view_size": 512}}
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, scene)
    out = tmp_path / "t4.ply"
    ply4d.export(path, 4, out)
    expected = scene.at(4)
    if antialiased:
        focal = 512 / (2 * math.tan(math.radians(40.0)))
        expected = bake_antialiasing(expected, [0.5, -1.0, 2.0], focal)
    assert_bit_equal(ply4d.read_ply(out), expected)


def test_ply4d_version_2_layout_matches_spec(tmp_path: Path) -> None:
    """Parse a version-2 file by hand following docs/ply4d.md; its dynamic section, cut
    out, is a 3DGS .ply of the canonical set with the time properties after the standard
    ones."""
    scene = make_spacetime_scene(0, 3, TimeModel(4, 1, 1))
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, scene)
    data = path.read_bytes()
    magic, version, json_len, n_sections, header_crc = struct.unpack_from("<8sIIII", data)
    assert (magic, version, n_sections) == (b"\x89PLY4D\r\n", 2, 2)
    table_start = 32 + json_len
    table = data[table_start : table_start + 40 * n_sections]
    assert zlib.crc32(data[32:table_start] + table) == header_crc
    header = json.loads(data[32:table_start])
    assert header["format_version"] == 2
    assert header["timestamps"] == [0.0, 0.125, 0.25, 0.375]
    entries = [struct.unpack_from("<IIQQQI", table, 40 * i) for i in range(n_sections)]
    assert [(kind, t) for kind, t, *_ in entries] == [(0, 0), (1, 0)]
    _, _, offset, length, count, crc = entries[1]
    blob = data[offset : offset + length]
    assert zlib.crc32(blob) == crc and count == 3
    properties = [
        line.split()[-1]
        for line in blob[: blob.index(b"end_header")].decode().splitlines()
        if line.startswith("property")
    ]
    assert properties[-15:] == [
        "rot_3", "t_centre", "t_log_width",
        "f_dc_0_cos_1", "f_dc_1_cos_1", "f_dc_2_cos_1", "f_dc_0_sin_1", "f_dc_1_sin_1",
        "f_dc_2_sin_1",
        "x_cos_1", "y_cos_1", "z_cos_1", "x_sin_1", "y_sin_1", "z_sin_1",
    ]  # fmt: skip
    cut = tmp_path / "dynamic.ply"
    cut.write_bytes(blob)
    assert isinstance(scene.dynamic, SpacetimeGaussians)
    assert_bit_equal(ply4d.read_ply(cut), scene.dynamic.canonical)


def test_version_2_scenes_and_files_refuse_what_they_cannot_be(tmp_path: Path) -> None:
    s = random_spacetime(2, 0, MODEL, seed=0)
    with pytest.raises(ValueError, match="4 timestamps but its spacetime set loops over 5"):
        ply4d.Scene4D(Gaussians.empty(), s, [0.0, 1.0, 2.0, 3.0], fps=1.0)
    path = tmp_path / "v1.ply4d"
    ply4d.write(path, make_scene(0, [2]))
    f = ply4d.open(path)
    assert f.version == 1
    with pytest.raises(ply4d.FormatError, match="stores one dynamic set per timestamp"):
        f.spacetime()


# --- time: any real t ≥ 0, taken modulo the loop --------------------------------------


def test_a_version_2_scene_is_evaluated_at_any_real_time(tmp_path: Path) -> None:
    """Between its frames a spacetime set moves on (at 2.5 it is neither frame 2 nor 3), and
    a time one or more loops on is the same time, whichever way the scene is read."""
    scene = make_spacetime_scene(1, 12)
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, scene)
    back, f = ply4d.read(path), ply4d.open(path)
    assert isinstance(scene.dynamic, SpacetimeGaussians)
    expected = Gaussians.cat([scene.static, scene.dynamic.at(2.5)])
    for at in (scene.at, back.at, f.at):
        assert_bit_equal(at(2.5), expected)
        for later in (2.5 + MODEL.period, 2.5 + 3 * MODEL.period):
            assert_bit_equal(at(later), expected)
    assert_bit_equal(f.dynamic(2.5), scene.dynamic.at(2.5))
    assert_bit_equal(scene.dynamic_at(0.25 + MODEL.period), scene.dynamic.at(0.25))
    between = scene.dynamic.at(2.5)
    for frame in (2, 3):
        assert not torch.equal(between.means, scene.dynamic.at(frame).means), frame
        assert not torch.equal(between.sh, scene.dynamic.at(frame).sh), frame
    assert f.shown_time(2.5) == 2.5 and f.shown_time(7.5) == 2.5
    out = tmp_path / "t2.5.ply"
    ply4d.export(path, 2.5, out)
    assert_bit_equal(ply4d.read_ply(out), expected)


def test_a_version_1_scene_holds_each_timestamp_until_the_next(tmp_path: Path) -> None:
    scene = make_scene(1, [3, 5, 4])
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, scene)
    back, f = ply4d.read(path), ply4d.open(path)
    # time → the timestamp shown: ⌊t mod 3⌋
    held = {0.0: 0, 0.99: 0, 1: 1, 1.5: 1, 2.999: 2, 3.0: 0, 7.25: 1, 3 * 1000 + 2.5: 2}
    for t, timestamp in held.items():
        expected = Gaussians.cat([scene.static, scene.dynamic[timestamp]])
        for at in (scene.at, back.at, f.at):
            assert_bit_equal(at(t), expected)
        assert_bit_equal(f.dynamic(t), scene.dynamic[timestamp])
        assert f.shown_time(t) == timestamp
    out = tmp_path / "t1.5.ply"
    ply4d.export(path, 1.5, out)  # the stored sections of timestamp 1, copied
    ply4d.export(path, 1, tmp_path / "t1.ply")
    assert out.read_bytes() == (tmp_path / "t1.ply").read_bytes()


@pytest.mark.parametrize("t", [math.nan, -1, -0.5, math.inf, -math.inf])
def test_a_time_that_is_not_one_is_a_time_error(tmp_path: Path, t: float) -> None:
    """NaN, infinite or negative: one error class, an InputError (the command line's one
    `error:` line, exit 2), from every reader of either version."""
    from pano4d.errors import InputError

    assert issubclass(ply4d.TimeError, InputError) and issubclass(ply4d.TimeError, ValueError)
    out = tmp_path / "out.ply"
    for name, scene in (("v1", make_scene(0, [2, 3])), ("v2", make_spacetime_scene(0, 4))):
        path = tmp_path / f"{name}.ply4d"
        ply4d.write(path, scene)
        f = ply4d.open(path)
        reads = [functools.partial(read, t) for read in
                 (scene.at, scene.dynamic_at, f.at, f.dynamic, f.shown_time)]  # fmt: skip
        reads += [
            functools.partial(f.export, t, out),
            functools.partial(ply4d.export, path, t, out),
        ]
        for read in reads:
            with pytest.raises(ply4d.TimeError, match=f"time {t:g}: .*frames ≥ 0"):
                read()
    assert not out.exists()


def test_playback_times_follow_the_scene_rate() -> None:
    """A 30 fps playback of an 8 fps scene advances 8/30 of a frame a sample; a sample that
    lands on a frame is that frame whatever the rates' rounding."""
    times = [ply4d.playback_time(i, 30.0, 8.0) for i in range(16)]
    assert times[1] == pytest.approx(8 / 30) and times[15] == 4.0
    assert [math.floor(t) for t in times[:9]] == [0, 0, 0, 0, 1, 1, 1, 1, 2]
    assert 0.3 / 0.1 < 3 and ply4d.playback_time(1, 0.1, 0.3) == 3.0
    assert ply4d.loop_samples(6, 8.0, 30.0) == 23  # ⌈6 · 30 / 8⌉
    assert ply4d.loop_samples(14, 8.0, 8.0) == 14
    assert ply4d.loop_samples(3, 0.3, 0.1) == 1
    assert ply4d.loop_samples(0, 8.0, 30.0) == 0


# --- errors --------------------------------------------------------------------------


def test_ply_errors_name_the_problem(tmp_path: Path) -> None:
    data = TRAIN.read_bytes()
    truncated = tmp_path / "truncated.ply"
    truncated.write_bytes(data[:-10])
    with pytest.raises(ValueError, match=r"truncated PLY: element 'vertex' needs 248000 bytes"):
        ply4d.read_ply(truncated)

    ascii_ply = tmp_path / "ascii.ply"
    ascii_ply.write_text(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n"
    )
    with pytest.raises(ValueError, match="unsupported PLY format 'ascii'"):
        ply4d.read_ply(ascii_ply)

    header_end = data.index(b"end_header")
    no_opacity = data[:header_end].replace(b"property float opacity\n", b"property float alpha\n")
    missing = tmp_path / "missing.ply"
    missing.write_bytes(no_opacity + data[header_end:])
    with pytest.raises(ValueError, match="missing required property 'opacity'"):
        ply4d.read_ply(missing)

    not_ply = tmp_path / "image.ply"
    not_ply.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    with pytest.raises(ValueError, match="not a PLY file"):
        ply4d.read_ply(not_ply)

    with pytest.raises(OSError, match="cannot read"):
        ply4d.read_ply(tmp_path / "absent.ply")


def test_ply4d_errors_name_the_problem(tmp_path: Path) -> None:
    path = tmp_path / "scene.ply4d"
    ply4d.write(path, make_scene(1, [3, 4]))
    good = path.read_bytes()
    bad = tmp_path / "bad.ply4d"

    bad.write_bytes(good[:-100])
    with pytest.raises(ValueError, match="lies outside the data area"):
        ply4d.open(bad)
    bad.write_bytes(good[:16])
    with pytest.raises(ValueError, match=r"truncated \.ply4d"):
        ply4d.open(bad)

    flipped = bytearray(good)
    flipped[-5] ^= 0x01  # inside the last dynamic set
    bad.write_bytes(flipped)
    f = ply4d.open(bad)  # the header is intact
    f.static()
    with pytest.raises(ValueError, match="checksum mismatch in timestamp 1"):
        f.dynamic(1)
    with pytest.raises(ValueError, match="checksum mismatch in timestamp 1"):
        f.verify()

    header_flip = bytearray(good)
    header_flip[40] ^= 0x01
    bad.write_bytes(header_flip)
    with pytest.raises(ValueError, match="header checksum mismatch"):
        ply4d.read(bad)

    bad.write_bytes(b"PLY5D\0\0\0" + good[8:])
    with pytest.raises(ValueError, match="wrong magic"):
        ply4d.read(bad)

    with pytest.raises(ValueError, match="wrong magic"):
        ply4d.open(TRAIN)  # a .ply is not a .ply4d

    with pytest.raises(OSError, match="cannot open"):
        ply4d.open(tmp_path / "absent.ply4d")


def test_write_rejects_bad_scenes(tmp_path: Path) -> None:
    scene = make_scene(0, [2])
    scene.fps = float("nan")
    with pytest.raises(ValueError, match="finite"):
        ply4d.write(tmp_path / "nan.ply4d", scene)
    scene = make_scene(0, [2])
    scene.extra = {"tensor": torch.zeros(1)}
    with pytest.raises(ValueError, match="not JSON-serialisable"):
        ply4d.write(tmp_path / "obj.ply4d", scene)
    with pytest.raises(ValueError, match="2 timestamps but 1 dynamic sets"):
        ply4d.Scene4D(scene.static, scene.dynamic, [0.0, 1.0], fps=1.0)
    with pytest.raises(OSError):
        ply4d.write(tmp_path / "no" / "such" / "dir.ply4d", make_scene(0, [1]))
    assert sorted(os.listdir(tmp_path)) == []
