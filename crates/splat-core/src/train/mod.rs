//! Training on the device: the lifting phase's optimisation loop with the Gaussians, their
//! Adam moments and the stage's targets resident, driven step by step from Python
//! (`pano4d.lift.resident`).
//!
//! - [`session`]: [`TrainSession`], the buffers and one step (forward → losses → backward
//!   → Adam), the read-backs at checkpoints and densification, the traffic counter.
//! - [`losses`]: λ_l1·L1 + λ_ssim·D-SSIM (λ_ssim is the `lambda_dssim` knob, λ_l1 its
//!   complement), L_temporal and L_geo with their pixel gradient (`losses.wgsl`).
//! - [`adam`]: torch's Adam with the lifting phase's per-group learning rates
//!   (`adam.wgsl`).
//!
//! A spacetime set is drawn at a step's view time, and its gradient carried back to its time
//! parameters, by the evaluate pass and its adjoint, which live beside the CPU form in
//! [`crate::spacetime`] (the viewer launches the same pass).
//!
//! The torch trainer (`pano4d.lift.torch_trainer.GaussianTrainer`) is the reference; the
//! Python tests compare the two step for step.

pub mod adam;
pub mod losses;
pub mod session;
#[cfg(test)]
mod tests;

pub use adam::{AdamConfig, GROUPS};
pub use losses::{ssim_taps, ssim_window, LossParts, LossWeights, LOSS_PARTS, OUTSIDE_SUMS};
pub use session::{Traffic, TrainConfig, TrainSession, TrainState, TrainedInput, ViewTargets};

/// The training loop's kernel modules (for the checks of the WGSL against the Rust
/// structs).
#[cfg(test)]
pub(crate) fn kernel_modules() -> Vec<crate::wgsl::KernelModule> {
    vec![losses::module(), adam::module()]
}
