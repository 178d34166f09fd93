"""pano4d: one 360° panorama in, a 4D Gaussian scene out.

Public API (docs/design.md): ``sphere``, ``Gaussians``, ``Camera``, ``render``, ``ply4d``,
``synth``.
"""

from __future__ import annotations

import importlib
from typing import Any

from pano4d.camera import Camera
from pano4d.gaussians import Gaussians

# `pano4d.render` is the function (docs/design.md's API); its module is pano4d.renderer.
# The Rust extension itself is loaded on first use (pano4d.extension).
from pano4d.renderer import render

__version__ = "0.1.0"
__all__ = ["Camera", "Gaussians", "ply4d", "render", "sphere", "synth"]

_LAZY_MODULES = {"sphere", "ply4d", "synth"}


def __getattr__(name: str) -> Any:
    if name in _LAZY_MODULES:
        return importlib.import_module(f"pano4d.{name}")
    raise AttributeError(f"module 'pano4d' has no attribute {name!r}")
