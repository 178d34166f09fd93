"""The Panoramic Denoiser: one latent video on the sphere, denoised through perspective views.

The latent video lives on icosphere points as (L, c, N). Every step projects it into each
active view's latent grid, asks the perspective model Φ for its denoised prediction x̂₀
(batched over views), fuses the predictions back onto the sphere in closed form (the
window-weighted mean of the view pixels that see each point, see ``noise.Footprints``),
and takes one sampler step on the sphere.

What is fused, and why x̂₀. The sampler is EDM's Euler step (diffusers'
EulerDiscreteScheduler with s_churn = 0, what SVD uses):
    x_next = x + (x − x̂₀)(σ_next − σ)/σ = r·x + (1 − r)·x̂₀,   r = σ_next / σ.
It is affine in (x, x̂₀) with scalar coefficients, so starting from x = c₀·ε the state is
always x = m + c·ε: a signal m (a running mix of fused predictions) plus the *initial*
noise scaled by c = c₀·σ/σ₀. We keep m and ε apart on the sphere, fuse only x̂₀, and
project m by footprint means but ε by the variance-preserving transport. Fusing the
post-step latent instead would pass the noise through fuse∘project, which averages
neighbouring pixels: the noise would lose variance and whiteness every step. With one view
project∘fuse is the identity, so the loop reproduces plain single-view sampling.

Points no active view sees take x̂₀ = the encoded input (static) latent, so they end there.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import torch

from pano4d.animate.noise import Footprints, sphere_white_noise
from pano4d.animate.protocol import ImageToVideoDenoiser, ViewCondition
from pano4d.camera import Camera


@dataclass
class SphereLatent:
    """The sampler state x = signal + noise_scale · noise, all (L, c, N) on the sphere."""

    signal: torch.Tensor
    noise: torch.Tensor
    noise_scale: float


def euler_step(
    state: SphereLatent, x0: torch.Tensor, sigma: float, sigma_next: float
) -> SphereLatent:
    """The one place that advances the sampler: an EDM Euler step from σ to σ_next."""
    ratio = sigma_next / sigma
    signal = torch.lerp(x0, state.signal, ratio)  # ratio·signal + (1 − ratio)·x̂₀
    return SphereLatent(signal, state.noise, state.noise_scale * ratio)


def latent_cameras(cameras: list[Camera], scale_factor: int) -> list[Camera]:
    """The views' cameras at latent resolution (same rays, pixels ``scale_factor`` larger)."""
    out = []
    for cam in cameras:
        if cam.width % scale_factor or cam.height % scale_factor:
            raise ValueError(
                f"view size {cam.width}x{cam.height} is not divisible by the latent scale "
                f"factor {scale_factor}"
            )
        K = cam.K.clone()
        K[:2] /= scale_factor
        out.append(
            Camera(K, cam.world_to_cam, cam.width // scale_factor, cam.height // scale_factor)
        )
    return out


@dataclass
class StepReport:
    """One denoising step: seconds per phase, UNet batches, and the views' disagreement."""

    seconds: dict[str, float] = field(default_factory=dict)
    unet_calls: int = 0
    disagreement: float = 0.0  # RMS spread of x̂₀ across the views seeing a point, pre-fusion


PhaseHook = Callable[[str], contextlib.AbstractContextManager[None]]


class PanoramicDenoiser:
    """Denoise a spherical latent video through the given (active) views.

    ``footprints`` are those of the active views' latent grids (``latent_cameras``) on the
    icosphere the latent lives on; ``view_batch`` bounds how many views one call to Φ sees.
    """

    def __init__(
        self, model: ImageToVideoDenoiser, footprints: Footprints, view_batch: int
    ) -> None:
        if view_batch < 1:
            raise ValueError(f"view_batch must be at least 1, got {view_batch}")
        self.model = model
        self.footprints = footprints.to(model.device)
        self.view_batch = view_batch
        self.views_per_point = torch.bincount(self.footprints.point, minlength=footprints.n_points)
        self.window_sum = self.footprints.window_sum()  # the fusion's denominator, fixed
        self.reports: list[StepReport] = []

    def batches(self) -> list[slice]:
        n = self.footprints.n_views
        return [slice(a, min(a + self.view_batch, n)) for a in range(0, n, self.view_batch)]

    def sample(
        self,
        condition: ViewCondition,
        static: torch.Tensor,
        frames: int,
        steps: int,
        seed: int,
        phase: PhaseHook | None = None,
        on_fuse: Callable[[torch.Tensor, list[torch.Tensor]], None] | None = None,
    ) -> torch.Tensor:
        """Run the sampler; returns the clean latent video (L, c, N) float32 on the sphere.

        ``static`` (c, N) is the encoded input on the sphere. ``phase(name)`` wraps the
        project / unet / fuse work of every step (for benchmarks). ``on_fuse(x0_sphere,
        x0_views)`` sees each step's fused and per-view predictions (for tests).
        """
        fp, device = self.footprints, self.model.device
        c = self.model.latent_channels
        if static.shape != (c, fp.n_points):
            raise ValueError(
                f"static latent must be ({c}, {fp.n_points}), got {tuple(static.shape)}"
            )
        static = static.to(device, torch.float32)
        generator = torch.Generator().manual_seed(seed)
        noise = sphere_white_noise(fp.n_points, (frames, c), generator).to(device)
        sigmas, init_scale = self.model.schedule(steps)
        state = SphereLatent(torch.zeros_like(noise), noise, init_scale)
        noise_views = fp.project_white(noise)  # (V, L, c, h, w), fixed for the whole run
        multi = self.views_per_point > 1
        any_multi = bool(multi.any())
        seen = self.window_sum > 0
        safe_sum = torch.where(seen, self.window_sum, 1.0)
        self.reports = []
        for i in range(steps):
            sigma, sigma_next = float(sigmas[i]), float(sigmas[i + 1])
            report = StepReport()
            timed = _timed(report, phase, device)
            numerator = torch.zeros_like(noise)
            square = torch.zeros_like(noise)
            kept = []
            for views in self.batches():
                with timed("project"):
                    latents = fp.project_mean(state.signal, views)
                    latents = latents + state.noise_scale * noise_views[views]
                with timed("unet"):
                    x0 = self.model.predict_x0(latents, sigma, condition.select(views))
                    report.unet_calls += 1
                with timed("fuse"):
                    fp.splat(x0, views, numerator)
                    fp.splat(x0.square(), views, square)
                if on_fuse is not None:
                    kept.append(x0)
            with timed("fuse"):
                x0_sphere = torch.where(seen, numerator / safe_sum, static[None])
                if any_multi:
                    spread = (square / safe_sum - x0_sphere.square())[..., multi].clamp(min=0)
                    report.disagreement = float(spread.mean().sqrt())
            if on_fuse is not None:
                on_fuse(x0_sphere, kept)
            state = euler_step(state, x0_sphere, sigma, sigma_next)
            self.reports.append(report)
        return state.signal


def _timed(
    report: StepReport, phase: PhaseHook | None, device: torch.device
) -> Callable[[str], contextlib.AbstractContextManager[None]]:
    """Time a phase into ``report``; on a GPU, wait for its kernels so the time is its own."""

    def sync() -> None:
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    @contextlib.contextmanager
    def timed(name: str) -> Iterator[None]:
        outer = phase(name) if phase is not None else contextlib.nullcontext()
        with outer:
            sync()
            start = time.perf_counter()
            yield
            sync()
            report.seconds[name] = report.seconds.get(name, 0.0) + time.perf_counter() - start

    return timed
