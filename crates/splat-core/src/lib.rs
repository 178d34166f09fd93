//! splat-core: the Rust half of pano4d.
//!
//! - [`camera`]: the equirectangular mapping and pinhole cameras shared with Python
//!   (docs/design.md, "Conventions"), checked against `tests/vectors/geometry.json`.
//! - [`gaussians`]: a CPU-side Gaussian set in the 3DGS parameterisation.
//! - [`ply`]: standard and SuperSplat-compressed 3DGS `.ply` files.
//! - [`ply4d`]: the `.ply4d` 4D scene format (docs/ply4d.md).
//! - [`raster`]: the wgpu compute rasteriser (forward and backward).
//! - [`spacetime`]: spacetime Gaussians, one dynamic set with functions of time, evaluated
//!   on the CPU or by a GPU pass (which the trainer and the viewer share).
//! - [`train`]: the lifting phase's training loop resident on the device.
//!
//! Python bindings live in [`python`] behind the `python` feature.

pub mod camera;
pub mod gaussians;
pub mod ply;
pub mod ply4d;
pub mod raster;
pub mod spacetime;
pub mod train;
mod wgsl;

#[cfg(feature = "python")]
mod python;
