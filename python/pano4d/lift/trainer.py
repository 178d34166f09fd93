"""What every trainer of the lifting phase is: the ``Trainer`` base, what it is given (the
views it trains on, ``TrainViews``; its knobs, ``Knobs``; the frozen static set) and
Adam's settings both trainers share (``learning_rates``, ``ADAM_BETAS``, ``ADAM_EPS``).

Two trainers implement it: the torch reference (``lift.torch_trainer.GaussianTrainer``) and
the resident one on the GPU (``lift.resident.ResidentTrainer``); ``lift.trainers`` says
which exist, ``pipeline.make_trainer`` builds one per optimisation (the static set once, the
dynamic set per timestamp). Their losses are ``lift.losses``', their densification
``lift.densify``'s.

A trainer optimises a set of Gaussians or a spacetime set (``pano4d.spacetime``: Gaussians
with functions of time, trained with them) and gives back the kind it was given. Views
then have times (``TrainViews.times``, in frames): a step draws the trained set at its
view's time (``SpacetimeGaussians.at``) and its gradient reaches the time parameters
through that evaluation; a set of Gaussians is the same at every time.

Each step renders one view drawn from a seeded generator. Gaussians can be trained against
the frozen static set (``static``: while a timestamp's dynamic set trains), which is
rendered with them but gets no gradient. Positions are optimised as offsets in units of
each Gaussian's initial depth, so one learning rate fits a Gaussian at 2 m and one at
1000 m. For the run's diagnosis (``lift.diagnosis``) a trainer keeps its last loss terms in
``last_terms`` and its last densify-and-prune's counts in ``last_densify``.
``state_dict`` / ``load_state_dict`` capture everything a resumed run needs (parameters,
Adam moments, the view generator, the step), so a resumed run continues bit-for-bit;
``trained_in`` gives the trained set such a state holds.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

import torch

from pano4d.camera import Camera
from pano4d.config import OptimisationKnobs
from pano4d.gaussians import Gaussians
from pano4d.lift.diagnosis import DensifyStats
from pano4d.lift.losses import OUTSIDE_SUMS
from pano4d.spacetime import SpacetimeGaussians

ADAM_EPS = 1e-15  # 3DGS's
ADAM_BETAS = (0.9, 0.999)  # torch.optim.Adam's defaults, what 3DGS trains with
SH_REST_LR_DIVISOR = 20  # the higher SH degrees learn 20× slower than degree 0 (3DGS)
# A spacetime set's colour terms learn 5× slower than the SH DC: each step sees one time, and
# at lr_color the terms chase it (landscape, draft, 14 frames: 25.6 dB in the moving region at
# lr_color, 27.0 at a fifth, 26.8 at a twentieth; bench/RESULTS.md, "One dynamic set").
COLOUR_TERMS_LR_DIVISOR = 5

# What a trainer optimises, and what its result() gives back: the same kind.
TrainedSet = TypeVar("TrainedSet", Gaussians, SpacetimeGaussians)


class RenderFn(Protocol):
    def __call__(
        self, gaussians: Gaussians, camera: Camera, background: torch.Tensor | None
    ) -> Any: ...


class FeatureModel(Protocol):
    def cls(self, image: torch.Tensor) -> torch.Tensor:
        """CLS embedding (D,) of an image (h, w, 3) in [0, 1], differentiable."""
        ...


@dataclass
class TrainViews:
    """What one optimisation sees: cameras and, per view, target (h, w, 3), loss weight
    (h, w) and Θ's z-depth (h, w); ``previous`` holds renders of G_{t−1} for L_temporal.

    The cameras may be windows of larger views (``Camera.window``: a dynamic step renders
    only the pixels the moving region reaches, lift.windows). Then ``weight_sums`` (V,)
    holds the whole views' loss normalisers and ``outside`` (V, len(OUTSIDE_SUMS)) the loss
    sums over the rest of each view, so that the loss and its gradient are the whole
    view's. Views may then differ in size: the tensors hold lists.

    ``times`` (V,) is the time each view shows, in frames (real-valued, periodic), for a
    spacetime set: a dynamic stage's list holds each camera once per frame, with that
    frame's targets. None: every view shows one moment (a set of Gaussians does not change
    in time)."""

    cameras: list[Camera]
    targets: torch.Tensor | list[torch.Tensor]
    weights: torch.Tensor | list[torch.Tensor]
    depth: torch.Tensor | list[torch.Tensor]
    previous: torch.Tensor | list[torch.Tensor] | None = None
    weight_sums: torch.Tensor | None = None
    outside: torch.Tensor | None = None
    times: list[float] | None = None

    def time(self, index: int) -> float:
        """The time view ``index`` shows, in frames (0 when the views have no times)."""
        return 0.0 if self.times is None else float(self.times[index])

    def weight_sum(self, index: int) -> torch.Tensor:
        """The loss normaliser of view ``index``: max(Σ weight, 1e-6) over the whole view."""
        if self.weight_sums is not None:
            return self.weight_sums[index]
        return self.weights[index].sum().clamp(min=1e-6)

    def outside_sums(self, index: int) -> torch.Tensor:
        """OUTSIDE_SUMS of view ``index`` (zeros: the view is whole)."""
        if self.outside is not None:
            return self.outside[index]
        return torch.zeros(len(OUTSIDE_SUMS), device=self.weights[index].device)


class Knobs(OptimisationKnobs):
    """One optimisation's knobs: the preset's optimisation knobs (the λ, densify, the
    learning rates) and this run's own (``pipeline.trainer_knobs`` makes them per stage)."""

    iterations: int
    max_gaussians: int = 1_000_000  # this set's budget
    pixel_angle: float = 0.0  # radians per working-panorama pixel (0: every Gaussian splits)
    # The views' pixels × radians per pixel: the statistic's unit (densify.DENSIFY_GRADIENT).
    gradient_scale: float = 1.0
    densify_every: int = 100
    sem_scale: float = 1.0  # world units of δ = 1 (median scene depth)


def learning_rates(knobs: OptimisationKnobs) -> dict[str, float]:
    """Adam's learning rate per parameter group (the groups of GaussianTrainer.params and of
    the resident trainer's TrainSettings), a spacetime set's time parameters' last: its
    colour terms learn as the SH DC / COLOUR_TERMS_LR_DIVISOR, its position terms as the
    means (in the same offset units), its centre times and log-widths at their own rates."""
    return {
        "offsets": knobs.lr_position,
        "log_scales": knobs.lr_scale,
        "quats": knobs.lr_rotation,
        "opacity_logits": knobs.lr_opacity,
        "sh_dc": knobs.lr_color,
        "sh_rest": knobs.lr_color / SH_REST_LR_DIVISOR,
        "colour_terms": knobs.lr_color / COLOUR_TERMS_LR_DIVISOR,
        "position_terms": knobs.lr_position,
        "time_centre": knobs.lr_time_centre,
        "time_log_width": knobs.lr_time_width,
    }


class Trainer(ABC, Generic[TrainedSet]):
    """What both trainers share (``GaussianTrainer`` in lift.torch_trainer,
    ``ResidentTrainer`` in lift.resident): their inputs, the step count, the seeded
    generator that draws each step's view, and the loop; a lifting stage can use either
    (``pipeline.make_trainer``). Only the torch trainer takes a ``render_fn``: the resident
    one renders on the device."""

    def __init__(
        self,
        gaussians: TrainedSet,
        views: TrainViews,
        knobs: Knobs,
        static: Gaussians | None = None,
        features: FeatureModel | None = None,
        seed: int = 0,
        background: torch.Tensor | None = None,
    ) -> None:
        if knobs.iterations < 0:
            raise ValueError(f"iterations must be ≥ 0, got {knobs.iterations}")
        if len(views.cameras) == 0:
            raise ValueError("no views to train on")
        if views.times is not None and len(views.times) != len(views.cameras):
            raise ValueError(
                f"{len(views.cameras)} views with {len(views.times)} times: give one per view"
            )
        self.views, self.knobs, self.features = views, knobs, features
        # The frozen static set, rendered with the trained Gaussians, never trained.
        self.static = static.detach() if static is not None else None
        self.background = background
        self.device = gaussians.device
        self.step = 0
        self.last_view = -1  # the view of the last step (the records say which view they saw)
        self.last_time = 0.0  # and the time it shows, in frames (TrainViews.times)
        self.generator = torch.Generator().manual_seed(seed)
        self.last_loss = math.nan
        # For the diagnosis: diagnosis.TERMS names → values (tensors, read when logged).
        self.last_terms: dict[str, float | torch.Tensor] = {}
        self.last_densify: DensifyStats | None = None
        self._start(gaussians)

    @abstractmethod
    def _start(self, gaussians: TrainedSet) -> None:
        """Sets up the optimisation of ``gaussians`` (called once by __init__)."""

    def next_view(self) -> int:
        """The view of the next step, drawn from the seeded generator (``last_view``; the
        time it shows is ``last_time``)."""
        self.last_view = int(torch.randint(len(self.views.cameras), (), generator=self.generator))
        self.last_time = self.views.time(self.last_view)
        return self.last_view

    @abstractmethod
    def train_step(self) -> float:
        """One step; returns the loss (the resident trainer's last one read back)."""

    @abstractmethod
    def result(self) -> TrainedSet:
        """The trained set, of the kind given."""

    @abstractmethod
    def densify_and_prune(self) -> None: ...

    @abstractmethod
    def state_dict(self) -> dict[str, Any]:
        """Everything a resumed run needs."""

    @abstractmethod
    def trained_in(self, state: dict[str, Any]) -> TrainedSet:
        """The trained set a ``state_dict()`` holds, on the host, as ``result()`` would give
        it at that step, without reading anything from the device again: what a checkpoint
        has already read back is what a live view shows (``pano4d.live``)."""

    @abstractmethod
    def load_state_dict(self, state: dict[str, Any]) -> None: ...

    def run(self, on_step: Callable[[Trainer[TrainedSet]], bool] | None = None) -> TrainedSet:
        """Train up to ``knobs.iterations`` (continuing from ``self.step``), or until
        ``on_step`` returns True after a step; returns the result."""
        while self.step < self.knobs.iterations:
            self.train_step()
            if on_step is not None and on_step(self):
                break
        return self.result()
