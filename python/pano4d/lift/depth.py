"""Monocular depth Θ for the lifting phase: per-view ray-length depth of a panoramic frame.

Backends (``depth.backend`` in scene.yaml):

- ``layout`` (embedded, no weights): a geometric prior — the ground plane ``camera_height``
  below the camera under the horizon, a dome at ``far`` above it — refined edge-aware with a
  guided filter whose guide is the frame itself, so depth edges snap to image edges.
- ``file``: a user-supplied equirect ray-length depth (EXR, or 16-bit PNG in millimetres).
- ``dpt``: a transformers depth model (DPT / MiDaS, Depth Anything) from a local folder.
  Relative models predict disparity (inverse depth up to scale and shift); it is inverted
  with a floor so the sky gets a finite far depth. The alignment fixes scale and shift.

Every backend returns ray length per view pixel: a perspective model's z-depth is multiplied
by the camera's per-pixel ray factor (the paper scales by the ray's length).
"""

from __future__ import annotations

import json
import math
from abc import ABC, abstractmethod
from pathlib import Path

import torch
import torch.nn.functional as F

from pano4d.camera import Camera
from pano4d.config import DepthConfig
from pano4d.resample import equirect_sampler
from pano4d.sphere import equirect_directions

MIN_DEPTH = 1e-3  # floor for every depth this module returns (metres or relative units)
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
METRIC_MODEL_TYPES = ("zoedepth", "glpn")


class DepthError(ValueError):
    """A depth backend could not be set up or produced unusable depth."""


class DepthBackend(ABC):
    """Θ: per-view ray-length depth (n, h, w) of an equirect frame (H, W, 3) in [0, 1]."""

    name: str

    @abstractmethod
    def view_depth(self, frame: torch.Tensor, cameras: list[Camera]) -> torch.Tensor: ...


# --- equirect backends ----------------------------------------------------------------------
def sample_equirect_depth(depth: torch.Tensor, cameras: list[Camera]) -> torch.Tensor:
    """Equirect ray-length depth (H, W) seen by each camera at the origin: (n, h, w).

    Interpolates log depth so a sky/ground boundary does not produce mid-air values.
    """
    height, width = depth.shape
    log_depth = depth.clamp(min=MIN_DEPTH).log()
    out = []
    for cam in cameras:
        sampler = equirect_sampler(cam.world_directions(torch.float64), width, height)
        out.append(sampler.to(depth.device).apply(log_depth).exp())
    return torch.stack(out)


def layout_prior(width: int, height: int, camera_height: float, far: float) -> torch.Tensor:
    """Ray length (H, W) to a ground plane ``camera_height`` below, capped by a dome at ``far``."""
    down = -equirect_directions(width, height, torch.float64)[..., 2]
    ground = camera_height / down.clamp(min=camera_height / far)
    return torch.where(down > 0, ground, torch.full_like(ground, far)).to(torch.float32)


def _box_mean(x: torch.Tensor, radius: int) -> torch.Tensor:
    """Mean over a (2r+1)² window of (C, H, W); wraps around the seam, clamps at the poles."""
    padded = F.pad(x[None], (radius, radius, 0, 0), mode="circular")
    padded = F.pad(padded, (0, 0, radius, radius), mode="replicate")
    return F.avg_pool2d(padded, 2 * radius + 1, stride=1)[0]


def guided_filter(
    guide: torch.Tensor, source: torch.Tensor, radius: int, eps: float
) -> torch.Tensor:
    """He et al.'s guided filter: ``source`` (H, W) smoothed edge-aware along ``guide`` (H, W)."""
    g, p = guide[None], source[None]
    mean_g, mean_p = _box_mean(g, radius), _box_mean(p, radius)
    cov = _box_mean(g * p, radius) - mean_g * mean_p
    var = _box_mean(g * g, radius) - mean_g * mean_g
    a = cov / (var + eps)
    b = mean_p - a * mean_g
    return (_box_mean(a, radius) * g + _box_mean(b, radius))[0]


def layout_depth(
    frame: torch.Tensor, camera_height: float, far: float, radius: int | None = None
) -> torch.Tensor:
    """The ``layout`` backend's equirect ray-length depth (H, W) for a frame (H, W, 3)."""
    height, width = frame.shape[:2]
    prior = layout_prior(width, height, camera_height, far).to(frame.device)
    luminance = frame[..., :3].to(torch.float32) @ torch.tensor(
        [0.2126, 0.7152, 0.0722], device=frame.device
    )
    radius = radius if radius is not None else max(1, height // 64)
    # Filter log depth: the guide's edges pull depth edges onto them, flat areas stay smooth.
    refined = guided_filter(luminance, prior.log(), radius, eps=1e-3)
    return refined.clamp(math.log(MIN_DEPTH), math.log(far)).exp()


class LayoutDepth(DepthBackend):
    name = "layout"

    def __init__(self, camera_height: float, far: float) -> None:
        self.camera_height, self.far = camera_height, far

    def view_depth(self, frame: torch.Tensor, cameras: list[Camera]) -> torch.Tensor:
        return sample_equirect_depth(layout_depth(frame, self.camera_height, self.far), cameras)


class FileDepth(DepthBackend):
    """A fixed equirect ray-length depth map, resized (in log space) to each frame."""

    name = "file"

    def __init__(self, path: Path, far: float) -> None:
        from pano4d.images import read_depth

        self.path = path
        self.depth = torch.from_numpy(read_depth(path)).clamp(max=far)
        if self.depth.shape[1] != 2 * self.depth.shape[0]:
            raise DepthError(
                f"{path}: an equirect depth map must be 2:1, got "
                f"{self.depth.shape[1]}x{self.depth.shape[0]}"
            )

    def equirect(self, height: int, width: int) -> torch.Tensor:
        if self.depth.shape == (height, width):
            return self.depth
        log_depth = F.interpolate(self.depth.log()[None, None], size=(height, width), mode="area")
        return log_depth[0, 0].exp()

    def view_depth(self, frame: torch.Tensor, cameras: list[Camera]) -> torch.Tensor:
        depth = self.equirect(*frame.shape[:2]).to(frame.device)
        return sample_equirect_depth(depth, cameras)


# --- transformers depth models ------------------------------------------------------------
def disparity_to_depth(disparity: torch.Tensor, far_ratio: float) -> torch.Tensor:
    """Relative disparity (n, h, w) → relative depth: 1 / disparity, normalised per view.

    Disparity is known only up to scale and shift; dividing by its 98th percentile puts the
    nearest content near depth 1, and the floor ``1 / far_ratio`` gives zero- or negative-
    disparity pixels (the sky) a finite far depth ``far_ratio``.
    """
    flat = disparity.reshape(disparity.shape[0], -1).to(torch.float32)
    top = torch.quantile(flat, 0.98, dim=1).clamp(min=1e-12)
    normalised = (flat / top[:, None]).clamp(min=1.0 / far_ratio)
    return (1.0 / normalised).reshape(disparity.shape)


class TransformersDepth(DepthBackend):
    """AutoModelForDepthEstimation (DPT / MiDaS, Depth Anything, ...) loaded from a folder."""

    name = "dpt"

    def __init__(
        self,
        weights: Path,
        far_ratio: float,
        device: torch.device | str = "cpu",
        batch_size: int = 4,
    ) -> None:
        from transformers import AutoModelForDepthEstimation

        weights = Path(weights)
        if not (weights / "config.json").is_file():
            raise DepthError(f"{weights}: not a transformers model folder (no config.json)")
        try:
            self.model = AutoModelForDepthEstimation.from_pretrained(weights)
        except (OSError, ValueError, KeyError) as error:
            raise DepthError(f"{weights}: could not load a depth model: {error}") from error
        self.model.eval().to(device)
        self.device = torch.device(device)
        self.far_ratio = far_ratio
        self.batch_size = batch_size
        config = self.model.config
        self.metric = (
            getattr(config, "depth_estimation_type", "relative") == "metric"
            or config.model_type in METRIC_MODEL_TYPES
        )
        backbone = getattr(config, "backbone_config", None)
        self.patch = int(getattr(backbone, "patch_size", None) or getattr(config, "patch_size", 16))
        self.mean, self.std = _normalisation(weights, config.model_type)

    def predict_z(self, images: torch.Tensor) -> torch.Tensor:
        """z-depth (n, h, w) of square perspective images (n, 3, h, w) in [0, 1]."""
        n, _, h, w = images.shape
        side = max(2, round(max(h, w) / self.patch)) * self.patch
        mean = torch.tensor(self.mean, device=self.device)[:, None, None]
        std = torch.tensor(self.std, device=self.device)[:, None, None]
        out = []
        with torch.no_grad():
            for start in range(0, n, self.batch_size):
                batch = images[start : start + self.batch_size].to(self.device, torch.float32)
                batch = F.interpolate(batch, size=(side, side), mode="bilinear", antialias=True)
                predicted = self.model(pixel_values=(batch - mean) / std).predicted_depth
                predicted = F.interpolate(predicted[:, None], size=(h, w), mode="bilinear")
                out.append(predicted[:, 0].float())
        raw = torch.cat(out)
        if not torch.isfinite(raw).all():
            raise DepthError("the depth model produced NaN or Inf")
        if self.metric:
            return raw.clamp(min=MIN_DEPTH)
        return disparity_to_depth(raw, self.far_ratio)

    def view_depth(self, frame: torch.Tensor, cameras: list[Camera]) -> torch.Tensor:
        height, width = frame.shape[:2]
        image = frame.permute(2, 0, 1)[:3].to(torch.float32)
        views, ray_factors = [], []
        for cam in cameras:
            sampler = equirect_sampler(cam.world_directions(torch.float64), width, height)
            views.append(sampler.to(frame.device).apply(image))
            ray_factors.append(cam.z_to_ray_factor())
        z = self.predict_z(torch.stack(views))
        return z * torch.stack(ray_factors).to(z.device)


def _normalisation(weights: Path, model_type: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Mean and std from the folder's preprocessor_config.json, else the model family's."""
    processor = weights / "preprocessor_config.json"
    if processor.is_file():
        data = json.loads(processor.read_text())
        if "image_mean" in data and "image_std" in data:
            return tuple(data["image_mean"]), tuple(data["image_std"])
    if model_type == "dpt":
        return (0.5, 0.5, 0.5), (0.5, 0.5, 0.5)
    return IMAGENET_MEAN, IMAGENET_STD


def make_depth_backend(cfg: DepthConfig, device: torch.device | str = "cpu") -> DepthBackend:
    """The backend ``cfg.backend`` names, set up from the config's paths and knobs."""
    if cfg.backend == "layout":
        return LayoutDepth(cfg.camera_height, cfg.far)
    if cfg.backend == "file":
        if cfg.path is None:
            raise DepthError("depth backend 'file' needs 'path'")
        return FileDepth(cfg.path, cfg.far)
    if cfg.weights is None:
        raise DepthError("depth backend 'dpt' needs 'weights'")
    return TransformersDepth(cfg.weights, far_ratio=cfg.far / cfg.camera_height, device=device)
