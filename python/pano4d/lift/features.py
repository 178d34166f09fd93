"""Feature backend for L_sem: a DINOv2 model (transformers) loaded from a local folder."""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F

from pano4d.config import FeaturesConfig

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class FeatureError(ValueError):
    """The feature model could not be loaded."""


class Dinov2Features:
    """CLS embeddings of rendered images; gradients flow to the image, not the weights."""

    def __init__(self, weights: Path, device: torch.device | str = "cpu") -> None:
        from transformers import AutoModel

        weights = Path(weights)
        if not (weights / "config.json").is_file():
            raise FeatureError(f"{weights}: not a transformers model folder (no config.json)")
        try:
            self.model = AutoModel.from_pretrained(weights)
        except (OSError, ValueError, KeyError) as error:
            raise FeatureError(f"{weights}: could not load a feature model: {error}") from error
        self.model.eval().to(device).requires_grad_(False)
        self.device = torch.device(device)
        self.patch = int(getattr(self.model.config, "patch_size", 14))
        self.mean = torch.tensor(IMAGENET_MEAN, device=self.device)[:, None, None]
        self.std = torch.tensor(IMAGENET_STD, device=self.device)[:, None, None]

    def cls(self, image: torch.Tensor) -> torch.Tensor:
        """CLS token (D,) of an image (h, w, 3) in [0, 1]."""
        x = image.permute(2, 0, 1)[None].to(self.device, torch.float32)
        side = max(2, round(max(image.shape[:2]) / self.patch)) * self.patch
        x = F.interpolate(x, size=(side, side), mode="bilinear", align_corners=False)
        hidden = self.model(pixel_values=(x - self.mean) / self.std).last_hidden_state
        return hidden[0, 0]


def make_feature_model(
    cfg: FeaturesConfig, device: torch.device | str = "cpu"
) -> Dinov2Features | None:
    """The configured feature model, or None when ``backend: none``."""
    if cfg.backend == "none":
        return None
    if cfg.weights is None:
        raise FeatureError("features backend 'dinov2' needs 'weights'")
    return Dinov2Features(cfg.weights, device)
