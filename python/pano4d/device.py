"""The torch device a scene.yaml's ``device`` names: 'auto' is CUDA when torch sees a GPU."""

from __future__ import annotations

import torch


def resolve_device(name: str) -> torch.device:
    """'auto', 'cpu' or 'cuda' as a torch device; 'cuda' without a GPU is an error."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise RuntimeError("device: cuda was asked for but torch sees no CUDA device")
    return torch.device(name)
