"""Random-weight DINOv2 models, for tests and benchmarks of the ``dinov2`` feature backend.

No DINOv2 weights can be downloaded here, so L_sem is exercised on a model of the real
architecture with random weights and a few channels: ``save_random_dinov2`` writes one in
transformers' format, and ``random_feature_model`` loads it by path through
``features.make_feature_model``, as real weights are loaded (the pipeline never uses this
module).
"""

from __future__ import annotations

from pathlib import Path

import torch

from pano4d.config import FeaturesConfig
from pano4d.lift.features import Dinov2Features, make_feature_model


def save_random_dinov2(
    folder: Path, *, patch_size: int, image_size: int, layers: int = 1, hidden_size: int = 16
) -> Path:
    """A random DINOv2 (seed 0) saved under ``folder / "dino"``; returns that folder."""
    import transformers
    from transformers import Dinov2Config, Dinov2Model

    transformers.logging.set_verbosity_error()
    transformers.logging.disable_progress_bar()
    config = Dinov2Config(
        hidden_size=hidden_size,
        num_hidden_layers=layers,
        num_attention_heads=2,
        intermediate_size=2 * hidden_size,
        patch_size=patch_size,
        image_size=image_size,
    )
    torch.manual_seed(0)
    path = folder / "dino"
    Dinov2Model(config).save_pretrained(path)
    return path


def random_feature_model(
    folder: Path, *, patch_size: int, image_size: int, layers: int = 1, hidden_size: int = 16
) -> Dinov2Features:
    """``save_random_dinov2``'s model loaded through the ``dinov2`` feature backend."""
    weights = save_random_dinov2(
        folder, patch_size=patch_size, image_size=image_size, layers=layers,
        hidden_size=hidden_size,
    )  # fmt: skip
    model = make_feature_model(FeaturesConfig(backend="dinov2", weights=weights))
    assert model is not None  # a dinov2 backend always gives one
    return model
