"""pano4d: one 360° panorama in, a 4D Gaussian scene out.

Public API (DESIGN.md): ``sphere``, ``Gaussians``, ``Camera``, ``render``, ``ply4d``,
``synth``. Modules that need the Rust extension load it on first use, so geometry and
configuration work even before the extension is built.
"""

from __future__ import annotations

import importlib
from typing import Any

from pano4d.camera import Camera
from pano4d.gaussians import Gaussians

__version__ = "0.1.0"
__all__ = ["Camera", "Gaussians", "ply4d", "render", "sphere", "synth"]

_LAZY_MODULES = {"sphere", "ply4d", "synth"}


def __getattr__(name: str) -> Any:
    if name in _LAZY_MODULES:
        return importlib.import_module(f"pano4d.{name}")
    if name == "render":
        return importlib.import_module("pano4d.render").render
    raise AttributeError(f"module 'pano4d' has no attribute {name!r}")
