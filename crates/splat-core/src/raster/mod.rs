//! The wgpu compute rasteriser (forward and backward), headless.
//!
//! Stages (docs/rasterizer.md): project + SH colour + tile count (`project.wgsl`) →
//! stable radix sort by depth → tile intersections in depth order (`tiles.wgsl`, sized
//! on the GPU) → stable radix sort by tile → per-tile ranges → front-to-back blending
//! (`rasterize.wgsl`). The backward pass walks each pixel's contributors back to front
//! (`rasterize_backward.wgsl`), sums each Gaussian's 2D gradients with atomics and
//! carries them to the 3D parameters (`project_backward.wgsl`).
//!
//! Files: `renderer.rs` (pipelines, the calls that wait: forward, draw), `frame.rs` (one
//! frame encoded without waiting, the intersection capacity), `backward.rs`, `buffers.rs`
//! (the reusable GPU buffers), `kernels.rs` (sort, scan and dispatch helpers),
//! `resident.rs` (scenes kept on the GPU), `context.rs` (adapter and device).

mod backward;
mod buffers;
pub mod context;
mod frame;
pub(crate) mod kernels;
pub mod renderer;
mod resident;
#[cfg(test)]
mod tests;

pub use backward::Gradients;
pub use context::{AdapterSummary, DeviceOptions, GpuContext};
pub use frame::{IntersectionCheck, STATUS_DRAWN};
pub use renderer::{target_texture, Frame, RenderSettings, Renderer, TARGET_FORMAT};
pub use resident::{binding_limit, ResidentScene, SceneBuffer, StoredSet};

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
