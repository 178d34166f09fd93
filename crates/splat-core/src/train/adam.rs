//! Adam on the device (`adam.wgsl`): torch.optim.Adam's update, element by element, with
//! one learning rate per parameter group.

use crate::raster::gpu::{compile, div_ceil, run_linear};
use crate::raster::{COMMON_WGSL, GAUSSIAN_LAYOUT_WGSL};
use crate::spacetime::evaluate::TIME_LAYOUT_WGSL;
use crate::spacetime::MIN_WIDTH_FRAMES;
use crate::wgsl::{gpu_struct, KernelModule, WgslPart};

const ADAM_WGSL: WgslPart = WgslPart {
    file: "adam.wgsl",
    source: include_str!("adam.wgsl"),
    needs: &[
        COMMON_WGSL.file,
        GAUSSIAN_LAYOUT_WGSL.file,
        TIME_LAYOUT_WGSL.file,
    ],
    reads: &[],
};

pub(crate) fn module() -> KernelModule {
    KernelModule {
        label: "adam",
        parts: vec![
            &COMMON_WGSL,
            &GAUSSIAN_LAYOUT_WGSL,
            &TIME_LAYOUT_WGSL,
            &ADAM_WGSL,
        ],
    }
}

/// Parameter groups, in the order of the learning rates: means (as offsets in units of
/// each Gaussian's initial depth), log-scales, quaternions, opacity logits, SH DC, SH rest,
/// then a spacetime set's colour terms, position terms (as offsets, like the means),
/// centre times and log-widths.
pub const GROUPS: usize = 10;

/// Adam's hyper-parameters (torch's names and defaults for β).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamConfig {
    pub learning_rates: [f64; GROUPS],
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
}

gpu_struct! {
    /// The uniform of one Adam step (adam.wgsl documents each field).
    pub(crate) struct AdamParams {
        n_static: u32,
        n_train: u32,
        grad_len: u32,
        sh_coeffs: u32,
        has_extra: u32,
        timed: u32,
        pad0: u32,
        pad1: u32,
        beta1_complement: f32,
        beta2: f32,
        beta2_complement: f32,
        eps: f32,
        bias2_sqrt: f32,
        min_log_width: f32,
        pad2: f32,
        pad3: f32,
        /// Per group, four to a vector (two slots unused).
        neg_step: [[f32; 4]; GROUPS.div_ceil(4)],
    }
}

/// Where the trained Gaussians and their gradients lie (see adam.wgsl's header).
#[derive(Clone, Copy, Debug)]
pub(super) struct AdamLayout {
    pub n_static: u32,
    pub n_train: u32,
    pub sh_coeffs: u32,
    pub has_extra: bool,
    /// A spacetime set: its time sections follow the Gaussians'.
    pub timed: bool,
}

impl AdamConfig {
    /// The shader's constants for Adam step `step` (1 for the first), computed as
    /// torch's `_single_tensor_adam` does: the bias corrections in f64 (Python floats),
    /// rounded to f32 where torch hands them to a float32 kernel as a scalar.
    pub(super) fn params(&self, step: u64, layout: AdamLayout) -> AdamParams {
        let t = step as f64;
        let bias1 = 1.0 - self.beta1.powf(t);
        let bias2 = 1.0 - self.beta2.powf(t);
        let mut neg_step = [[0.0f32; 4]; GROUPS.div_ceil(4)];
        for (out, lr) in neg_step
            .as_flattened_mut()
            .iter_mut()
            .zip(self.learning_rates)
        {
            *out = -(lr / bias1) as f32;
        }
        AdamParams {
            n_static: layout.n_static,
            n_train: layout.n_train,
            grad_len: layout.n_static + layout.n_train,
            sh_coeffs: layout.sh_coeffs,
            has_extra: layout.has_extra as u32,
            timed: layout.timed as u32,
            pad0: 0,
            pad1: 0,
            beta1_complement: (1.0 - self.beta1) as f32,
            beta2: self.beta2 as f32,
            beta2_complement: (1.0 - self.beta2) as f32,
            eps: self.eps as f32,
            bias2_sqrt: bias2.sqrt() as f32,
            // torch's clamp_ rounds the Python float ln(MIN_WIDTH_FRAMES) to f32.
            min_log_width: f64::from(MIN_WIDTH_FRAMES).ln() as f32,
            pad2: 0.0,
            pad3: 0.0,
            neg_step,
        }
    }
}

/// The buffers one Adam step reads and writes.
pub(super) struct AdamBindings<'a> {
    pub params: &'a wgpu::Buffer,
    /// The trained set's parameters (not the rendered snapshot: session.rs).
    pub trained: &'a wgpu::Buffer,
    pub grads: &'a wgpu::Buffer,
    pub grads_extra: &'a wgpu::Buffer,
    pub exp_avg: &'a wgpu::Buffer,
    pub exp_avg_sq: &'a wgpu::Buffer,
    pub unit: &'a wgpu::Buffer,
    pub stats: &'a wgpu::Buffer,
    /// A spacetime set's time parameters' gradient and the step's time (for a set of
    /// Gaussians, buffers the kernel does not read).
    pub time_grads: &'a wgpu::Buffer,
    pub time_params: &'a wgpu::Buffer,
}

pub(super) struct AdamKernel {
    pipeline: wgpu::ComputePipeline,
}

impl AdamKernel {
    pub(super) fn new(device: &wgpu::Device) -> Self {
        Self {
            pipeline: compile(device, &module(), &["main"]).remove(0),
        }
    }

    /// Encodes one step over `n_train` Gaussians.
    pub(super) fn encode(
        &self,
        device: &wgpu::Device,
        pass: &mut wgpu::ComputePass<'_>,
        b: &AdamBindings<'_>,
        n_train: u32,
    ) {
        run_linear(
            pass,
            device,
            &self.pipeline,
            &[
                (0, b.params),
                (1, b.trained),
                (2, b.grads),
                (3, b.grads_extra),
                (4, b.exp_avg),
                (5, b.exp_avg_sq),
                (6, b.unit),
                (7, b.stats),
                (8, b.time_grads),
                (9, b.time_params),
            ],
            div_ceil(n_train, 256),
        );
    }
}
