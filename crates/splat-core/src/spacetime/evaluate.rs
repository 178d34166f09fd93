//! A spacetime set on the device: the evaluate pass that draws it at a time into the scene
//! the rasteriser reads, and its adjoint, which carries the gradient of what was drawn to
//! the time parameters (`evaluate.wgsl`; the functions of time they share with the
//! trainer's Adam are in `time_layout.wgsl`). Two launch the evaluate pass: the training
//! session (crate::train::session, at each step's view time, with the adjoint) and
//! [`super::GpuSpacetimeSet`] (the viewer's version-2 playback, at the shown time). The
//! reference is `pano4d.spacetime.SpacetimeGaussians.at`, with torch's autograd for the
//! adjoint; [`super::SpacetimeSet::at`] is its CPU form.

use super::{TimeModel, MAX_HARMONICS};
use crate::raster::gpu::{compile, div_ceil, run_linear};
use crate::raster::{COMMON_WGSL, GAUSSIAN_LAYOUT_WGSL};
use crate::wgsl::{gpu_struct, KernelModule, WgslPart};

/// The functions of time at the step's time, for the kernels that bind `params` and `tp`.
pub(crate) const TIME_LAYOUT_WGSL: WgslPart = WgslPart {
    file: "time_layout.wgsl",
    source: include_str!("time_layout.wgsl"),
    needs: &[GAUSSIAN_LAYOUT_WGSL.file],
    reads: &["params", "tp"],
};

const EVALUATE_WGSL: WgslPart = WgslPart {
    file: "evaluate.wgsl",
    source: include_str!("evaluate.wgsl"),
    needs: &[
        COMMON_WGSL.file,
        GAUSSIAN_LAYOUT_WGSL.file,
        TIME_LAYOUT_WGSL.file,
    ],
    reads: &[],
};

pub(crate) fn module() -> KernelModule {
    KernelModule {
        label: "evaluate",
        parts: vec![
            &COMMON_WGSL,
            &GAUSSIAN_LAYOUT_WGSL,
            &TIME_LAYOUT_WGSL,
            &EVALUATE_WGSL,
        ],
    }
}

/// Basis values the uniform has room for: cos and sin of each harmonic.
const BASIS_VALUES: usize = 2 * MAX_HARMONICS as usize;

gpu_struct! {
    /// The functions of time's uniform (time_layout.wgsl documents each field).
    pub(crate) struct TimeParams {
        n_static: u32,
        n_train: u32,
        scene_len: u32,
        grad_len: u32,
        sh_coeffs: u32,
        colour_harmonics: u32,
        position_harmonics: u32,
        has_extra: u32,
        period: f32,
        time: f32,
        pad0: f32,
        pad1: f32,
        colour_basis: [[f32; 4]; BASIS_VALUES / 4],
        position_basis: [[f32; 4]; BASIS_VALUES / 4],
    }
}

/// Where the evaluated set (the trained one, in a session) and its gradient lie when the
/// passes run.
#[derive(Clone, Copy, Debug)]
pub(crate) struct TimeLayout {
    pub n_static: u32,
    pub n_train: u32,
    /// The scene's section length (its capacity).
    pub scene_len: u32,
    pub sh_coeffs: u32,
    pub has_extra: bool,
}

impl TimeParams {
    /// The uniform for drawing a set of `model` at `time` (frames): the bases in f64 as the
    /// torch form computes them, the time in f32 as its distance arithmetic takes it.
    pub(crate) fn new(model: &TimeModel, time: f64, layout: TimeLayout) -> Self {
        let basis = |harmonics: u32| {
            let mut out = [[0.0f32; 4]; BASIS_VALUES / 4];
            for (to, value) in out
                .as_flattened_mut()
                .iter_mut()
                .zip(model.basis(time, harmonics))
            {
                *to = value;
            }
            out
        };
        Self {
            n_static: layout.n_static,
            n_train: layout.n_train,
            scene_len: layout.scene_len,
            grad_len: layout.n_static + layout.n_train,
            sh_coeffs: layout.sh_coeffs,
            colour_harmonics: model.colour_harmonics,
            position_harmonics: model.position_harmonics,
            has_extra: layout.has_extra as u32,
            period: model.period as f32,
            time: time as f32,
            pad0: 0.0,
            pad1: 0.0,
            colour_basis: basis(model.colour_harmonics),
            position_basis: basis(model.position_harmonics),
        }
    }
}

pub(crate) struct EvaluateKernels {
    evaluate: wgpu::ComputePipeline,
    adjoint: wgpu::ComputePipeline,
}

impl EvaluateKernels {
    pub(crate) fn new(device: &wgpu::Device) -> Self {
        let mut pipelines = compile(device, &module(), &["evaluate", "adjoint"]).into_iter();
        Self {
            evaluate: pipelines.next().expect("evaluate"),
            adjoint: pipelines.next().expect("adjoint"),
        }
    }

    /// Encodes the snapshot of `n_train` Gaussians at the uniform's time into `scene`.
    pub(crate) fn encode_evaluate(
        &self,
        device: &wgpu::Device,
        pass: &mut wgpu::ComputePass<'_>,
        uniform: &wgpu::Buffer,
        params: &wgpu::Buffer,
        scene: &wgpu::Buffer,
        n_train: u32,
    ) {
        run_linear(
            pass,
            device,
            &self.evaluate,
            &[(0, uniform), (1, params), (2, scene)],
            div_ceil(n_train, 256),
        );
    }

    /// Encodes the time parameters' gradient of `n_train` Gaussians from the scene's
    /// gradient (`grads`, plus `grads_extra` where the uniform says so) into `time_grads`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn encode_adjoint(
        &self,
        device: &wgpu::Device,
        pass: &mut wgpu::ComputePass<'_>,
        uniform: &wgpu::Buffer,
        params: &wgpu::Buffer,
        grads: &wgpu::Buffer,
        grads_extra: &wgpu::Buffer,
        time_grads: &wgpu::Buffer,
        n_train: u32,
    ) {
        run_linear(
            pass,
            device,
            &self.adjoint,
            &[
                (0, uniform),
                (1, params),
                (3, grads),
                (4, grads_extra),
                (5, time_grads),
            ],
            div_ceil(n_train, 256),
        );
    }
}
