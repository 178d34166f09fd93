"""A synthetic scene on disk (``pano4d synth``): the panorama, its depth and mask, a
scene.yaml ready to train, the true animation and the ground-truth views."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from pano4d.fsutil import write_json_atomic, write_text_atomic
from pano4d.images import write_image
from pano4d.progress import Bars, Task
from pano4d.synth.scene import SynthScene, make_scene

SCENE_YAML = """\
# Synthetic {kind} written by `pano4d synth` (seed {seed}). Train with: pano4d train scene.yaml
panorama: panorama.png
regions:
  - mask: mask.png          # white = moves ({moving})
    motion: {{direction_deg: {direction}, speed: {speed:.6g}}}  # {what}, degrees of arc per frame
animate:
  backend: flow
  frames: {frames}
depth:
  backend: layout           # or {{backend: file, path: depth.exr}} to train on the exact depth
  camera_height: {camera_height:g}
preset: draft
seed: {seed}
output: output
"""


def write_scene(
    out_dir: str | Path,
    scene: SynthScene,
    seed: int | None = None,
    progress: Task | None = None,
) -> Path:
    """Write the file set of ``scene`` into ``out_dir`` (docs/design.md, "Files a run
    writes"); returns scene.yaml's path.

    ``seed`` (optional) must be the scene's own; it is what scene.yaml records. Frame and
    view PNGs of an earlier run in the same folder are replaced, not left behind.
    """
    if seed is not None and seed != scene.seed:
        raise ValueError(f"scene was made with seed {scene.seed}, not {seed}")
    report = (progress or Task()).advance
    out = Path(out_dir)
    gt = out / "gt"
    for folder in (gt / "frames", gt / "views"):
        if folder.exists():
            shutil.rmtree(folder)
    write_image(out / "panorama.png", scene.panorama.numpy())
    write_image(out / "depth.exr", scene.depth.numpy()[..., None])
    write_image(out / "mask.png", scene.mask.numpy().astype(np.float32)[..., None])
    report("wrote the panorama, depth and mask")
    for t, frame in enumerate(scene.frames):
        write_image(gt / "frames" / f"{t:04d}.png", frame.numpy())
        report(f"wrote frame {t}")
    entries = []
    for i, view in enumerate(scene.views):
        name = f"views/{i:04d}.png"
        write_image(gt / name, view.image.numpy())
        entries.append({"image": name, **view.to_dict()})
    write_json_atomic(
        gt / "views.json",
        {
            "kind": scene.kind,
            "seed": scene.seed,
            "frames": len(scene.frames),
            "scene": scene.world.metadata(),
            "views": entries,
        },
    )
    report("wrote the views")
    yaml_path = out / "scene.yaml"
    hint = scene.world.motion_hint()
    write_text_atomic(
        yaml_path,
        SCENE_YAML.format(
            kind=scene.kind,
            seed=scene.seed,
            moving=scene.world.moving_parts,
            direction=hint.direction_deg,
            speed=hint.speed,
            what=hint.what,
            frames=len(scene.frames),
            camera_height=scene.world.camera_height,
        ),
    )
    return yaml_path


def run_synth(
    out: Path, width: int, height: int, frames: int, seed: int, views: int = 8,
    kind: str = "landscape",
) -> Path:  # fmt: skip
    """``pano4d synth``: make the scene (of ``kind``, see SCENE_KINDS) and write it with a
    progress bar; returns scene.yaml."""
    steps = 3 + 1 + frames + 1  # make_scene stages, panorama files, frames, views
    with Bars(transient=True) as bars:
        task = bars.task(f"synth {kind} {width}x{height}, {frames} frames", steps)
        scene = make_scene(seed, width, height, frames, views=views, kind=kind, progress=task)
        return write_scene(out, scene, progress=task)
