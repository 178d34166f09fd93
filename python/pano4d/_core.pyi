"""Types of ``pano4d._core``, the Rust extension (crates/splat-core/src/python): the one
place its names, arguments and return types are written down for Python. Load it through
``pano4d.extension.core``. tests/test_core_stub.py checks that the module and this stub name
the same things."""

from collections.abc import Sequence
from os import PathLike

import numpy as np
import numpy.typing as npt

_F32 = npt.NDArray[np.float32]
_F64 = npt.NDArray[np.float64]
_Path = str | PathLike[str]

__version__: str

# --- Gaussian sets (python/gaussians.rs) -----------------------------------------------------
class GaussianArrays:
    """N Gaussians (or gradients or Adam moments of that shape), float32, copied in."""

    def __init__(
        self,
        *,
        means: _F32,
        log_scales: _F32,
        quats: _F32,
        opacity_logits: _F32,
        sh: _F32,
    ) -> None: ...
    @property
    def means(self) -> _F32:
        """(N, 3)"""
    @property
    def log_scales(self) -> _F32:
        """(N, 3)"""
    @property
    def quats(self) -> _F32:
        """(N, 4), (w, x, y, z)"""
    @property
    def opacity_logits(self) -> _F32:
        """(N,)"""
    @property
    def sh(self) -> _F32:
        """(N, K, 3), K = (sh_degree + 1)²"""
    @property
    def sh_degree(self) -> int: ...
    def __len__(self) -> int: ...

class SpacetimeArrays:
    """N spacetime Gaussians (``pano4d.spacetime.SpacetimeGaussians``), float32, copied in."""

    def __init__(
        self,
        *,
        canonical: GaussianArrays,
        period: int,
        colour_harmonics: int,
        position_harmonics: int,
        time_centre: _F32,
        time_log_width: _F32,
        colour_terms: _F32,
        position_terms: _F32,
    ) -> None: ...
    @property
    def canonical(self) -> GaussianArrays: ...
    @property
    def period(self) -> int: ...
    @property
    def colour_harmonics(self) -> int: ...
    @property
    def position_harmonics(self) -> int: ...
    @property
    def time_centre(self) -> _F32:
        """(N,)"""
    @property
    def time_log_width(self) -> _F32:
        """(N,)"""
    @property
    def colour_terms(self) -> _F32:
        """(N, 2·colour_harmonics, 3)"""
    @property
    def position_terms(self) -> _F32:
        """(N, 2·position_harmonics, 3)"""
    def __len__(self) -> int: ...

# --- rendering (python/raster.rs) ------------------------------------------------------------
class View:
    """A pinhole camera: K (3×3) and world-to-camera rows (3×4 or 4×4), float64."""

    def __init__(
        self,
        *,
        k: _F64,
        world_to_cam: _F64,
        half_fov_tan: tuple[float, float],
        width: int,
        height: int,
    ) -> None: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...

class RasterOutput:
    @property
    def pixels(self) -> _F32:
        """H·W·5: r, g, b, alpha, Σ z·α·T."""
    @property
    def intersections(self) -> int: ...

def render_forward(
    gaussians: GaussianArrays,
    view: View,
    *,
    background: tuple[float, float, float],
    antialiased: bool,
) -> RasterOutput: ...
def render_backward(
    gaussians: GaussianArrays,
    view: View,
    *,
    background: tuple[float, float, float],
    antialiased: bool,
    v_pixels: _F32,
) -> GaussianArrays:
    """The gradient w.r.t. each array of ``gaussians``, in its shape."""

def footprints(gaussians: GaussianArrays, view: View, *, antialiased: bool) -> _F32:
    """N·3: each Gaussian's pixel centre x, y and footprint radius (0 where culled)."""

def adapter_info() -> dict[str, str]:
    """name, backend, device_type, driver, subgroups and float_atomics ("yes" / "no")."""

# --- files (python/io.rs) --------------------------------------------------------------------
def read_ply(path: _Path) -> GaussianArrays: ...
def write_ply(path: _Path, gaussians: GaussianArrays) -> None: ...

class Ply4dWriter:
    def __init__(self, path: _Path, static_set: GaussianArrays) -> None: ...
    def push(self, dynamic_set: GaussianArrays) -> None: ...
    def push_spacetime(self, spacetime_set: SpacetimeArrays) -> None: ...
    def finish(self, meta_json: str) -> None: ...
    def close(self) -> None: ...

class Ply4dReader:
    def __init__(self, path: _Path) -> None: ...
    def header_json(self) -> str: ...
    @property
    def num_times(self) -> int: ...
    def read_static(self) -> GaussianArrays: ...
    def read_dynamic(self, t: int) -> GaussianArrays: ...
    def read_at(self, t: int) -> GaussianArrays: ...
    def read_spacetime(self) -> SpacetimeArrays: ...
    def verify(self) -> None: ...
    def export_ply(self, t: int, path: _Path) -> None: ...

# --- training (python/train.rs) --------------------------------------------------------------
class TrainSettings:
    def __init__(
        self,
        *,
        learning_rates: dict[str, float],
        betas: tuple[float, float],
        eps: float,
        lambda_l1: float,
        lambda_ssim: float,
        lambda_temporal: float,
        lambda_geo: float,
        background: tuple[float, ...] | Sequence[float],
        antialiased: bool,
    ) -> None: ...
    @property
    def learning_rates(self) -> dict[str, float]: ...
    @property
    def betas(self) -> tuple[float, float]: ...
    @property
    def eps(self) -> float: ...
    @property
    def lambda_l1(self) -> float: ...
    @property
    def lambda_ssim(self) -> float: ...
    @property
    def lambda_temporal(self) -> float: ...
    @property
    def lambda_geo(self) -> float: ...
    @property
    def background(self) -> list[float]: ...
    @property
    def antialiased(self) -> bool: ...

class ViewTarget:
    """One view's targets: rgb H·W·3, weight, depth H·W, previous H·W·3 (any shape with those
    counts, float32)."""

    def __init__(
        self,
        *,
        view: View,
        rgb: _F32,
        weight: _F32,
        weight_sum: float,
        outside_sums: Sequence[float],
        depth: _F32 | None = None,
        previous: _F32 | None = None,
        time: float = 0.0,
    ) -> None: ...

class LossParts:
    @property
    def total(self) -> float: ...
    @property
    def l1(self) -> float: ...
    @property
    def d_ssim(self) -> float: ...
    @property
    def temporal(self) -> float: ...
    @property
    def one_minus_pearson(self) -> float: ...
    @property
    def covered_weight(self) -> float: ...
    @property
    def geo_applied(self) -> bool: ...

class LossGradient:
    @property
    def pixel_gradient(self) -> _F32:
        """H·W·5"""
    @property
    def parts(self) -> LossParts: ...

class FrameCheck:
    @property
    def overflowed(self) -> int: ...
    @property
    def max_intersections(self) -> int: ...
    @property
    def capacity(self) -> int: ...

class Traffic:
    @property
    def uploaded(self) -> int: ...
    @property
    def read_back(self) -> int: ...

class TrainState:
    """The kind of set the session trains: GaussianArrays or SpacetimeArrays."""

    @property
    def params(self) -> GaussianArrays | SpacetimeArrays: ...
    @property
    def exp_avg(self) -> GaussianArrays | SpacetimeArrays: ...
    @property
    def exp_avg_sq(self) -> GaussianArrays | SpacetimeArrays: ...
    @property
    def unit(self) -> _F32: ...
    @property
    def grad_accum(self) -> _F32: ...
    @property
    def grad_count(self) -> _F32: ...
    @property
    def adam_steps(self) -> int: ...

class TrainSession:
    def __init__(
        self,
        *,
        static_set: GaussianArrays,
        trained: GaussianArrays | SpacetimeArrays,
        unit: _F32,
        views: Sequence[ViewTarget],
        settings: TrainSettings,
    ) -> None: ...
    @property
    def settings(self) -> TrainSettings: ...
    def step(self, view: int) -> None: ...
    def forward_backward(self, view: int) -> None: ...
    def read_render(self) -> _F32: ...
    def render_at(self, view: View) -> _F32: ...
    def loss_gradient(self, view: int, pixels: _F32) -> LossGradient: ...
    def backward_at(self, v_pixels: _F32) -> None: ...
    def apply_adam(self) -> None: ...
    def apply_gradients(self, grads: GaussianArrays) -> None: ...
    def reserve_frames(self) -> None: ...
    def check_frames(self) -> FrameCheck: ...
    def loss(self) -> LossParts: ...
    def state(self) -> TrainState: ...
    def params(self) -> GaussianArrays | SpacetimeArrays: ...
    def parameter_gradient(
        self, scene_gradient: GaussianArrays | None = None
    ) -> GaussianArrays | SpacetimeArrays: ...
    def scene(self) -> GaussianArrays: ...
    def set_trained(
        self,
        *,
        trained: GaussianArrays | SpacetimeArrays,
        unit: _F32,
        exp_avg: GaussianArrays | SpacetimeArrays | None = None,
        exp_avg_sq: GaussianArrays | SpacetimeArrays | None = None,
        grad_accum: _F32 | None = None,
        grad_count: _F32 | None = None,
        adam_steps: int = 0,
    ) -> None: ...
    def traffic(self) -> Traffic: ...
    def __len__(self) -> int: ...
