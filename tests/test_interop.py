"""Our files read by readers that are not ours: the .ply that `pano4d export` writes, read by
plyfile (the field layout the 3DGS tools expect) and by gaussforge (the values), must hold
exactly the Gaussians of the .ply4d timestamp it came from.

gaussforge 0.6.0 refuses every SH-degree-0 3DGS .ply ("std::bad_cast", also the reference
train scene with its f_rest fields removed), so it reads the SH-3 export only.
"""

from __future__ import annotations

from pathlib import Path

import gaussforge
import numpy as np
import plyfile
import pytest
import torch
from pano4d_process import pano4d

from pano4d import ply4d
from pano4d.gaussians import Gaussians, sh_coeffs_for_degree


def gaussians(n: int, degree: int, seed: int) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)

    def r(*shape: int) -> torch.Tensor:
        return torch.randn(*shape, generator=gen)

    return Gaussians(r(n, 3), r(n, 3), r(n, 4), r(n), r(n, sh_coeffs_for_degree(degree), 3))


def exported(folder: Path, degree: int) -> tuple[Gaussians, Path]:
    """A 2-timestamp .ply4d, timestamp 1 exported by `pano4d export`; (its Gaussians, .ply)."""
    scene = ply4d.Scene4D(
        static=gaussians(50, degree, seed=1),
        dynamic=[gaussians(20, degree, seed=2), gaussians(30, degree, seed=3)],
        timestamps=[0.0, 0.1],
        fps=10.0,
    )
    path, out = folder / "scene.ply4d", folder / "t1.ply"
    ply4d.write(path, scene)
    result = pano4d("export", path, out, "--time", "1")
    assert result.returncode == 0, result.stderr
    return scene.at(1), out


def layout(degree: int) -> list[str]:
    """The 3DGS reference implementation's vertex properties, in order."""
    rest = 3 * (sh_coeffs_for_degree(degree) - 1)
    return [
        *["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"],
        *(f"f_rest_{i}" for i in range(rest)),
        "opacity",
        *(f"scale_{i}" for i in range(3)),
        *(f"rot_{i}" for i in range(4)),
    ]


@pytest.mark.parametrize("degree", [0, 3])
def test_plyfile_reads_the_3dgs_layout_and_our_values(tmp_path: Path, degree: int) -> None:
    g, path = exported(tmp_path, degree)
    ply = plyfile.PlyData.read(str(path))
    assert [e.name for e in ply.elements] == ["vertex"]
    vertex = ply["vertex"]
    assert [p.name for p in vertex.properties] == layout(degree)
    assert {p.val_dtype for p in vertex.properties} == {"f4"}
    assert vertex.count == len(g)
    v = vertex.data

    def field(*names: str) -> np.ndarray:
        return np.stack([v[name] for name in names], axis=-1)

    assert np.array_equal(field("x", "y", "z"), g.means.numpy())
    assert np.array_equal(field("nx", "ny", "nz"), np.zeros((len(g), 3), np.float32))
    assert np.array_equal(field("f_dc_0", "f_dc_1", "f_dc_2"), g.sh[:, 0, :].numpy())
    k = sh_coeffs_for_degree(degree) - 1
    # f_rest is channel-major: all of red's coefficients, then green's, then blue's.
    if k:
        rest = field(*(f"f_rest_{i}" for i in range(3 * k))).reshape(len(g), 3, k)
        assert np.array_equal(rest.transpose(0, 2, 1), g.sh[:, 1:, :].numpy())
    assert np.array_equal(v["opacity"], g.opacity_logits.numpy())
    assert np.array_equal(field("scale_0", "scale_1", "scale_2"), g.log_scales.numpy())
    assert np.array_equal(field("rot_0", "rot_1", "rot_2", "rot_3"), g.quats.numpy())


def test_gaussforge_reads_our_values(tmp_path: Path) -> None:
    g, path = exported(tmp_path, degree=3)
    result = gaussforge.GaussForge().read(path.read_bytes(), "ply")
    assert "error" not in result, result
    data = result["data"]
    n = len(g)
    assert data["numPoints"] == n
    assert data["meta"]["shDegree"] == 3

    def array(name: str, *shape: int) -> np.ndarray:
        return np.frombuffer(data[name], dtype="<f4").reshape(n, *shape)

    assert np.array_equal(array("positions", 3), g.means.numpy())
    assert np.array_equal(array("scales", 3), g.log_scales.numpy())
    assert np.array_equal(array("rotations", 4), g.quats.numpy())
    assert np.array_equal(array("alphas"), g.opacity_logits.numpy())
    assert np.array_equal(array("colors", 3), g.sh[:, 0, :].numpy())
    assert np.array_equal(array("sh", 15, 3), g.sh[:, 1:, :].numpy())
