//! The backward pass (docs/rasterizer.md, "Backward"): gradients of a loss w.r.t. the
//! Gaussians, given its gradient w.r.t. the forward's output. `rasterize_backward.wgsl`
//! walks each pixel's contributors back to front and sums each Gaussian's 2D gradients
//! (the tile sum and the global add each in one of two variants, by what the device has);
//! `project_backward.wgsl` carries them to the 3D parameters.

use super::gpu::{compile, div_ceil, run_linear, run_per_tile};
use super::{COMMON_WGSL, GAUSSIAN_LAYOUT_WGSL, GAUSSIAN_WGSL};
use crate::wgsl::{KernelModule, WgslPart};

const RASTERIZE_BACKWARD_WGSL: WgslPart = WgslPart {
    file: "rasterize_backward.wgsl",
    source: include_str!("rasterize_backward.wgsl"),
    needs: &[COMMON_WGSL.file],
    reads: &[],
};
// The tile sum (`sum_grads`), without or with subgroup operations; both call
// rasterize_backward.wgsl's `add_tile_grad`.
const GRAD_SUM_PLAIN_WGSL: WgslPart = WgslPart {
    file: "grad_sum_plain.wgsl",
    source: include_str!("grad_sum_plain.wgsl"),
    needs: &[RASTERIZE_BACKWARD_WGSL.file],
    reads: &[],
};
const GRAD_SUM_SUBGROUP_WGSL: WgslPart = WgslPart {
    file: "grad_sum_subgroup.wgsl",
    source: include_str!("grad_sum_subgroup.wgsl"),
    needs: &[RASTERIZE_BACKWARD_WGSL.file],
    reads: &[],
};
// The per-Gaussian sums' binding (6) and `add_gaussian_grad`: native f32 atomics or a
// compare-exchange loop.
const GRAD_ADD_FLOAT_WGSL: WgslPart = WgslPart {
    file: "grad_add_float.wgsl",
    source: include_str!("grad_add_float.wgsl"),
    needs: &[],
    reads: &[],
};
const GRAD_ADD_CAS_WGSL: WgslPart = WgslPart {
    file: "grad_add_cas.wgsl",
    source: include_str!("grad_add_cas.wgsl"),
    needs: &[],
    reads: &[],
};
const PROJECT_BACKWARD_WGSL: WgslPart = WgslPart {
    file: "project_backward.wgsl",
    source: include_str!("project_backward.wgsl"),
    needs: &[COMMON_WGSL.file, GAUSSIAN_WGSL.file],
    reads: &[],
};

/// The rasterisation backward with subgroup sums or not, native float atomics or not.
pub(crate) fn rasterize_backward_module(subgroups: bool, float_atomics: bool) -> KernelModule {
    let grad_sum = if subgroups {
        &GRAD_SUM_SUBGROUP_WGSL
    } else {
        &GRAD_SUM_PLAIN_WGSL
    };
    let grad_add = if float_atomics {
        &GRAD_ADD_FLOAT_WGSL
    } else {
        &GRAD_ADD_CAS_WGSL
    };
    KernelModule {
        label: "rasterize_backward",
        parts: vec![&COMMON_WGSL, grad_sum, grad_add, &RASTERIZE_BACKWARD_WGSL],
    }
}

pub(crate) fn project_backward_module() -> KernelModule {
    KernelModule {
        label: "project_backward",
        parts: vec![
            &COMMON_WGSL,
            &GAUSSIAN_LAYOUT_WGSL,
            &GAUSSIAN_WGSL,
            &PROJECT_BACKWARD_WGSL,
        ],
    }
}

/// Floats of each Gaussian's 2D gradient sums: mean2d (2), conic (3), rgb (3), opacity,
/// depth (rasterize_backward.wgsl).
pub(crate) const GAUSSIAN_GRAD_FLOATS: u64 = 10;

/// Gradients in the layout of [`crate::gaussians::SceneInput`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Gradients {
    pub means: Vec<f32>,
    pub log_scales: Vec<f32>,
    pub quats: Vec<f32>,
    pub opacity_logits: Vec<f32>,
    pub sh: Vec<f32>,
}

/// What one backward reads and writes (the bindings of both kernels).
pub(crate) struct BackwardBuffers<'a> {
    pub params: &'a wgpu::Buffer,
    pub gaussians: &'a wgpu::Buffer,
    pub projected: &'a wgpu::Buffer,
    pub tile_counts: &'a wgpu::Buffer,
    pub sorted_gaussians: &'a wgpu::Buffer,
    pub ranges: &'a wgpu::Buffer,
    pub pixel_state: &'a wgpu::Buffer,
    pub v_pixels: &'a wgpu::Buffer,
    /// Each Gaussian's ten 2D gradient sums, zeroed by the caller.
    pub sums: &'a wgpu::Buffer,
    pub grads: &'a wgpu::Buffer,
}

pub(crate) struct BackwardKernels {
    rasterize_backward: wgpu::ComputePipeline,
    project_backward: wgpu::ComputePipeline,
}

impl BackwardKernels {
    /// Subgroup sums cut the backward's contention, native float atomics its global
    /// adds, where the device has them.
    pub(crate) fn new(device: &wgpu::Device, subgroups: bool, float_atomics: bool) -> Self {
        let rasterize = rasterize_backward_module(subgroups, float_atomics);
        Self {
            rasterize_backward: compile(device, &rasterize, &["main"]).remove(0),
            project_backward: compile(device, &project_backward_module(), &["main"]).remove(0),
        }
    }

    /// The backward of a frame of `n` Gaussians on a `tiles` (x, y) grid.
    pub(crate) fn encode(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        device: &wgpu::Device,
        b: &BackwardBuffers<'_>,
        n: u32,
        tiles: (u32, u32),
    ) {
        run_per_tile(
            pass,
            device,
            &self.rasterize_backward,
            &[
                (0, b.params),
                (1, b.projected),
                (2, b.sorted_gaussians),
                (3, b.ranges),
                (4, b.pixel_state),
                (5, b.v_pixels),
                (6, b.sums),
            ],
            tiles,
        );
        if n > 0 {
            run_linear(
                pass,
                device,
                &self.project_backward,
                &[
                    (0, b.params),
                    (1, b.gaussians),
                    (2, b.tile_counts),
                    (3, b.sums),
                    (4, b.grads),
                ],
                div_ceil(n, 256),
            );
        }
    }
}
