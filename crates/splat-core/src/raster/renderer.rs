//! The rasteriser's pipelines and its calls that wait for their results: `forward`,
//! `draw` (the frame itself is encoded in frame.rs, the backward in backward.rs).

use super::buffers::{Buffers, STATUS_WORDS};
use super::context::GpuContext;
use super::kernels::{compile, div_ceil, SortKernels, COMMON_WGSL, GAUSSIAN_WGSL};
use super::resident::{check_scene_fits, ResidentScene, SceneBuffer};
use super::RasterError;
use crate::camera::Camera;
use crate::gaussians::SceneInput;

const PROJECT_WGSL: &str = include_str!("../../../../shaders/project.wgsl");
const TILES_WGSL: &str = include_str!("../../../../shaders/tiles.wgsl");
const RANGES_WGSL: &str = include_str!("../../../../shaders/ranges.wgsl");
const RASTERIZE_WGSL: &str = include_str!("../../../../shaders/rasterize.wgsl");
const RASTERIZE_BACKWARD_WGSL: &str = include_str!("../../../../shaders/rasterize_backward.wgsl");
const PROJECT_BACKWARD_WGSL: &str = include_str!("../../../../shaders/project_backward.wgsl");
const PRESENT_WGSL: &str = include_str!("../../../../shaders/present.wgsl");
const GRAD_SUM_PLAIN_WGSL: &str = include_str!("../../../../shaders/grad_sum_plain.wgsl");
const GRAD_SUM_SUBGROUP_WGSL: &str = include_str!("../../../../shaders/grad_sum_subgroup.wgsl");
const GRAD_ADD_FLOAT_WGSL: &str = include_str!("../../../../shaders/grad_add_float.wgsl");
const GRAD_ADD_CAS_WGSL: &str = include_str!("../../../../shaders/grad_add_cas.wgsl");

pub const TILE_SIZE: u32 = 16;
/// Floats per output pixel: r, g, b, alpha, accumulated depth.
pub const PIXEL_CHANNELS: usize = 5;
/// Floats per projected Gaussian (`Projected` in common.wgsl).
pub(super) const PROJECTED_FLOATS: u64 = 12;
/// The EWA Jacobian clamps x/z and y/z to this multiple of tan(half fov), as 3DGS does.
const JACOBIAN_CLAMP: f64 = 1.3;

/// Per-call options.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    pub background: [f32; 3],
    /// Multiply opacity by sqrt(det Σ2D / det(Σ2D + 0.3 I)) (Mip-Splatting's 2D filter).
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

/// The texture format [`Renderer::draw`] writes: the forward's colours (display values,
/// clamped to 0..1) as 8-bit RGBA, sampled as they are (egui takes texture samples as
/// display values).
pub const TARGET_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// A texture [`Renderer::draw`] can write, egui can sample and [`Renderer::read_rgba8`]
/// can copy out.
pub fn target_texture(device: &wgpu::Device, width: u32, height: u32) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some("render target"),
        size: wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: TARGET_FORMAT,
        usage: wgpu::TextureUsages::STORAGE_BINDING
            | wgpu::TextureUsages::TEXTURE_BINDING
            | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    })
}

#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct RenderParams {
    rot_rows: [[f32; 4]; 3],
    cam_pos: [f32; 4],
    intrinsics: [f32; 4],
    jacobian_limits: [f32; 4],
    background: [f32; 4],
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) tiles_x: u32,
    pub(super) tiles_y: u32,
    pub(super) num_gaussians: u32,
    pub(super) sh_coeffs: u32,
    antialiased: u32,
    pub(super) intersection_capacity: u32,
    gaussian_stride: u32,
    log_scale_offset: f32,
    pub(super) record_overflow: u32,
    pad: u32,
}

pub(super) fn render_params(
    camera: &Camera,
    settings: &RenderSettings,
    scene: &SceneBuffer,
) -> RenderParams {
    let r = camera.rotation;
    let t = camera.translation;
    let row = |i: usize| {
        let v = r.row(i);
        [v.x as f32, v.y as f32, v.z as f32, t[i] as f32]
    };
    let p = camera.position();
    let tan_x = 0.5 * camera.width as f64 / camera.fx;
    let tan_y = 0.5 * camera.height as f64 / camera.fy;
    let bg = settings.background;
    RenderParams {
        rot_rows: [row(0), row(1), row(2)],
        cam_pos: [p.x as f32, p.y as f32, p.z as f32, 0.0],
        intrinsics: [
            camera.fx as f32,
            camera.fy as f32,
            camera.cx as f32,
            camera.cy as f32,
        ],
        jacobian_limits: [
            (JACOBIAN_CLAMP * tan_x) as f32,
            (JACOBIAN_CLAMP * tan_y) as f32,
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
        pad: 0,
    }
}

pub(super) fn validate_settings(settings: &RenderSettings) -> Result<(), RasterError> {
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

pub(super) fn validate_camera(camera: &Camera) -> Result<(), RasterError> {
    let finite = [camera.fx, camera.fy, camera.cx, camera.cy]
        .iter()
        .all(|v| v.is_finite())
        && camera.rotation.is_finite()
        && camera.translation.is_finite();
    if !finite || camera.fx <= 0.0 || camera.fy <= 0.0 {
        return Err(RasterError::InvalidInput(
            "camera intrinsics and pose must be finite with fx, fy > 0".into(),
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

/// One frame's results on the GPU, from [`Renderer::encode_frame`] (the forward's output
/// is at [`Renderer::frame_pixels`], its status at [`Renderer::frame_status`]): what its
/// backward needs. The buffers are the renderer's own: the next `encode_frame` on the same
/// renderer overwrites them.
pub struct Frame {
    pub(super) scene: SceneBuffer,
    pub(super) params: RenderParams,
    pub(super) projected: wgpu::Buffer,
    pub(super) tile_counts: wgpu::Buffer,
    /// Gaussian ids of the intersections, sorted by tile (depth order within a tile).
    pub(super) sorted_gaussians: wgpu::Buffer,
    pub(super) ranges: wgpu::Buffer,
    pub(super) pixel_state: wgpu::Buffer,
    pub(super) pixels: wgpu::Buffer,
}

impl Frame {
    /// (width, height) in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.params.width, self.params.height)
    }

    pub fn num_gaussians(&self) -> u32 {
        self.params.num_gaussians
    }
}

/// Compiled pipelines and reusable buffers on one device. Not thread-safe by itself:
/// callers serialise access (the Python binding keeps one behind a mutex).
pub struct Renderer {
    pub(super) ctx: GpuContext,
    pub(super) sort: SortKernels,
    pub(super) project: wgpu::ComputePipeline,
    pub(super) gather_counts: wgpu::ComputePipeline,
    pub(super) plan_intersections: wgpu::ComputePipeline,
    pub(super) emit: wgpu::ComputePipeline,
    pub(super) ranges: wgpu::ComputePipeline,
    pub(super) rasterize: wgpu::ComputePipeline,
    pub(super) rasterize_backward: wgpu::ComputePipeline,
    pub(super) project_backward: wgpu::ComputePipeline,
    present: wgpu::ComputePipeline,
    pub(super) buffers: Buffers,
    /// Tile intersections a frame has room for (0 until the first frame sizes it).
    pub(super) intersection_capacity: u32,
    /// The status buffer's overflow count at the last `check_intersections`.
    pub(super) overflows_seen: u32,
}

pub(crate) fn pop_error(scope: wgpu::ErrorScopeGuard) -> Result<(), RasterError> {
    match pollster::block_on(scope.pop()) {
        Some(e) => Err(RasterError::Gpu(e.to_string())),
        None => Ok(()),
    }
}

/// Submits `encoder`, turning validation errors into [`RasterError::Gpu`].
pub(crate) fn submit_checked(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    encoder: wgpu::CommandEncoder,
) -> Result<(), RasterError> {
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    queue.submit([encoder.finish()]);
    pop_error(scope)
}

/// Maps the first `bytes` of `staging` (a MAP_READ buffer whose copy has been submitted),
/// waits for the device and returns them.
pub(crate) fn read_mapped(
    device: &wgpu::Device,
    staging: &wgpu::Buffer,
    bytes: u64,
) -> Result<Vec<u8>, RasterError> {
    let slice = staging.slice(..bytes);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| RasterError::Gpu(e.to_string()))?;
    rx.recv()
        .map_err(|e| RasterError::Gpu(e.to_string()))?
        .map_err(|e| RasterError::Gpu(e.to_string()))?;
    let data = slice
        .get_mapped_range()
        .map_err(|e| RasterError::Gpu(e.to_string()))?
        .to_vec();
    staging.unmap();
    Ok(data)
}

impl Renderer {
    pub fn new(ctx: GpuContext) -> Result<Self, RasterError> {
        let device = &ctx.device;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let one =
            |label: &str, sources: &[&str]| compile(device, label, sources, &["main"]).remove(0);
        let tiles = compile(
            device,
            "tiles",
            &[COMMON_WGSL, TILES_WGSL],
            &["gather_counts", "plan_intersections", "emit_intersections"],
        );
        let [gather_counts, plan_intersections, emit]: [wgpu::ComputePipeline; 3] =
            tiles.try_into().expect("three tiles entry points");
        // Subgroup sums cut the backward's contention, native float atomics its global
        // adds, where the device has them.
        let grad_sum = if ctx.has_subgroups() {
            GRAD_SUM_SUBGROUP_WGSL
        } else {
            GRAD_SUM_PLAIN_WGSL
        };
        let grad_add = if ctx.has_float_atomics() {
            GRAD_ADD_FLOAT_WGSL
        } else {
            GRAD_ADD_CAS_WGSL
        };
        let renderer = Self {
            sort: SortKernels::new(device),
            project: one("project", &[COMMON_WGSL, GAUSSIAN_WGSL, PROJECT_WGSL]),
            gather_counts,
            plan_intersections,
            emit,
            ranges: one("ranges", &[COMMON_WGSL, RANGES_WGSL]),
            rasterize: one("rasterize", &[COMMON_WGSL, RASTERIZE_WGSL]),
            rasterize_backward: one(
                "rasterize_backward",
                &[COMMON_WGSL, grad_sum, grad_add, RASTERIZE_BACKWARD_WGSL],
            ),
            project_backward: one(
                "project_backward",
                &[COMMON_WGSL, GAUSSIAN_WGSL, PROJECT_BACKWARD_WGSL],
            ),
            present: one("present", &[COMMON_WGSL, PRESENT_WGSL]),
            buffers: Buffers::new(device),
            intersection_capacity: 0,
            overflows_seen: 0,
            ctx,
        };
        pop_error(scope)?;
        Ok(renderer)
    }

    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// Copies `bytes` of `src` from byte `offset` to the host (waits for the queue).
    pub(super) fn read_back(
        &mut self,
        src: &wgpu::Buffer,
        offset: u64,
        bytes: u64,
    ) -> Result<Vec<u8>, RasterError> {
        let device = &self.ctx.device;
        let staging = self.buffers.readback.get(device, bytes).clone();
        let mut encoder = device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(src, offset, &staging, 0, bytes);
        self.ctx.queue.submit([encoder.finish()]);
        read_mapped(&self.ctx.device, &staging, bytes)
    }

    /// Copies `scene` into the renderer's own Gaussian buffer (training and one-off
    /// renders; the viewer keeps a [`ResidentScene`] instead).
    pub(super) fn upload(&mut self, scene: &SceneInput<'_>) -> Result<SceneBuffer, RasterError> {
        let (n, k) = scene.validate().map_err(RasterError::InvalidInput)?;
        let device = &self.ctx.device;
        let bytes = ResidentScene::bytes_for(n as usize, k as usize);
        check_scene_fits(device, n as usize, k as usize)?;
        let buffer = self.buffers.gaussians.get(device, bytes).clone();
        self.ctx
            .queue
            .write_buffer(&buffer, 0, bytemuck::cast_slice(&scene.packed()));
        Ok(SceneBuffer {
            buffer,
            len: n,
            stride: n,
            sh_coeffs: k,
        })
    }

    /// For the calls that wait for their frame anyway (`forward`, `backward`, `draw`):
    /// encodes `scene`'s frame and what `then` adds to it, waits, and returns the frame's
    /// tile intersections and the bytes of the buffer `then` names (none if it names
    /// none). A frame with more intersections than room is encoded again with room for
    /// all of them, so these calls never return an overflowed frame; their frames do not
    /// count in [`Self::check_intersections`].
    pub(super) fn render_and_read(
        &mut self,
        scene: &SceneBuffer,
        camera: &Camera,
        settings: &RenderSettings,
        mut then: impl FnMut(&mut Self, &Frame) -> Result<Option<(wgpu::Buffer, u64)>, RasterError>,
    ) -> Result<(u32, Vec<u8>), RasterError> {
        // Twice at most: the second frame has room for the first one's intersections.
        for _ in 0..2 {
            let frame = self.encode_frame_for(scene.clone(), camera, settings, false)?;
            let read = then(self, &frame)?;
            let (status, data) = self.read_status_and(read)?;
            let [_, _, count, drawn] = status;
            if drawn == 1 {
                return Ok((count, data));
            }
            // Fails when even the largest buffers cannot hold them.
            self.reserve_intersections(count)?;
        }
        Err(RasterError::Gpu(
            "a frame overflowed its intersection buffers after they were sized for it".into(),
        ))
    }

    /// Waits for the queue and reads the status buffer and, if given, `bytes` of a buffer,
    /// in one copy and one map.
    fn read_status_and(
        &mut self,
        read: Option<(wgpu::Buffer, u64)>,
    ) -> Result<([u32; STATUS_WORDS], Vec<u8>), RasterError> {
        let status_bytes = 4 * STATUS_WORDS as u64;
        let data_bytes = read.as_ref().map_or(0, |(_, bytes)| *bytes);
        let device = &self.ctx.device;
        let staging = self
            .buffers
            .readback
            .get(device, status_bytes + data_bytes)
            .clone();
        let mut encoder = device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(&self.buffers.status, 0, &staging, 0, status_bytes);
        if let Some((src, bytes)) = &read {
            if *bytes > 0 {
                encoder.copy_buffer_to_buffer(src, 0, &staging, status_bytes, *bytes);
            }
        }
        self.submit(encoder)?;
        let mut data = read_mapped(&self.ctx.device, &staging, status_bytes + data_bytes)?;
        let status: Vec<u32> = bytemuck::pod_collect_to_vec(&data[..status_bytes as usize]);
        data.drain(..status_bytes as usize);
        Ok((status.try_into().expect("status words"), data))
    }

    /// Renders `scene`: returns H·W·5 floats per pixel (r, g, b, alpha, Σ z·α·T) and the
    /// number of tile intersections.
    pub fn forward(
        &mut self,
        scene: &SceneInput<'_>,
        camera: &Camera,
        settings: &RenderSettings,
    ) -> Result<(Vec<f32>, u32), RasterError> {
        let scene = self.upload(scene)?;
        let bytes = 4 * PIXEL_CHANNELS as u64 * camera.width as u64 * camera.height as u64;
        let (count, data) = self.render_and_read(&scene, camera, settings, |_, frame| {
            Ok(Some((frame.pixels.clone(), bytes)))
        })?;
        Ok((bytemuck::pod_collect_to_vec(&data), count))
    }

    /// Draws the resident `scene` into `target` (a [`target_texture`] of the camera's size)
    /// without a trip of the image through the host; waits for it and returns the number
    /// of tile intersections.
    pub fn draw(
        &mut self,
        scene: &ResidentScene,
        camera: &Camera,
        settings: &RenderSettings,
        target: &wgpu::Texture,
    ) -> Result<u32, RasterError> {
        let size = target.size();
        if target.format() != TARGET_FORMAT
            || !target
                .usage()
                .contains(wgpu::TextureUsages::STORAGE_BINDING)
            || [size.width, size.height] != [camera.width, camera.height]
        {
            return Err(RasterError::InvalidInput(format!(
                "the target must be a {}x{} texture from target_texture(), got {}x{} {:?}",
                camera.width,
                camera.height,
                size.width,
                size.height,
                target.format()
            )));
        }
        let view = target.create_view(&Default::default());
        let (count, _) =
            self.render_and_read(&scene.as_buffer(), camera, settings, |renderer, frame| {
                renderer.encode_present(frame, &view)?;
                Ok(None)
            })?;
        Ok(count)
    }

    /// Converts `frame`'s colours into `target` (present.wgsl).
    fn encode_present(&self, frame: &Frame, target: &wgpu::TextureView) -> Result<(), RasterError> {
        let device = &self.ctx.device;
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("present"),
            layout: &self.present.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.buffers.params.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: frame.pixels.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(target),
                },
            ],
        });
        let mut encoder = device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.present);
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(frame.params.tiles_x, frame.params.tiles_y, 1);
        }
        self.submit(encoder)
    }

    /// Submits `encoder`, turning validation errors into [`RasterError::Gpu`].
    pub(super) fn submit(&self, encoder: wgpu::CommandEncoder) -> Result<(), RasterError> {
        submit_checked(&self.ctx.device, &self.ctx.queue, encoder)
    }

    /// The pixels of a [`target_texture`] as tightly packed RGBA8 rows.
    pub fn read_rgba8(&mut self, texture: &wgpu::Texture) -> Result<Vec<u8>, RasterError> {
        let (width, height) = (texture.width(), texture.height());
        let row = 4 * width;
        let padded_row = row.next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let bytes = padded_row as u64 * height as u64;
        let device = &self.ctx.device;
        let staging = self.buffers.readback.get(device, bytes).clone();
        let mut encoder = device.create_command_encoder(&Default::default());
        encoder.copy_texture_to_buffer(
            texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &staging,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(padded_row),
                    rows_per_image: Some(height),
                },
            },
            texture.size(),
        );
        self.ctx.queue.submit([encoder.finish()]);
        let padded = read_mapped(&self.ctx.device, &staging, bytes)?;
        Ok(padded
            .chunks_exact(padded_row as usize)
            .flat_map(|r| &r[..row as usize])
            .copied()
            .collect())
    }
}
