"""Which trainers a lifting stage can use: ``TRAINERS``, each name with how it is built and
the rasterisers it trains with. A trainer is added here and nowhere else: the command
line's ``--trainer`` and ``pano4d.train.run_train`` resolve a name with ``trainer_for``,
and ``pipeline.make_trainer`` builds the named one for each optimisation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from pano4d.gaussians import Gaussians
from pano4d.lift.resident import ResidentTrainer
from pano4d.lift.torch_trainer import GaussianTrainer
from pano4d.lift.trainer import FeatureModel, Knobs, RenderFn, TrainedSet, Trainer, TrainViews


class BuildTrainer(Protocol):
    def __call__(
        self,
        gaussians: TrainedSet,
        views: TrainViews,
        knobs: Knobs,
        render: RenderFn,
        static: Gaussians | None,
        features: FeatureModel | None,
        seed: int,
    ) -> Trainer[TrainedSet]: ...


@dataclass(frozen=True)
class TrainerKind:
    # The trainer of one set of Gaussians or spacetime set (``pipeline.make_trainer``).
    build: BuildTrainer
    backends: tuple[str, ...]  # the rasterisers (``--backend``) it trains with


def _resident(
    gaussians: TrainedSet,
    views: TrainViews,
    knobs: Knobs,
    render: RenderFn,
    static: Gaussians | None,
    features: FeatureModel | None,
    seed: int,
) -> Trainer[TrainedSet]:
    # ``render`` is not needed: the resident trainer renders on the device.
    return ResidentTrainer(gaussians, views, knobs, static=static, features=features, seed=seed)


def _torch(
    gaussians: TrainedSet,
    views: TrainViews,
    knobs: Knobs,
    render: RenderFn,
    static: Gaussians | None,
    features: FeatureModel | None,
    seed: int,
) -> Trainer[TrainedSet]:
    return GaussianTrainer(
        gaussians, views, knobs, render, static=static, features=features, seed=seed
    )


# In order of preference: a rasteriser's default trainer is the first that trains with it.
TRAINERS: dict[str, TrainerKind] = {
    # The Gaussians, Adam and the losses stay on the GPU (lift.resident); wgpu only.
    "resident": TrainerKind(_resident, backends=("wgpu",)),
    # The reference: losses and Adam in torch (lift.torch_trainer), any rasteriser.
    "torch": TrainerKind(_torch, backends=("wgpu", "torch")),
}


def trainer_kind(name: str) -> TrainerKind:
    """The trainer called ``name``; ValueError naming those that exist if there is none."""
    if name not in TRAINERS:
        raise ValueError(f"trainer must be one of {sorted(TRAINERS)}, got {name!r}")
    return TRAINERS[name]


def trainer_for(render_backend: str, trainer: str | None) -> str:
    """The trainer to use with the ``render_backend`` rasteriser: ``trainer`` if it trains
    with it, or by default the first of TRAINERS that does (the resident one on wgpu, the
    torch one with the torch rasteriser)."""
    default = next((n for n, k in TRAINERS.items() if render_backend in k.backends), None)
    if default is None:
        raise ValueError(f"no trainer renders with the {render_backend!r} rasteriser")
    if trainer is None:
        return default
    backends = trainer_kind(trainer).backends
    if render_backend not in backends:
        raise ValueError(
            f"the {trainer} trainer renders with {' or '.join(backends)}, not the "
            f"{render_backend!r} rasteriser: use the {default} trainer with that backend"
        )
    return trainer
