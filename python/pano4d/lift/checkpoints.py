"""What lets a run resume: each lifting stage's state in output/checkpoints/<stage>.pt.

A checkpoint records the hash of the config it was written for; a different config (or a
different output) starts that stage again instead of resuming someone else's state. Every
file is written atomically, so a kill leaves the previous checkpoint or the new one.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from pano4d.fsutil import atomic_path

CHECKPOINT_EVERY = 50  # optimisation steps between checkpoints


class TrainError(RuntimeError):
    """The run cannot go on (missing frames, broken checkpoint, ...)."""


def save_atomic(path: Path, payload: dict[str, Any]) -> None:
    """torch.save through a temporary file and a rename."""
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


@dataclass
class Checkpoints:
    folder: Path
    config_hash: str
    every: int = CHECKPOINT_EVERY  # optimisation steps between checkpoints

    def path(self, name: str) -> Path:
        return self.folder / f"{name}.pt"

    def load(self, name: str) -> dict[str, Any] | None:
        """The stage's saved state, or None if absent or written for another config."""
        path = self.path(name)
        if not path.is_file():
            return None
        try:
            state = torch.load(path, map_location="cpu", weights_only=False)
        except (OSError, RuntimeError, EOFError) as error:
            raise TrainError(
                f"{path}: unreadable checkpoint ({error}); delete it to restart that stage"
            ) from error
        return state if state.get("config_hash") == self.config_hash else None

    def save(self, name: str, state: dict[str, Any]) -> None:
        save_atomic(self.path(name), {**state, "config_hash": self.config_hash})
