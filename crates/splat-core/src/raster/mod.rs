//! The wgpu compute rasteriser (forward and backward), headless, organised by stage: each
//! stage's WGSL lies beside the Rust that compiles and dispatches it.
//!
//! Stages (docs/rasterizer.md): `project/` (project.wgsl: projection, SH colour, tile
//! count, depth key) → `sort/` (sort.wgsl around scan.wgsl: the stable radix sort by
//! depth) → `tiles/` (tiles.wgsl: tile counts in depth order, scanned; the plan that sizes
//! the rest of the frame on the GPU; the intersections) → `sort/` again, by tile →
//! `tiles/` (ranges.wgsl: per-tile ranges) → `blend/` (rasterize.wgsl: front-to-back
//! blending). `backward/` walks each pixel's contributors back to front
//! (rasterize_backward.wgsl with its grad_sum_* and grad_add_* variants), sums each
//! Gaussian's 2D gradients with atomics and carries them to the 3D parameters
//! (project_backward.wgsl). `present/` (present.wgsl) writes a frame into the viewer's
//! texture.
//!
//! Shared by the stages: `common.wgsl` (RenderParams, Projected, constants, dispatch and
//! tile helpers), `gaussian_layout.wgsl` (the SoA sections), `gaussian.wgsl` (per-Gaussian
//! maths of the projection and its backward), declared below as the parts each kernel
//! module lists (crate::wgsl); `params.rs` (the settings and the Rust side of
//! RenderParams and Projected), `gpu.rs` (compile, bind, dispatch, submit, read back),
//! `buffers.rs` (the reusable GPU buffers), `gpu_scene.rs` (Gaussian sets kept on the
//! GPU), `frame.rs` (a frame's results and status), `context.rs` (adapter and device).
//! `renderer.rs` holds the [`Renderer`]: every call, each stage dispatched by its module.

mod backward;
mod blend;
mod buffers;
pub mod context;
mod frame;
pub(crate) mod gpu;
mod gpu_scene;
pub(crate) mod params;
mod present;
mod project;
mod renderer;
pub(crate) mod sort;
#[cfg(test)]
mod tests;
mod tiles;

pub use backward::Gradients;
pub use context::{AdapterSummary, DeviceOptions, GpuContext};
pub use frame::{Frame, IntersectionCheck, STATUS_DRAWN};
pub use gpu_scene::{binding_limit, GpuScene, SceneBuffer, StoredSet};
pub use params::{RenderSettings, PIXEL_CHANNELS, TILE_SIZE};
pub use present::{target_texture, TARGET_FORMAT};
pub use renderer::Renderer;

use crate::wgsl::WgslPart;

/// The first part of every rasteriser kernel module.
pub(crate) const COMMON_WGSL: WgslPart = WgslPart {
    file: "common.wgsl",
    source: include_str!("common.wgsl"),
    needs: &[],
    reads: &[],
};
/// Where each parameter of a Gaussian lies in a buffer of SoA sections (also Adam's).
pub(crate) const GAUSSIAN_LAYOUT_WGSL: WgslPart = WgslPart {
    file: "gaussian_layout.wgsl",
    source: include_str!("gaussian_layout.wgsl"),
    needs: &[],
    reads: &[],
};
/// The projection's per-Gaussian maths; the kernel binds the two globals it reads.
pub(crate) const GAUSSIAN_WGSL: WgslPart = WgslPart {
    file: "gaussian.wgsl",
    source: include_str!("gaussian.wgsl"),
    needs: &[COMMON_WGSL.file, GAUSSIAN_LAYOUT_WGSL.file],
    reads: &["params", "gaussians"],
};

/// Every kernel module of the rasteriser, each variant of the backward included (for the
/// checks of the WGSL against the Rust structs).
#[cfg(test)]
pub(crate) fn kernel_modules() -> Vec<crate::wgsl::KernelModule> {
    let mut modules = vec![
        project::module(),
        sort::scan_module(),
        sort::sort_module(),
        tiles::tiles_module(),
        tiles::ranges_module(),
        blend::module(),
        backward::project_backward_module(),
        present::module(),
    ];
    for subgroups in [false, true] {
        for float_atomics in [false, true] {
            modules.push(backward::rasterize_backward_module(
                subgroups,
                float_atomics,
            ));
        }
    }
    modules
}

/// Errors of the rasteriser; the Python binding turns them into exceptions.
#[derive(Debug, thiserror::Error)]
pub enum RasterError {
    #[error("{0}")]
    NoAdapter(String),
    #[error("could not create the GPU device: {0}")]
    Device(String),
    #[error("invalid render input: {0}")]
    InvalidInput(String),
    #[error(
        "{gaussians} Gaussians take {bytes} bytes, more than this device's storage binding \
         limit ({allowed} bytes)"
    )]
    TooLarge {
        gaussians: usize,
        bytes: u64,
        allowed: u64,
    },
    #[error("GPU error: {0}")]
    Gpu(String),
}
