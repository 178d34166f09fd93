"""Spacetime Gaussians: one dynamic set for every time of a looping animation.

Each Gaussian has canonical 3DGS parameters (a :class:`~pano4d.gaussians.Gaussians`) and a
compact function of time for what changes in the animations this tool makes:

- **colour**: the SH DC coefficient plus ``colour_harmonics`` Fourier terms,
  ``dc(t) = dc + Σₕ aₕ·cos(h·u) + bₕ·sin(h·u)``, u = 2π·t / period;
- **position**: the mean plus ``position_harmonics`` Fourier terms of the same form;
- **presence**: an opacity that rises and falls around a centre time τ with width s,
  ``logit(t) = logit − ½·(d(t, τ) / s)²``, d the signed distance from τ around the loop
  (in [−period/2, period/2)); s = exp(log width). Advected texture (water, cloud) is carried
  by Gaussians that appear and fade; a Gaussian present throughout has s ≫ period.

Time t is in frames (timestamp indices, real-valued): frame ``period`` is frame 0 again, as
the animations loop. Fourier terms close the loop by construction. Scale, rotation and the
higher SH bands do not change in time.

This module is the torch form of the evaluation (``SpacetimeGaussians.at``, differentiable in
every parameter): the torch trainer's and the reference every other form is checked against
(the `.ply4d` reader's in Rust, ``ply4d.rs``; the resident trainer's evaluate pass and its
adjoint in WGSL). The `.ply4d` version 2 stores a set in this form (docs/ply4d.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np
import torch

from pano4d.gaussians import Gaussians

# The narrowest presence a trainer lets a Gaussian have, in frames: both trainers clamp
# ``time_log_width`` to ≥ log(MIN_WIDTH_FRAMES) after each Adam step (the resident one
# through splat-core's spacetime::MIN_WIDTH_FRAMES, which mirrors it). Narrower, a Gaussian
# could fit one frame's targets alone and flash on and off as the animation plays.
MIN_WIDTH_FRAMES = 1.5


@dataclass(frozen=True)
class TimeModel:
    """The form of every Gaussian's function of time in one scene."""

    period: int  # frames per loop: frame ``period`` is frame 0
    colour_harmonics: int  # Fourier terms of the SH DC colour
    position_harmonics: int  # Fourier terms of the mean

    def __post_init__(self) -> None:
        if self.period < 1:
            raise ValueError(f"a loop's period must be ≥ 1 frame, got {self.period}")
        if self.colour_harmonics < 0 or self.position_harmonics < 0:
            raise ValueError(
                f"harmonics must be ≥ 0, got colour {self.colour_harmonics}, "
                f"position {self.position_harmonics}"
            )

    def basis(self, t: float, harmonics: int) -> torch.Tensor:
        """(2·harmonics,) float64: cos(h·u), sin(h·u) for h = 1..harmonics, in that order
        (cos₁, sin₁, cos₂, sin₂, …), u = 2π·t / period."""
        u = 2.0 * math.pi * (t % self.period) / self.period
        return torch.tensor(
            [f(h * u) for h in range(1, harmonics + 1) for f in (math.cos, math.sin)],
            dtype=torch.float64,
        )

    def fitted(self, series: torch.Tensor, harmonics: int) -> tuple[torch.Tensor, torch.Tensor]:
        """A series over the loop's frames, (period, N, C), in Fourier terms by least
        squares: the constant (N, C) and the terms (N, 2·harmonics, C), float64. For evenly
        spaced samples of one period that is the discrete transform: the mean, and twice the
        mean projection on each term; once at the Nyquist rate (its sine is zero), none above
        it (the frames cannot tell those terms apart from lower ones). With ⌊period / 2⌋
        harmonics the terms pass through every frame."""
        count = series.shape[0]
        if count != self.period:
            raise ValueError(f"{count} frames for a loop of {self.period}")
        values = series.to(torch.float64)
        basis = torch.stack([self.basis(t, harmonics) for t in range(count)])  # (L, 2·H)
        h = torch.arange(1, harmonics + 1).repeat_interleave(2)
        scale = torch.where(
            2 * h < count, 2.0 / count, torch.where(2 * h == count, 1.0 / count, 0.0)
        )
        terms = torch.einsum("lk,lnc->nkc", (basis * scale).to(values), values)
        return values.mean(0), terms

    def distance(self, t: float, centre: torch.Tensor) -> torch.Tensor:
        """Signed distance in frames from each ``centre`` to ``t`` around the loop, in
        [−period/2, period/2)."""
        d = t - centre
        return d - self.period * torch.floor(d / self.period + 0.5)


@dataclass
class SpacetimeGaussians:
    """N Gaussians with their functions of time (``TimeModel``); all tensors on one device.

    canonical: the Gaussians' parameters at no displacement and full presence;
    time_centre (N,) τ in frames; time_log_width (N,) log s, s in frames;
    colour_terms (N, 2·colour_harmonics, 3): cos₁, sin₁, cos₂, … terms of the SH DC;
    position_terms (N, 2·position_harmonics, 3): the same for the mean.
    """

    model: TimeModel
    canonical: Gaussians
    time_centre: torch.Tensor
    time_log_width: torch.Tensor
    colour_terms: torch.Tensor
    position_terms: torch.Tensor

    def __post_init__(self) -> None:
        n, m = len(self.canonical), self.model
        expected = {
            "time_centre": (n,),
            "time_log_width": (n,),
            "colour_terms": (n, 2 * m.colour_harmonics, 3),
            "position_terms": (n, 2 * m.position_harmonics, 3),
        }
        for name, shape in expected.items():
            got = tuple(getattr(self, name).shape)
            if got != shape:
                raise ValueError(f"SpacetimeGaussians.{name} must have shape {shape}, got {got}")

    def __len__(self) -> int:
        return len(self.canonical)

    @property
    def device(self) -> torch.device:
        return self.canonical.device

    def at(self, t: float) -> Gaussians:
        """The Gaussians at time ``t`` (frames; any real value, taken modulo the period)."""
        g, m = self.canonical, self.model
        dtype = g.means.dtype
        sh = g.sh
        if m.colour_harmonics:
            wave = m.basis(t, m.colour_harmonics).to(dtype=dtype, device=self.device)
            dc = sh[:, :1] + torch.einsum("k,nkc->nc", wave, self.colour_terms)[:, None]
            sh = torch.cat([dc, sh[:, 1:]], dim=1)
        means = g.means
        if m.position_harmonics:
            wave = m.basis(t, m.position_harmonics).to(dtype=dtype, device=self.device)
            means = means + torch.einsum("k,nkc->nc", wave, self.position_terms)
        z = m.distance(t, self.time_centre) * torch.exp(-self.time_log_width)
        logits = g.opacity_logits - 0.5 * z * z
        return Gaussians(means, g.log_scales, g.quats, logits, sh)

    # --- sets of one model --------------------------------------------------------------------
    def _time_tensors(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self)[2:]}

    def map(self, fn) -> SpacetimeGaussians:  # type: ignore[no-untyped-def]
        """Apply ``fn`` to every tensor."""
        return SpacetimeGaussians(
            self.model,
            self.canonical.map(fn),
            **{k: fn(v) for k, v in self._time_tensors().items()},
        )

    def to(self, *args, **kwargs) -> SpacetimeGaussians:  # type: ignore[no-untyped-def]
        return self.map(lambda t: t.to(*args, **kwargs))

    def detach(self) -> SpacetimeGaussians:
        return self.map(torch.Tensor.detach)

    def __getitem__(self, index: torch.Tensor | slice) -> SpacetimeGaussians:
        return self.map(lambda t: t[index])

    @staticmethod
    def still(
        model: TimeModel,
        g: Gaussians,
        centre: torch.Tensor | None = None,
        log_width: torch.Tensor | None = None,
    ) -> SpacetimeGaussians:
        """``g`` unchanging in colour and position: present throughout (width 10 periods)
        unless ``centre`` and ``log_width`` say when."""
        n = len(g)
        zeros = g.means.new_zeros
        if log_width is None:
            log_width = g.means.new_full((n,), math.log(10.0 * model.period))
        return SpacetimeGaussians(
            model,
            g,
            zeros(n) if centre is None else centre,
            log_width,
            zeros(n, 2 * model.colour_harmonics, 3),
            zeros(n, 2 * model.position_harmonics, 3),
        )

    @staticmethod
    def through_frames(model: TimeModel, frames: list[Gaussians]) -> SpacetimeGaussians:
        """One set that passes through ``frames``: the same Gaussians (same count and order)
        posed at each frame of the loop, of which only the means and colours differ, as the
        tracked stage leaves them (``lift.pipeline.fit_tracked``).

        The means and the SH DC over the frames are fitted by the model's Fourier terms
        (``TimeModel.fitted``); with harmonics ⌊period / 2⌋ (at most 8) the fit passes through every
        frame exactly, fewer keep the slowest waves. Scale, rotation and opacity are frame
        0's; the higher SH bands, which the form holds constant, are their mean over the
        frames. Present throughout: a width of 1000 periods, at which the opacity at every
        time is frame 0's to float32 rounding (``still``'s 10 periods, a start for training,
        dim it by up to 0.1 % of a logit)."""
        if len(frames) != model.period:
            raise ValueError(f"{model.period} frames make one loop, got {len(frames)}")
        counts = {len(g) for g in frames}
        if len(counts) != 1:
            raise ValueError(f"the frames must pose one set of Gaussians, got counts {counts}")

        first = frames[0]
        means, position_terms = model.fitted(
            torch.stack([g.means for g in frames]), model.position_harmonics
        )
        dc, colour_terms = model.fitted(
            torch.stack([g.sh[:, 0] for g in frames]), model.colour_harmonics
        )
        dtype = first.means.dtype
        means, position_terms = means.to(dtype), position_terms.to(dtype)
        dc, colour_terms = dc.to(dtype), colour_terms.to(dtype)
        rest = torch.stack([g.sh[:, 1:] for g in frames]).mean(dim=0)
        sh = torch.cat([dc[:, None], rest], dim=1)
        canonical = Gaussians(means, first.log_scales, first.quats, first.opacity_logits, sh)
        width = means.new_full((len(canonical),), math.log(1000.0 * model.period))
        still = SpacetimeGaussians.still(model, canonical, log_width=width)
        return replace(still, colour_terms=colour_terms, position_terms=position_terms)

    @staticmethod
    def cat(sets: list[SpacetimeGaussians]) -> SpacetimeGaussians:
        if not sets:
            raise ValueError("SpacetimeGaussians.cat needs at least one set")
        models = {s.model for s in sets}
        if len(models) != 1:
            raise ValueError(f"sets of different time models cannot be joined: {models}")
        return SpacetimeGaussians(
            sets[0].model,
            Gaussians.cat([s.canonical for s in sets]),
            **{k: torch.cat([s._time_tensors()[k] for s in sets]) for k in sets[0]._time_tensors()},
        )

    # --- numpy interchange (float32): checkpoints, pano4d.extension ---------------------------
    def to_numpy(self) -> dict[str, object]:
        m = self.model
        return {
            "model": [m.period, m.colour_harmonics, m.position_harmonics],
            "canonical": self.canonical.to_numpy(),
            **{
                k: np.ascontiguousarray(v.detach().cpu().to(torch.float32).numpy())
                for k, v in self._time_tensors().items()
            },
        }

    @staticmethod
    def from_numpy(
        arrays: dict[str, object], device: torch.device | str = "cpu"
    ) -> SpacetimeGaussians:
        period, colour, position = (int(v) for v in arrays["model"])  # type: ignore[attr-defined]
        tensors = {
            k: torch.from_numpy(np.asarray(arrays[k], dtype=np.float32)).to(device)
            for k in ("time_centre", "time_log_width", "colour_terms", "position_terms")
        }
        return SpacetimeGaussians(
            TimeModel(period, colour, position),
            Gaussians.from_numpy(arrays["canonical"], device),  # type: ignore[arg-type]
            **tensors,
        )
