//! What every stage of a frame reads: the per-call [`RenderSettings`], the uniform
//! [`RenderParams`] made from them and the camera, and the [`Projected`] Gaussian the
//! projection hands to binning, blending and the backward (both declared once here; WGSL
//! declares them in common.wgsl, checked by the wgsl tests).

use super::gpu::div_ceil;
use super::gpu_scene::SceneBuffer;
use super::RasterError;
use crate::camera::Camera;
use crate::wgsl::gpu_struct;

pub const TILE_SIZE: u32 = 16;
/// Floats per output pixel: r, g, b, alpha, accumulated depth.
pub const PIXEL_CHANNELS: usize = 5;
/// The EWA Jacobian clamps x/z and y/z to this multiple of tan(half fov), as 3DGS does.
const JACOBIAN_CLAMP: f64 = 1.3;

/// Per-call options.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    pub background: [f32; 3],
    /// Draw through Mip-Splatting's 2D filter: Σ2D + 0.1 I with the opacity multiplied by
    /// sqrt(det Σ2D / det(Σ2D + 0.1 I)); classic adds 3DGS's 0.3 I at full opacity.
    pub antialiased: bool,
    /// Multiplies every Gaussian's scale as it is drawn (the viewer's slider; 1 = as stored).
    pub splat_scale: f32,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            background: [0.0; 3],
            antialiased: false,
            splat_scale: 1.0,
        }
    }
}

gpu_struct! {
    /// The uniform every rasteriser kernel reads (common.wgsl documents each field).
    pub(crate) struct RenderParams {
        rot_row0: [f32; 4],
        rot_row1: [f32; 4],
        rot_row2: [f32; 4],
        cam_pos: [f32; 4],
        intrinsics: [f32; 4],
        jacobian_limits: [f32; 4],
        background: [f32; 4],
        pub(crate) width: u32,
        pub(crate) height: u32,
        pub(crate) tiles_x: u32,
        pub(crate) tiles_y: u32,
        pub(crate) num_gaussians: u32,
        pub(crate) sh_coeffs: u32,
        antialiased: u32,
        pub(crate) intersection_capacity: u32,
        gaussian_stride: u32,
        log_scale_offset: f32,
        pub(crate) record_overflow: u32,
        n_static: u32,
        pub(crate) static_render: u32,
        pad0: u32,
        pad1: u32,
        pad2: u32,
    }
}

gpu_struct! {
    /// One projected Gaussian, as the projection writes it (the host sizes them and
    /// reads footprints from them).
    pub(crate) struct Projected {
        xy_opacity_z: [f32; 4],
        conic_radius: [f32; 4],
        rgb: [f32; 4],
    }
}

impl Projected {
    /// Pixel centre x, y and footprint radius (radius 0: culled, project.wgsl's `cull`).
    pub(crate) fn footprint(&self) -> [f32; 3] {
        [
            self.xy_opacity_z[0],
            self.xy_opacity_z[1],
            self.conic_radius[3],
        ]
    }
}

impl RenderParams {
    pub(crate) fn new(camera: &Camera, settings: &RenderSettings, scene: &SceneBuffer) -> Self {
        let r = camera.rotation;
        let t = camera.translation;
        let row = |i: usize| {
            let v = r.row(i);
            [v.x as f32, v.y as f32, v.z as f32, t[i] as f32]
        };
        let p = camera.position();
        let tan = camera.half_fov_tan;
        let bg = settings.background;
        Self {
            rot_row0: row(0),
            rot_row1: row(1),
            rot_row2: row(2),
            cam_pos: [p.x as f32, p.y as f32, p.z as f32, 0.0],
            intrinsics: [
                camera.fx as f32,
                camera.fy as f32,
                camera.cx as f32,
                camera.cy as f32,
            ],
            jacobian_limits: [
                (JACOBIAN_CLAMP * tan.x) as f32,
                (JACOBIAN_CLAMP * tan.y) as f32,
                0.0,
                0.0,
            ],
            background: [bg[0], bg[1], bg[2], 0.0],
            width: camera.width,
            height: camera.height,
            tiles_x: div_ceil(camera.width, TILE_SIZE),
            tiles_y: div_ceil(camera.height, TILE_SIZE),
            num_gaussians: scene.len,
            sh_coeffs: scene.sh_coeffs,
            antialiased: settings.antialiased as u32,
            intersection_capacity: 0,
            gaussian_stride: scene.stride,
            log_scale_offset: settings.splat_scale.ln(),
            record_overflow: 0,
            n_static: scene.n_static,
            static_render: 0,
            pad0: 0,
            pad1: 0,
            pad2: 0,
        }
    }

    /// The frame's tile grid (x, y): one workgroup per tile for blending and its backward.
    pub(crate) fn tiles(&self) -> (u32, u32) {
        (self.tiles_x, self.tiles_y)
    }
}

pub(crate) fn validate_settings(settings: &RenderSettings) -> Result<(), RasterError> {
    if !settings.background.iter().all(|v| v.is_finite()) {
        return Err(RasterError::InvalidInput(
            "background must be finite".into(),
        ));
    }
    let scale = settings.splat_scale;
    if !(scale.is_finite() && scale > 0.0) {
        return Err(RasterError::InvalidInput(format!(
            "splat scale must be finite and > 0, got {scale}"
        )));
    }
    Ok(())
}

pub(crate) fn validate_camera(camera: &Camera) -> Result<(), RasterError> {
    let finite = [camera.fx, camera.fy, camera.cx, camera.cy]
        .iter()
        .all(|v| v.is_finite())
        && camera.rotation.is_finite()
        && camera.translation.is_finite()
        && camera.half_fov_tan.is_finite();
    if !finite || camera.fx <= 0.0 || camera.fy <= 0.0 || camera.half_fov_tan.min_element() <= 0.0 {
        return Err(RasterError::InvalidInput(
            "camera intrinsics, field of view and pose must be finite with fx, fy and the \
             half field of view's tangents > 0"
                .into(),
        ));
    }
    if camera.width == 0 || camera.height == 0 || camera.width > 16384 || camera.height > 16384 {
        return Err(RasterError::InvalidInput(format!(
            "image size must be 1..=16384 per side, got {}x{}",
            camera.width, camera.height
        )));
    }
    Ok(())
}
