//! Stage 1 (`project.wgsl`): every Gaussian projected by EWA splatting, its SH colour, the
//! number of 16×16 tiles it touches and its depth sort key.

use super::gpu::{compile, div_ceil, run_linear};
use super::{COMMON_WGSL, GAUSSIAN_LAYOUT_WGSL, GAUSSIAN_WGSL};
use crate::wgsl::{KernelModule, WgslPart};

const PROJECT_WGSL: WgslPart = WgslPart {
    file: "project.wgsl",
    source: include_str!("project.wgsl"),
    needs: &[COMMON_WGSL.file, GAUSSIAN_WGSL.file],
    reads: &[],
};

pub(crate) fn module() -> KernelModule {
    KernelModule {
        label: "project",
        parts: vec![
            &COMMON_WGSL,
            &GAUSSIAN_LAYOUT_WGSL,
            &GAUSSIAN_WGSL,
            &PROJECT_WGSL,
        ],
    }
}

/// The buffers of one projection (project.wgsl's bindings 0–5).
pub(crate) struct ProjectBuffers<'a> {
    pub params: &'a wgpu::Buffer,
    pub gaussians: &'a wgpu::Buffer,
    pub projected: &'a wgpu::Buffer,
    pub tile_counts: &'a wgpu::Buffer,
    pub depth_keys: &'a wgpu::Buffer,
    pub depth_vals: &'a wgpu::Buffer,
}

pub(crate) struct ProjectKernel {
    pipeline: wgpu::ComputePipeline,
}

impl ProjectKernel {
    pub(crate) fn new(device: &wgpu::Device) -> Self {
        Self {
            pipeline: compile(device, &module(), &["main"]).remove(0),
        }
    }

    /// Projects `n` Gaussians.
    pub(crate) fn encode(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        device: &wgpu::Device,
        b: &ProjectBuffers<'_>,
        n: u32,
    ) {
        run_linear(
            pass,
            device,
            &self.pipeline,
            &[
                (0, b.params),
                (1, b.gaussians),
                (2, b.projected),
                (3, b.tile_counts),
                (4, b.depth_keys),
                (5, b.depth_vals),
            ],
            div_ceil(n, 256),
        );
    }
}
