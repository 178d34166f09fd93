//! Stage 7 (`rasterize.wgsl`): per-tile front-to-back blending of the tile-sorted
//! intersections, one 16×16 workgroup per tile; writes each pixel's colour, alpha and
//! depth, and the state the backward walks back from; copies the tiles of a frozen static set
//! alone from that static set's own render where the caller has one.

use super::gpu::{compile, run_per_tile};
use super::COMMON_WGSL;
use crate::wgsl::{KernelModule, WgslPart};

const RASTERIZE_WGSL: WgslPart = WgslPart {
    file: "rasterize.wgsl",
    source: include_str!("rasterize.wgsl"),
    needs: &[COMMON_WGSL.file],
    reads: &[],
};

pub(crate) fn module() -> KernelModule {
    KernelModule {
        label: "rasterize",
        parts: vec![&COMMON_WGSL, &RASTERIZE_WGSL],
    }
}

/// rasterize.wgsl's bindings 0–6.
pub(crate) struct BlendBuffers<'a> {
    pub params: &'a wgpu::Buffer,
    pub projected: &'a wgpu::Buffer,
    pub sorted_gaussians: &'a wgpu::Buffer,
    pub ranges: &'a wgpu::Buffer,
    pub pixels: &'a wgpu::Buffer,
    pub pixel_state: &'a wgpu::Buffer,
    /// The static set's own render of the camera (any buffer when the frame has none).
    pub static_pixels: &'a wgpu::Buffer,
}

pub(crate) struct BlendKernel {
    pipeline: wgpu::ComputePipeline,
}

impl BlendKernel {
    pub(crate) fn new(device: &wgpu::Device) -> Self {
        Self {
            pipeline: compile(device, &module(), &["main"]).remove(0),
        }
    }

    /// Blends every tile of a `tiles` (x, y) grid.
    pub(crate) fn encode(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        device: &wgpu::Device,
        b: &BlendBuffers<'_>,
        tiles: (u32, u32),
    ) {
        run_per_tile(
            pass,
            device,
            &self.pipeline,
            &[
                (0, b.params),
                (1, b.projected),
                (2, b.sorted_gaussians),
                (3, b.ranges),
                (4, b.pixels),
                (5, b.pixel_state),
                (6, b.static_pixels),
            ],
            tiles,
        );
    }
}
