"""Write tests/vectors/geometry.json: the shared geometry test vectors.

Python computes them once; tests in both languages (tests/test_sphere.py and
crates/splat-core/tests/geometry_vectors.rs) check their implementation against them, so
the two cannot drift. Regenerate only when the conventions in docs/design.md change:
    .venv/bin/python tests/vectors/make_geometry.py
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import torch

from pano4d import sphere
from pano4d.camera import Camera

OUT = Path(__file__).with_name("geometry.json")


def main() -> None:
    gen = torch.Generator().manual_seed(1234)
    w, h = 4096, 2048
    special = [(0.0, 0.0), (w, 0.0), (0.0, h), (w / 2, h / 2), (0.5, 0.5), (w - 0.5, h - 0.5),
               (1e-7, h / 3), (w - 1e-7, h / 3), (w / 4, 1e-7), (3 * w / 4, h - 1e-7)]  # fmt: skip
    rand = torch.rand(20, 2, generator=gen, dtype=torch.float64) * torch.tensor([w, h])
    uv = torch.tensor(special, dtype=torch.float64)
    uv = torch.cat([uv, rand])
    dirs = sphere.equirect_to_dir(uv[:, 0], uv[:, 1], w, h)
    equirect = [
        {"u": float(a), "v": float(b), "width": w, "height": h, "dir": d.tolist()}
        for (a, b), d in zip(uv.tolist(), dirs, strict=True)
    ]

    probe = torch.cat([
        torch.tensor([[1.0, 0, 0], [0, -1.0, 0], [-1.0, 0, 0], [-1.0, 1e-12, 0], [-1.0, -1e-12, 0],
                      [0, 0, 1.0], [0, 0, -1.0], [3.0, 4.0, 5.0]], dtype=torch.float64),
        torch.randn(12, 3, generator=gen, dtype=torch.float64),
    ])  # fmt: skip
    pu, pv = sphere.dir_to_equirect(probe, w, h)
    dir_to_equirect = [
        {"dir": d.tolist(), "width": w, "height": h, "u": float(a), "v": float(b)}
        for d, a, b in zip(probe, pu, pv, strict=True)
    ]

    cameras = []
    specs = [
        (90.0, 64, 48, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0)),
        (80.0, 512, 512, (0.3, -0.2, 0.1), (0.2, 0.9, -0.3)),
        (60.0, 17, 13, (1.0, 2.0, 3.0), (0.0, 0.0, 1.0)),  # straight up: the no-roll fallback
        (60.0, 17, 13, (0.0, 0.0, 0.0), (0.0, 0.0, -2.0)),  # straight down
    ]
    for fov, cw, ch, pos, fwd in specs:
        cam = Camera.from_fov(fov, cw, ch, pos, fwd)
        pts = (
            torch.tensor(pos, dtype=torch.float64)
            + torch.randn(5, 3, generator=gen, dtype=torch.float64) * 2
        )
        pts[0] = torch.tensor(pos, dtype=torch.float64) + 3.0 * cam.forward
        puv, pz = cam.project(pts)
        uvs = torch.tensor(
            [[0.5, 0.5], [cw / 2, ch / 2], [cw - 0.5, ch - 0.5]], dtype=torch.float64
        )
        depths = torch.tensor([0.1, 7.0, 1e4], dtype=torch.float64)
        cameras.append({
            "fov_deg": fov, "width": cw, "height": ch, "position": list(pos), "forward": list(fwd),
            "up": [0.0, 0.0, 1.0], "K": cam.K.tolist(),
            "world_to_cam": cam.world_to_cam[:3].tolist(),
            "project": [{"point": p.tolist(), "uv": q.tolist(), "z": float(z)}
                        for p, q, z in zip(pts, puv, pz, strict=True)],
            "unproject_z": [{"uv": q.tolist(), "z": float(z), "point": cam.unproject(q, z).tolist()}
                            for q, z in zip(uvs, depths, strict=True)],
            "unproject_ray": [{"uv": q.tolist(), "ray_length": float(z),
                               "point": cam.unproject(q, z, kind="ray").tolist()}
                              for q, z in zip(uvs, depths, strict=True)],
        })  # fmt: skip

    layouts = [{"n": n, "directions": sphere.view_directions(n).tolist()} for n in (20, 7, 1)]
    data = {
        "about": "Shared geometry vectors (docs/design.md); written by make_geometry.py",
        "tolerance": 1e-9,
        "equirect_to_dir": equirect,
        "dir_to_equirect": dir_to_equirect,
        "cameras": cameras,
        "view_directions": layouts,
        "half_pi_check": math.pi / 2,
    }
    OUT.write_text(json.dumps(data, indent=1) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
