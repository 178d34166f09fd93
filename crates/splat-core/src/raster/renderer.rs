//! The rasteriser: pipelines, reusable buffers, forward and backward.

use super::buffers::{check_intersections, Buffers};
use super::context::GpuContext;
use super::kernels::{
    bind_group, compile, div_ceil, run_linear, scratch_len, SortKernels, COMMON_WGSL, GAUSSIAN_WGSL,
};
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
const GRAD_SUM_ATOMIC_WGSL: &str = include_str!("../../../../shaders/grad_sum_atomic.wgsl");
const GRAD_SUM_SUBGROUP_WGSL: &str = include_str!("../../../../shaders/grad_sum_subgroup.wgsl");

pub const TILE_SIZE: u32 = 16;
/// Floats per output pixel: r, g, b, alpha, accumulated depth.
pub const PIXEL_CHANNELS: usize = 5;
/// Floats per projected Gaussian (`Projected` in common.wgsl).
const PROJECTED_FLOATS: u64 = 12;
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
/// clamped to 0..1) as 8-bit RGBA. Targets may also be viewed as its sRGB twin, so that
/// samplers decode them the way egui decodes its own images.
pub const TARGET_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// A texture [`Renderer::draw`] can write, egui can sample (through an
/// `Rgba8UnormSrgb` view) and [`Renderer::read_rgba8`] can copy out.
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
        view_formats: &[wgpu::TextureFormat::Rgba8UnormSrgb],
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
    width: u32,
    height: u32,
    pub(super) tiles_x: u32,
    pub(super) tiles_y: u32,
    pub(super) num_gaussians: u32,
    pub(super) sh_coeffs: u32,
    antialiased: u32,
    num_intersections: u32,
    gaussian_stride: u32,
    log_scale_offset: f32,
    pad: [u32; 2],
}

fn render_params(camera: &Camera, settings: &RenderSettings, scene: &SceneBuffer) -> RenderParams {
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
        num_intersections: 0,
        gaussian_stride: scene.stride,
        log_scale_offset: settings.splat_scale.ln(),
        pad: [0; 2],
    }
}

fn validate_settings(settings: &RenderSettings) -> Result<(), RasterError> {
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

fn validate_camera(camera: &Camera) -> Result<(), RasterError> {
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

/// The geometry of one frame, left in the buffers by [`Renderer::encode_frame`].
pub(crate) struct Frame {
    pub(super) scene: SceneBuffer,
    pub(super) params: RenderParams,
    pub(super) num_intersections: u32,
    /// Which ping-pong buffer holds the depth-sorted Gaussian indices.
    pub(super) depth_sorted: usize,
    /// Which ping-pong buffer holds the tile-sorted slots.
    pub(super) sorted: usize,
}

/// Compiled pipelines and reusable buffers on one device. Not thread-safe by itself:
/// callers serialise access (the Python binding keeps one behind a mutex).
pub struct Renderer {
    pub(super) ctx: GpuContext,
    sort: SortKernels,
    project: wgpu::ComputePipeline,
    gather_counts: wgpu::ComputePipeline,
    emit: wgpu::ComputePipeline,
    ranges: wgpu::ComputePipeline,
    rasterize: wgpu::ComputePipeline,
    pub(super) rasterize_backward: wgpu::ComputePipeline,
    pub(super) project_backward: wgpu::ComputePipeline,
    present: wgpu::ComputePipeline,
    pub(super) buffers: Buffers,
}

pub(crate) fn pop_error(scope: wgpu::ErrorScopeGuard) -> Result<(), RasterError> {
    match pollster::block_on(scope.pop()) {
        Some(e) => Err(RasterError::Gpu(e.to_string())),
        None => Ok(()),
    }
}

impl Renderer {
    pub fn new(ctx: GpuContext) -> Result<Self, RasterError> {
        let device = &ctx.device;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let one =
            |label: &str, sources: &[&str]| compile(device, label, sources, &["main"]).remove(0);
        let mut tiles = compile(
            device,
            "tiles",
            &[COMMON_WGSL, TILES_WGSL],
            &["gather_counts", "emit_intersections"],
        );
        let emit = tiles.remove(1);
        let gather_counts = tiles.remove(0);
        // Subgroup sums cut the backward's contention where the device has them.
        let grad_sum = if device.features().contains(wgpu::Features::SUBGROUP) {
            GRAD_SUM_SUBGROUP_WGSL
        } else {
            GRAD_SUM_ATOMIC_WGSL
        };
        let renderer = Self {
            sort: SortKernels::new(device),
            project: one("project", &[COMMON_WGSL, GAUSSIAN_WGSL, PROJECT_WGSL]),
            gather_counts,
            emit,
            ranges: one("ranges", &[COMMON_WGSL, RANGES_WGSL]),
            rasterize: one("rasterize", &[COMMON_WGSL, RASTERIZE_WGSL]),
            rasterize_backward: one(
                "rasterize_backward",
                &[COMMON_WGSL, grad_sum, RASTERIZE_BACKWARD_WGSL],
            ),
            project_backward: one(
                "project_backward",
                &[COMMON_WGSL, GAUSSIAN_WGSL, PROJECT_BACKWARD_WGSL],
            ),
            present: one("present", &[COMMON_WGSL, PRESENT_WGSL]),
            buffers: Buffers::new(device),
            ctx,
        };
        pop_error(scope)?;
        Ok(renderer)
    }

    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// Copies `bytes` from `src` to the host.
    pub(super) fn read_back(
        &mut self,
        src: &wgpu::Buffer,
        bytes: u64,
    ) -> Result<Vec<u8>, RasterError> {
        let device = &self.ctx.device;
        let staging = self.buffers.readback.get(device, bytes).clone();
        let mut encoder = device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(src, 0, &staging, 0, bytes);
        self.ctx.queue.submit([encoder.finish()]);
        self.read_mapped(&staging, bytes)
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

    /// Runs every stage up to and including the forward blending; the results stay in
    /// the buffers for the read-back, the backward pass or [`Self::draw`]'s conversion.
    pub(crate) fn encode_frame(
        &mut self,
        scene: SceneBuffer,
        camera: &Camera,
        settings: &RenderSettings,
    ) -> Result<Frame, RasterError> {
        validate_camera(camera)?;
        validate_settings(settings)?;
        let mut params = render_params(camera, settings, &scene);
        self.ctx
            .queue
            .write_buffer(&self.buffers.params, 0, bytemuck::bytes_of(&params));
        let depth_sorted = self.encode_geometry(&scene)?;
        let m = self.read_intersection_count(scene.len)?;
        // Every per-intersection array must fit one storage binding (128 MiB on lavapipe).
        check_intersections(&self.ctx.device, m, 4)?;
        params.num_intersections = m;
        self.ctx
            .queue
            .write_buffer(&self.buffers.params, 0, bytemuck::bytes_of(&params));
        let sorted = self.encode_blend(&params, depth_sorted)?;
        Ok(Frame {
            scene,
            params,
            num_intersections: m,
            depth_sorted,
            sorted,
        })
    }

    /// Stages 1–3: projection, depth sort, tile-count scan (one submit). Returns which
    /// ping-pong buffer holds the depth-sorted indices.
    fn encode_geometry(&mut self, scene: &SceneBuffer) -> Result<usize, RasterError> {
        let n = scene.len;
        let device = self.ctx.device.clone();
        let b = &mut self.buffers;
        let n64 = n as u64;
        let (counts_len, sums_len) = scratch_len(n + 1);
        let projected = b.projected.get(&device, 4 * PROJECTED_FLOATS * n64).clone();
        let tile_counts = b.tile_counts.get(&device, 4 * n64).clone();
        let dk = [
            b.depth_keys[0].get(&device, 4 * n64).clone(),
            b.depth_keys[1].get(&device, 4 * n64).clone(),
        ];
        let dv = [
            b.depth_vals[0].get(&device, 4 * n64).clone(),
            b.depth_vals[1].get(&device, 4 * n64).clone(),
        ];
        let offsets = b.offsets.get(&device, 4 * (n64 + 1)).clone();
        let sort_counts = b.sort_counts.get(&device, 4 * counts_len as u64).clone();
        let block_sums = b.block_sums.get(&device, 4 * sums_len as u64).clone();
        let mut encoder = device.create_command_encoder(&Default::default());
        if n > 0 {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            run_linear(
                &mut pass,
                &device,
                &self.project,
                &[
                    (0, &b.params),
                    (1, &scene.buffer),
                    (2, &projected),
                    (3, &tile_counts),
                    (4, &dk[0]),
                    (5, &dv[0]),
                ],
                div_ceil(n, 256),
            );
        }
        let depth_sorted = self.sort.encode_sort(
            &device,
            &mut encoder,
            [&dk[0], &dk[1]],
            [&dv[0], &dv[1]],
            &sort_counts,
            &block_sums,
            n,
            32,
        );
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            run_linear(
                &mut pass,
                &device,
                &self.gather_counts,
                &[
                    (0, &b.params),
                    (2, &tile_counts),
                    (3, &dv[depth_sorted]),
                    (4, &offsets),
                ],
                div_ceil(n + 1, 256),
            );
        }
        self.sort
            .encode_scan(&device, &mut encoder, &offsets, &block_sums, n + 1);
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        self.ctx.queue.submit([encoder.finish()]);
        pop_error(scope)?;
        Ok(depth_sorted)
    }

    /// The number of tile intersections M: the scan's last entry, read back because it
    /// sizes the tile sort.
    fn read_intersection_count(&mut self, n: u32) -> Result<u32, RasterError> {
        let device = &self.ctx.device;
        let offsets = self.buffers.offsets.get(device, 4 * (n as u64 + 1)).clone();
        let staging = self.buffers.readback.get(device, 4).clone();
        let mut encoder = device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(&offsets, 4 * n as u64, &staging, 0, 4);
        self.ctx.queue.submit([encoder.finish()]);
        let bytes = self.read_mapped(&staging, 4)?;
        Ok(u32::from_le_bytes(bytes[..4].try_into().expect("4 bytes")))
    }

    /// Stages 4–7: intersections, tile sort, ranges, blending (one submit). Returns which
    /// ping-pong buffer holds the tile-sorted slots.
    fn encode_blend(
        &mut self,
        params: &RenderParams,
        depth_sorted: usize,
    ) -> Result<usize, RasterError> {
        let device = self.ctx.device.clone();
        let b = &mut self.buffers;
        let m = params.num_intersections;
        let n64 = params.num_gaussians as u64;
        let m64 = m as u64;
        let num_tiles = params.tiles_x * params.tiles_y;
        let pixels = params.width as u64 * params.height as u64;
        let projected = b.projected.get(&device, 4 * PROJECTED_FLOATS * n64).clone();
        let tile_counts = b.tile_counts.get(&device, 4 * n64).clone();
        let depth_vals = b.depth_vals[depth_sorted].get(&device, 4 * n64).clone();
        let offsets = b.offsets.get(&device, 4 * (n64 + 1)).clone();
        let ranges = b.ranges.get(&device, 8 * num_tiles as u64).clone();
        let out_pixels = b
            .pixels
            .get(&device, 4 * PIXEL_CHANNELS as u64 * pixels)
            .clone();
        let pixel_state = b.pixel_state.get(&device, 8 * pixels).clone();
        let ik = [
            b.isect_keys[0].get(&device, 4 * m64).clone(),
            b.isect_keys[1].get(&device, 4 * m64).clone(),
        ];
        let is = [
            b.isect_slots[0].get(&device, 4 * m64).clone(),
            b.isect_slots[1].get(&device, 4 * m64).clone(),
        ];
        let ig = b.isect_gaussian.get(&device, 4 * m64).clone();
        let (counts_len, sums_len) = scratch_len(m);
        let sort_counts = b.sort_counts.get(&device, 4 * counts_len as u64).clone();
        let block_sums = b.block_sums.get(&device, 4 * sums_len as u64).clone();
        let mut encoder = device.create_command_encoder(&Default::default());
        if m > 0 {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            run_linear(
                &mut pass,
                &device,
                &self.emit,
                &[
                    (0, &b.params),
                    (1, &projected),
                    (2, &tile_counts),
                    (3, &depth_vals),
                    (4, &offsets),
                    (5, &ik[0]),
                    (6, &is[0]),
                    (7, &ig),
                ],
                div_ceil(params.num_gaussians, 256),
            );
        }
        let tile_bits = u32::BITS - (num_tiles - 1).leading_zeros();
        let sorted = self.sort.encode_sort(
            &device,
            &mut encoder,
            [&ik[0], &ik[1]],
            [&is[0], &is[1]],
            &sort_counts,
            &block_sums,
            m,
            tile_bits,
        );
        encoder.clear_buffer(&ranges, 0, None);
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            if m > 0 {
                run_linear(
                    &mut pass,
                    &device,
                    &self.ranges,
                    &[(0, &b.params), (1, &ik[sorted]), (2, &ranges)],
                    div_ceil(m, 256),
                );
            }
            pass.set_pipeline(&self.rasterize);
            let group = bind_group(
                &device,
                &self.rasterize,
                &[
                    (0, &b.params),
                    (1, &projected),
                    (2, &is[sorted]),
                    (3, &ig),
                    (4, &ranges),
                    (5, &out_pixels),
                    (6, &pixel_state),
                ],
            );
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(params.tiles_x, params.tiles_y, 1);
        }
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        self.ctx.queue.submit([encoder.finish()]);
        pop_error(scope)?;
        Ok(sorted)
    }

    /// The buffer [`Self::encode_frame`] leaves the forward's H·W·5 pixels in (for a
    /// training loop's losses on the device).
    pub(crate) fn frame_pixels(&self) -> &wgpu::Buffer {
        self.buffers
            .pixels
            .buffer
            .as_ref()
            .expect("allocated by encode_frame")
    }

    fn read_mapped(&self, staging: &wgpu::Buffer, bytes: u64) -> Result<Vec<u8>, RasterError> {
        let slice = staging.slice(..bytes);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.ctx
            .device
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

    /// Renders `scene`: returns H·W·5 floats per pixel (r, g, b, alpha, Σ z·α·T) and the
    /// number of tile intersections.
    pub fn forward(
        &mut self,
        scene: &SceneInput<'_>,
        camera: &Camera,
        settings: &RenderSettings,
    ) -> Result<(Vec<f32>, u32), RasterError> {
        let scene = self.upload(scene)?;
        let frame = self.encode_frame(scene, camera, settings)?;
        let bytes = 4 * PIXEL_CHANNELS as u64 * camera.width as u64 * camera.height as u64;
        let src = self
            .buffers
            .pixels
            .buffer
            .clone()
            .expect("allocated by encode_frame");
        let data = self.read_back(&src, bytes)?;
        Ok((bytemuck::pod_collect_to_vec(&data), frame.num_intersections))
    }

    /// Draws the resident `scene` into `target` (a [`target_texture`] of the camera's size)
    /// without a trip through the host; returns the number of tile intersections.
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
        let frame = self.encode_frame(scene.as_buffer(), camera, settings)?;
        let device = &self.ctx.device;
        let pixels = self
            .buffers
            .pixels
            .buffer
            .clone()
            .expect("allocated by encode_frame");
        let view = target.create_view(&Default::default());
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
                    resource: pixels.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&view),
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
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        self.ctx.queue.submit([encoder.finish()]);
        pop_error(scope)?;
        Ok(frame.num_intersections)
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
        let padded = self.read_mapped(&staging, bytes)?;
        Ok(padded
            .chunks_exact(padded_row as usize)
            .flat_map(|r| &r[..row as usize])
            .copied()
            .collect())
    }
}
