//! pano4d-view: a 6-DoF viewer for `.ply4d` scenes (and plain 3DGS `.ply` files and
//! folders of per-frame `.ply` files), drawn with splat-core's forward rasteriser on the
//! wgpu device egui created.
//!
//! - [`camera`]: fly/orbit camera maths, pose strings, the support hint.
//! - [`camera_path`]: keyframes into nerfstudio's `camera_path.json` (`pano4d render --path`).
//! - [`spline`]: the Kochanek–Bartels curves nerfstudio's viewer interpolates a path with.
//! - [`scene`]: opening files and streaming dynamic sets per timestamp.
//! - [`stream`]: dynamic sets decoded ahead of playback on a worker thread.
//! - [`time`]: the shown time, in frames, and how it moves: play, pause, loop, speed and
//!   steps; continuous through a version-2 scene's loop, held at each timestamp otherwise.
//! - [`render`]: the frame render path shared by the window, headless use and the bench.
//! - [`residency`]: whether every timestamp's dynamic set stays on the GPU.
//! - [`headless`]: one view to an image, without a window.
//! - [`app`]: the egui application.
//! - [`edit`]: the region editor (`--edit scene.yaml`).
//! - [`synthetic`]: a small generated 4D scene for tests and the benchmark.

pub mod app;
pub mod camera;
pub mod camera_path;
pub mod edit;
pub mod headless;
pub mod render;
pub mod residency;
pub mod scene;
pub mod spline;
pub mod stream;
pub mod synthetic;
pub mod time;

use std::sync::Arc;

use eframe::egui_wgpu;

/// egui's wgpu set-up with the adapter's own limits instead of WebGPU's defaults: scenes of
/// millions of Gaussians need storage buffers larger than the default 128 MiB.
pub fn full_limits(mut setup: egui_wgpu::WgpuSetupCreateNew) -> egui_wgpu::WgpuSetupCreateNew {
    setup.device_descriptor = Arc::new(|adapter: &wgpu::Adapter| wgpu::DeviceDescriptor {
        label: Some("pano4d-view device"),
        required_limits: adapter.limits(),
        ..Default::default()
    });
    setup
}
