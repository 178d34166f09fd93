"""Synthetic 4D scenes with exact ground truth (``pano4d synth``).

A scene is an analytic world rendered by ray casting, deterministic from a seed: the
panorama, its ray-length depth, the motion mask, the looping animation and displaced
perspective views (the novel-view test set) all come from the same ray caster, so a ray from
any camera position has an exact answer.

``make_scene(seed, width, height, frames)`` renders one (``scene``), ``write_scene`` writes
it (``files``), ``run_synth`` does both with a progress bar. ``world`` is what a scene kind
provides; ``landscape`` is the outdoor kind (``terrain``, ``objects``, ``shading``, built from
``textures``); ``views`` renders the panorama and the ground-truth views of any kind.
"""

from pano4d.synth.files import run_synth, write_scene
from pano4d.synth.scene import SynthScene, make_scene

__all__ = ["SynthScene", "make_scene", "run_synth", "write_scene"]
