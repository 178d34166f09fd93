//! The viewer's frame render path: the Gaussians of the shown timestamp, packed once per
//! timestamp change, drawn by splat-core's forward rasteriser (the same kernels as training
//! and `pano4d render`) into an 8-bit RGBA image.
//!
//! The same [`FrameRenderer`] runs on the device egui created (the window and the UI
//! tests) and on a device of its own (headless rendering and the benchmark).

use std::path::Path;
use std::time::{Duration, Instant};

use image::RgbaImage;
use splat_core::camera::Camera;
use splat_core::gaussians::{sh_coeffs, GaussianSet};
use splat_core::raster::{AdapterSummary, GpuContext, RenderSettings, Renderer, SceneInput};

use crate::scene::Scene;

/// Floats per pixel in the forward's output (r, g, b, alpha, depth).
const FORWARD_CHANNELS: usize = 5;

/// How a frame is drawn, besides the camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameOptions {
    /// Linear 0..1 RGB behind the Gaussians.
    pub background: [f32; 3],
    /// Multiplies every Gaussian's scale (1 = as trained).
    pub splat_scale: f32,
}

impl Default for FrameOptions {
    fn default() -> Self {
        Self {
            background: [0.0; 3],
            splat_scale: 1.0,
        }
    }
}

/// The Gaussians of one timestamp in the rasteriser's flat layout: the static set first,
/// then the shown dynamic set, which is replaced when the timestamp changes.
#[derive(Debug, Default)]
struct PackedScene {
    sh_degree: u32,
    static_len: usize,
    means: Vec<f32>,
    log_scales: Vec<f32>,
    quats: Vec<f32>,
    opacity_logits: Vec<f32>,
    sh: Vec<f32>,
    /// ln(splat scale) added to every stored log-scale.
    log_scale_offset: f32,
}

impl PackedScene {
    fn new(static_set: &GaussianSet) -> Self {
        let mut packed = Self {
            sh_degree: static_set.sh_degree,
            ..Default::default()
        };
        packed.append(static_set);
        packed.static_len = static_set.len();
        packed
    }

    fn len(&self) -> usize {
        self.opacity_logits.len()
    }

    fn append(&mut self, set: &GaussianSet) {
        self.means.extend(set.means.iter().flatten());
        let offset = self.log_scale_offset;
        self.log_scales
            .extend(set.log_scales.iter().flatten().map(|s| s + offset));
        self.quats.extend(set.quats.iter().flatten());
        self.opacity_logits.extend(&set.opacity_logits);
        self.sh.extend(&set.sh);
    }

    /// Replaces the dynamic part with `set`.
    fn set_dynamic(&mut self, set: &GaussianSet) -> Result<(), String> {
        if !set.is_empty() && set.sh_degree != self.sh_degree {
            return Err(format!(
                "the dynamic set has SH degree {}, the static set {}",
                set.sh_degree, self.sh_degree
            ));
        }
        set.validate()?;
        let n = self.static_len;
        self.means.truncate(3 * n);
        self.log_scales.truncate(3 * n);
        self.quats.truncate(4 * n);
        self.opacity_logits.truncate(n);
        self.sh.truncate(3 * sh_coeffs(self.sh_degree) * n);
        self.append(set);
        Ok(())
    }

    fn set_splat_scale(&mut self, scale: f32) {
        let offset = scale.max(1e-3).ln();
        let delta = offset - self.log_scale_offset;
        if delta != 0.0 {
            self.log_scales.iter_mut().for_each(|s| *s += delta);
            self.log_scale_offset = offset;
        }
    }

    fn input(&self) -> SceneInput<'_> {
        SceneInput {
            means: &self.means,
            log_scales: &self.log_scales,
            quats: &self.quats,
            opacity_logits: &self.opacity_logits,
            sh: &self.sh,
        }
    }
}

/// Bytes of the largest buffer the rasteriser allocates per Gaussian set: the packed
/// parameters (11 floats + 3 per SH coefficient per Gaussian).
pub fn gaussian_buffer_bytes(count: usize, sh_degree: u32) -> u64 {
    4 * count as u64 * (11 + 3 * sh_coeffs(sh_degree) as u64)
}

/// Why a scene does not fit, with the advice to use the draft preset. `allowed` is the
/// device's buffer limit when that is the reason, `None` when an allocation failed.
fn too_large_message(count: usize, need: u64, allowed: Option<u64>, adapter: &str) -> String {
    const MIB: u64 = 1 << 20;
    let reason = match allowed {
        Some(limit) => format!("{adapter} allows {} MiB", limit / MIB),
        None => format!("{adapter} ran out of memory"),
    };
    format!(
        "The scene is too large for this GPU: {count} Gaussians need a {} MiB buffer and \
         {reason}. Train it again with the draft preset (fewer Gaussians, lower SH degree), \
         or view it on a GPU with more memory.",
        need.div_ceil(MIB)
    )
}

/// Draws scenes with splat-core's forward rasteriser on one device.
pub struct FrameRenderer {
    renderer: Renderer,
    adapter: AdapterSummary,
    packed: PackedScene,
    /// Timestamp index whose dynamic set is packed.
    shown_time: Option<usize>,
    dynamic_len: usize,
    last_render: Duration,
}

impl FrameRenderer {
    /// A renderer on a device of its own (the adapter `PANO4D_ADAPTER` picks).
    pub fn headless() -> Result<Self, String> {
        let ctx = GpuContext::new().map_err(|e| e.to_string())?;
        Self::with_context(ctx)
    }

    /// A renderer on an existing device, e.g. the one egui draws with.
    pub fn on_device(
        device: wgpu::Device,
        queue: wgpu::Queue,
        info: &wgpu::AdapterInfo,
    ) -> Result<Self, String> {
        // Errors outside an error scope (e.g. an allocation that fails) are reported, not
        // turned into a panic inside the window's event loop.
        device.on_uncaptured_error(std::sync::Arc::new(|e: wgpu::Error| {
            eprintln!("pano4d-view: wgpu error: {e}");
        }));
        let adapter = AdapterSummary::from(info);
        Self::with_context(GpuContext {
            device,
            queue,
            adapter,
        })
    }

    fn with_context(ctx: GpuContext) -> Result<Self, String> {
        let adapter = ctx.adapter.clone();
        let renderer =
            Renderer::new(ctx).map_err(|e| format!("cannot build the rasteriser: {e}"))?;
        Ok(Self {
            renderer,
            adapter,
            packed: PackedScene::default(),
            shown_time: None,
            dynamic_len: 0,
            last_render: Duration::ZERO,
        })
    }

    pub fn adapter(&self) -> &AdapterSummary {
        &self.adapter
    }

    /// Packs `scene`'s static set; the first [`Self::show_time`] adds a dynamic set.
    pub fn load_scene(&mut self, scene: &Scene) {
        self.packed = PackedScene::new(&scene.static_set);
        self.shown_time = None;
        self.dynamic_len = 0;
    }

    /// Makes timestamp `t` the one drawn, reading its dynamic set if it is not packed yet.
    pub fn show_time(&mut self, scene: &Scene, t: usize) -> Result<(), String> {
        if self.shown_time == Some(t) {
            return Ok(());
        }
        let dynamic = scene.dynamic_set(t)?;
        self.packed.set_dynamic(&dynamic)?;
        self.dynamic_len = dynamic.len();
        self.shown_time = Some(t);
        Ok(())
    }

    pub fn shown_time(&self) -> Option<usize> {
        self.shown_time
    }

    /// (static, dynamic) Gaussians in the frame drawn.
    pub fn counts(&self) -> (usize, usize) {
        (self.packed.static_len, self.dynamic_len)
    }

    /// GPU time plus read-back of the last [`Self::render`].
    pub fn last_render_time(&self) -> Duration {
        self.last_render
    }

    /// Whether the packed scene fits the device's buffer limits (a message if not).
    fn check_fits(&self) -> Result<(), String> {
        let limits = self.renderer.context().device.limits();
        let allowed = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let need = gaussian_buffer_bytes(self.packed.len(), self.packed.sh_degree);
        if need > allowed {
            return Err(too_large_message(
                self.packed.len(),
                need,
                Some(allowed),
                &self.adapter.name,
            ));
        }
        Ok(())
    }

    /// Draws the shown timestamp from `camera` with `options`.
    pub fn render(&mut self, camera: &Camera, options: &FrameOptions) -> Result<RgbaImage, String> {
        self.check_fits()?;
        self.packed.set_splat_scale(options.splat_scale);
        let settings = RenderSettings {
            background: options.background,
            antialiased: false,
        };
        let start = Instant::now();
        let device = self.renderer.context().device.clone();
        // Allocations and bind groups the rasteriser creates outside its own error scopes
        // report here, so that "too large for this GPU" is recognised.
        let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out_of_memory = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let result = self
            .renderer
            .forward(&self.packed.input(), camera, &settings);
        let out_of_memory = pollster::block_on(out_of_memory.pop());
        let invalid = pollster::block_on(validation.pop());
        let need = gaussian_buffer_bytes(self.packed.len(), self.packed.sh_degree);
        if out_of_memory.is_some() {
            return Err(too_large_message(
                self.packed.len(),
                need,
                None,
                &self.adapter.name,
            ));
        }
        if let Some(error) = invalid {
            let error = error.to_string();
            if exceeds_buffer_limit(&error) {
                let allowed = device.limits().max_storage_buffer_binding_size;
                let message =
                    too_large_message(self.packed.len(), need, Some(allowed), &self.adapter.name);
                return Err(format!("{message} ({error})"));
            }
            return Err(format!("GPU error: {error}"));
        }
        let (pixels, _intersections) = result.map_err(|e| e.to_string())?;
        self.last_render = start.elapsed();
        Ok(to_rgba8(&pixels, camera.width, camera.height))
    }
}

/// Whether a GPU error is a buffer over the device's size limits. The rasteriser's buffers
/// grow with headroom, so a set just under the limit can still cross it there.
fn exceeds_buffer_limit(error: &str) -> bool {
    error.contains("buffer_binding_size") || error.contains("max_buffer_size")
}

/// The forward's float RGB (background already blended in) as opaque 8-bit RGBA.
fn to_rgba8(pixels: &[f32], width: u32, height: u32) -> RgbaImage {
    let bytes = pixels
        .chunks_exact(FORWARD_CHANNELS)
        .flat_map(|p| {
            let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
            [q(p[0]), q(p[1]), q(p[2]), 255]
        })
        .collect();
    RgbaImage::from_raw(width, height, bytes).expect("the forward returns width × height pixels")
}

/// Writes `image` as a PNG at `path` atomically (a temporary file beside it, then rename).
pub fn save_png(image: &RgbaImage, path: &Path) -> Result<(), String> {
    let file_name = path
        .file_name()
        .ok_or_else(|| format!("{} is not a file path", path.display()))?;
    let tmp = path.with_file_name(format!(
        ".{}.{}.tmp",
        file_name.to_string_lossy(),
        std::process::id()
    ));
    let written = image
        .save_with_format(&tmp, image::ImageFormat::Png)
        .map_err(|e| format!("cannot write {}: {e}", path.display()))
        .and_then(|()| {
            std::fs::rename(&tmp, path).map_err(|e| format!("cannot write {}: {e}", path.display()))
        });
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic;

    #[test]
    fn packing_replaces_only_the_dynamic_part_and_scales() {
        let scene = synthetic::scene(30, 5, 2, 1, 3);
        let mut packed = PackedScene::new(&scene.static_set);
        packed.set_dynamic(&scene.dynamic[0]).unwrap();
        assert_eq!(packed.len(), 35);
        packed.set_dynamic(&scene.dynamic[1]).unwrap();
        assert_eq!(packed.len(), 35);
        assert_eq!(packed.means[3 * 30..3 * 31], scene.dynamic[1].means[0]);
        assert_eq!(packed.sh.len(), 35 * 4 * 3);
        assert_eq!(packed.sh[30 * 12..31 * 12], scene.dynamic[1].sh[..12]);
        let before = packed.log_scales[0];
        packed.set_splat_scale(2.0);
        assert!((packed.log_scales[0] - before - 2f32.ln()).abs() < 1e-6);
        // A new dynamic set arrives at the current splat scale.
        packed.set_dynamic(&scene.dynamic[0]).unwrap();
        let expected = scene.dynamic[0].log_scales[0][0] + 2f32.ln();
        assert!((packed.log_scales[3 * 30] - expected).abs() < 1e-6);
        packed.set_splat_scale(1.0);
        assert!((packed.log_scales[0] - before).abs() < 1e-6);
        let other_degree = synthetic::scene(1, 1, 1, 2, 3);
        assert!(packed
            .set_dynamic(&other_degree.dynamic[0])
            .unwrap_err()
            .contains("SH degree"));
    }

    #[test]
    fn rgba_conversion_clamps_and_is_opaque() {
        let pixels = [0.0, 0.5, 1.5, 0.3, 7.0, -1.0, 1.0, 0.25, 1.0, 2.0];
        let image = to_rgba8(&pixels, 2, 1);
        assert_eq!(image.get_pixel(0, 0).0, [0, 128, 255, 255]);
        assert_eq!(image.get_pixel(1, 0).0, [0, 255, 64, 255]);
    }

    #[test]
    fn buffer_size_and_message() {
        assert_eq!(gaussian_buffer_bytes(1_000_000, 3), 4 * 1_000_000 * 59);
        let msg = too_large_message(10, 300 << 20, Some(128 << 20), "lavapipe");
        assert!(msg.contains("300 MiB") && msg.contains("128 MiB") && msg.contains("draft preset"));
        assert!(too_large_message(10, 1, None, "gpu").contains("ran out of memory"));
        let wgpu_message =
            "Buffer binding 1 range 147500000 exceeds `max_*_buffer_binding_size` limit";
        assert!(exceeds_buffer_limit(wgpu_message));
        assert!(!exceeds_buffer_limit("BindGroup with '' label is invalid"));
    }
}
