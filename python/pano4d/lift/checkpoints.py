"""What lets a run resume: each lifting stage's state in output/checkpoints/<stage>.pt.

A checkpoint records the key of the stage it was written for (``stage_keys``): the hash of
what the stage's result depends on, chained through the stages before it. A stage resumes
only from a checkpoint with its own key, so a config change discards exactly the stages it
affects and those after them (a new ``gaussian_iterations`` keeps the depth and the
alignment; new regions re-run everything). Every file is written atomically, so a kill
leaves the previous checkpoint or the new one.

Each stage also records where this run picked it up (``Checkpoints.resumed``): saved with
every checkpoint of the stage and written to metrics.json as ``resumed_at``.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from pano4d.config import DYNAMIC_ONLY, PresetKnobs, SceneConfig
from pano4d.errors import InputError
from pano4d.fsutil import atomic_path

CHECKPOINT_EVERY = 50  # optimisation steps between checkpoints
STAGES = ("depth", "align", "static", "dynamic")  # in order; each depends on those before
DYNAMIC_CHECKPOINT_VERSION = 2


class TrainError(InputError, RuntimeError):
    """The run cannot go on (missing frames, broken checkpoint, ...)."""


def save_atomic(path: Path, payload: dict[str, Any]) -> None:
    """torch.save through a temporary file and a rename."""
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


# Knobs only the dynamic stage reads (marked DYNAMIC_ONLY where config declares them):
# changing one keeps the static set's checkpoint.
DYNAMIC_ONLY_KNOBS = tuple(
    name for name, info in PresetKnobs.model_fields.items() if DYNAMIC_ONLY in info.metadata
)


def stage_keys(cfg: SceneConfig) -> dict[str, str]:
    """Per lifting stage, the hash of the settings its result depends on, chained: each key
    covers the stage's own settings and the key of the stage before it."""
    from pano4d.animate.pipeline import inputs_hash

    knobs = cfg.resolved_preset().model_dump()
    later = {k: knobs.pop(k) for k in DYNAMIC_ONLY_KNOBS}
    own: dict[str, dict[str, Any]] = {
        # the frames (what the animating phase made of the panorama, regions and seed), the
        # view layout and the depth backend
        "depth": {
            "frames": inputs_hash(cfg),
            "depth": cfg.depth.model_dump(mode="json"),
            "lift": cfg.lift.model_dump(mode="json"),
            "view_size": knobs["view_size"],
            "device": cfg.device,
        },
        "align": {"align_iterations": knobs["align_iterations"]},
        "static": {
            "knobs": knobs,
            "features": cfg.features.model_dump(mode="json"),
            "seed": cfg.seed,
        },
        # trained against the static set: everything static depends on, and its own knobs;
        # the version changes with what the stage's checkpoint holds (2: the spacetime set
        # beside the per-timestamp sets), so an older checkpoint is discarded, not misread
        "dynamic": {"version": DYNAMIC_CHECKPOINT_VERSION, **later},
    }
    keys: dict[str, str] = {}
    previous = ""
    for stage in STAGES:
        text = json.dumps({"after": previous, **own[stage]}, sort_keys=True)
        previous = keys[stage] = hashlib.sha256(text.encode()).hexdigest()
    return keys


@dataclass
class Checkpoints:
    folder: Path
    keys: dict[str, str]  # stage_keys of the config being run
    every: int = CHECKPOINT_EVERY  # optimisation steps between checkpoints
    # Where this run picked each stage up, e.g. {"static": {"step": 50}}; all zeros when it
    # started the stage from scratch.
    resumed_at: dict[str, dict[str, int]] = field(default_factory=dict)

    @classmethod
    def for_config(
        cls, folder: Path, cfg: SceneConfig, every: int = CHECKPOINT_EVERY
    ) -> Checkpoints:
        return cls(folder, stage_keys(cfg), every)

    def path(self, name: str) -> Path:
        return self.folder / f"{name}.pt"

    def load(self, name: str) -> dict[str, Any] | None:
        """The stage's saved state, or None if absent or written for other settings."""
        path = self.path(name)
        if not path.is_file():
            return None
        try:
            state = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as error:  # torch raises what its unpickler and zip reader meet
            raise TrainError(
                f"{path}: unreadable checkpoint ({' '.join(str(error).split())}); "
                "delete it to restart that stage"
            ) from error
        if not isinstance(state, dict):
            raise TrainError(f"{path}: not a pano4d checkpoint; delete it to restart that stage")
        return state if state.get("key") == self.keys[name] else None

    def resumed(self, name: str, **position: int) -> None:
        """Record where this run picked stage ``name`` up."""
        self.resumed_at[name] = position

    def save(self, name: str, state: dict[str, Any]) -> None:
        payload = {**state, "key": self.keys[name], "resumed_at": self.resumed_at.get(name)}
        save_atomic(self.path(name), payload)
