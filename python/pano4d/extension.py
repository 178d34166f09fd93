"""The Rust extension ``pano4d._core`` and the objects it takes: one owner for its callers,
the renderer (``pano4d.renderer``), the resident trainer (``pano4d.lift.resident``) and the
file formats (``pano4d.ply4d``).

``core`` is the extension module, typed by its stub (``_core.pyi``) and loaded on first use,
so ``import pano4d`` works without it (the torch rasteriser and the torch trainer need
none). Across it everything is a typed object: a camera crosses as ``_core.View``
(:func:`view`), a Gaussian set as ``_core.GaussianArrays`` (:func:`gaussian_arrays`,
:func:`gaussians_from`), a spacetime set as ``_core.SpacetimeArrays``
(:func:`spacetime_arrays`, :func:`spacetime_from`).
"""

from __future__ import annotations

import importlib
import os
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from pano4d.camera import Camera
from pano4d.gaussians import Gaussians
from pano4d.spacetime import SpacetimeGaussians, TimeModel


class _Extension:
    """Stands for the module until an attribute is read, then imports it (ImportError saying
    how to build it when it is not built) and forwards to it."""

    _module: ModuleType | None = None

    def __getattr__(self, name: str) -> Any:
        if self._module is None:
            # Mesa's device-select Vulkan layer only reorders adapters (we choose our own)
            # and, without a desktop session, prints "XDG_RUNTIME_DIR is invalid" on every
            # start.
            os.environ.setdefault("NODEVICE_SELECT", "1")
            try:
                self._module = importlib.import_module("pano4d._core")
            except ImportError as e:  # pragma: no cover - depends on the build
                raise ImportError(
                    "pano4d._core (the Rust extension) is not built: run `maturin develop "
                    "--release` or `make setup`; backend='torch' works without it"
                ) from e
        return getattr(self._module, name)


if TYPE_CHECKING:
    from pano4d import _core as core
else:
    core = _Extension()


def host(t: torch.Tensor) -> np.ndarray:
    """A tensor as the extension takes it: contiguous float32 on the host, its shape kept."""
    return np.ascontiguousarray(t.detach().to("cpu", torch.float32).numpy())


def flat(t: torch.Tensor) -> np.ndarray:
    """:func:`host` in one dimension."""
    return host(t.reshape(-1))


def view(camera: Camera) -> core.View:
    """``camera`` as the extension's renderer takes it: intrinsics K (3×3), world-to-camera
    rows (3×4), float64, the tan of its view's half field of view and its size."""
    return core.View(
        k=np.ascontiguousarray(camera.K.numpy()),
        world_to_cam=np.ascontiguousarray(camera.world_to_cam[:3].numpy()),
        half_fov_tan=camera.half_fov_tan,
        width=camera.width,
        height=camera.height,
    )


def gaussian_arrays(g: Gaussians) -> core.GaussianArrays:
    """``g`` (or gradients or moments of that shape) as the extension holds a set: float32
    on the host."""
    return core.GaussianArrays(**g.to_numpy())


def gaussians_from(arrays: core.GaussianArrays, device: torch.device | str = "cpu") -> Gaussians:
    """The inverse of :func:`gaussian_arrays`, on ``device``."""
    return Gaussians.from_numpy(
        {
            "means": arrays.means,
            "log_scales": arrays.log_scales,
            "quats": arrays.quats,
            "opacity_logits": arrays.opacity_logits,
            "sh": arrays.sh,
        },
        device,
    )


def spacetime_arrays(s: SpacetimeGaussians) -> core.SpacetimeArrays:
    """``s`` as the extension holds a spacetime set: float32 on the host."""
    m = s.model
    return core.SpacetimeArrays(
        canonical=gaussian_arrays(s.canonical),
        period=m.period,
        colour_harmonics=m.colour_harmonics,
        position_harmonics=m.position_harmonics,
        time_centre=host(s.time_centre),
        time_log_width=host(s.time_log_width),
        colour_terms=host(s.colour_terms),
        position_terms=host(s.position_terms),
    )


def spacetime_from(
    arrays: core.SpacetimeArrays, device: torch.device | str = "cpu"
) -> SpacetimeGaussians:
    """The inverse of :func:`spacetime_arrays`, on ``device``."""

    def tensor(values: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(values).to(device)

    return SpacetimeGaussians(
        TimeModel(arrays.period, arrays.colour_harmonics, arrays.position_harmonics),
        gaussians_from(arrays.canonical, device),
        time_centre=tensor(arrays.time_centre),
        time_log_width=tensor(arrays.time_log_width),
        colour_terms=tensor(arrays.colour_terms),
        position_terms=tensor(arrays.position_terms),
    )
