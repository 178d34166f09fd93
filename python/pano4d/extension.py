"""The Rust extension ``pano4d._core`` and the arrays it takes: one owner for its GPU callers,
the renderer (``pano4d.renderer``) and the resident trainer (``pano4d.lift.resident``).

The extension is loaded on first use, so ``import pano4d`` works without it (the torch
rasteriser and the torch trainer need none).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import torch

from pano4d.camera import Camera


def core() -> Any:
    """The loaded extension module; ImportError saying how to build it when it is not."""
    # Mesa's device-select Vulkan layer only reorders adapters (we choose our own) and,
    # without a desktop session, prints "XDG_RUNTIME_DIR is invalid" on every start.
    os.environ.setdefault("NODEVICE_SELECT", "1")
    try:
        from pano4d import _core
    except ImportError as e:  # pragma: no cover - depends on the build
        raise ImportError(
            "pano4d._core (the Rust extension) is not built: run `maturin develop --release` "
            "or `make setup`; backend='torch' works without it"
        ) from e
    return _core


def flat(t: torch.Tensor) -> np.ndarray:
    """A tensor as the extension takes it: contiguous float32 on the host, one dimension."""
    return np.ascontiguousarray(t.detach().to("cpu", torch.float32).reshape(-1).numpy())


def camera_arrays(camera: Camera) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """A camera's intrinsics K (3×3), world-to-camera rows (3×4), float64, and the tan of
    its view's half field of view, as the extension takes them (its size goes separately
    where the call needs it)."""
    return (
        np.ascontiguousarray(camera.K.numpy()),
        np.ascontiguousarray(camera.world_to_cam[:3].numpy()),
        camera.half_fov_tan,
    )
