//! The wgpu compute rasteriser (forward and backward), headless.
//!
//! Stages (docs/rasterizer.md): project + SH colour + tile count (`project.wgsl`) →
//! stable radix sort by depth → tile intersections in depth order (`tiles.wgsl`) →
//! stable radix sort by tile → per-tile ranges → front-to-back blending
//! (`rasterize.wgsl`). The backward pass re-runs the geometry stages, walks each
//! pixel's contributors back to front (`rasterize_backward.wgsl`) and carries the 2D
//! gradients to the 3D parameters (`project_backward.wgsl`).

pub mod context;
mod kernels;
pub mod renderer;
#[cfg(test)]
mod tests;

pub use context::{AdapterSummary, GpuContext};
pub use renderer::{Gradients, RenderSettings, Renderer, SceneInput};

/// Errors of the rasteriser; the Python binding turns them into exceptions.
#[derive(Debug, thiserror::Error)]
pub enum RasterError {
    #[error("{0}")]
    NoAdapter(String),
    #[error("could not create the GPU device: {0}")]
    Device(String),
    #[error("invalid render input: {0}")]
    InvalidInput(String),
    #[error("GPU error: {0}")]
    Gpu(String),
}
