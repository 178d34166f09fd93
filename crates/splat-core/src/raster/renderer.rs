//! The [`Renderer`]: every stage's kernels and the reusable buffers on one device, and all
//! of its calls, in the order of a frame: construction, one frame encoded without waiting
//! (stages 1–7, each dispatched by its stage module), its backward, the room for
//! intersections, then the calls that wait for their results (`forward`, `backward`,
//! `footprints`, `draw`).

use super::backward::{BackwardBuffers, BackwardKernels, Gradients, GAUSSIAN_GRAD_FLOATS};
use super::blend::{BlendBuffers, BlendKernel};
use super::buffers::{ensure_intersections_fit, Buffers};
use super::context::GpuContext;
use super::frame::{Frame, IntersectionCheck, STATUS_WORDS};
use super::gpu::{pop_error, read_mapped, submit_checked};
use super::gpu_scene::{binding_limit, check_scene_fits, GpuScene, SceneBuffer};
use super::params::{
    validate_camera, validate_settings, Projected, RenderParams, RenderSettings, PIXEL_CHANNELS,
};
use super::present::{PresentKernel, TARGET_FORMAT};
use super::project::{ProjectBuffers, ProjectKernel};
use super::sort::{scan_plan, scratch_len, SortKernels};
use super::tiles::{GatherBuffers, IntersectionBuffers, TileKernels};
use super::RasterError;
use crate::camera::Camera;
use crate::gaussians::{SceneInput, BASE_FLOATS};

/// Compiled pipelines and reusable buffers on one device. Not thread-safe by itself:
/// callers serialise access (the Python binding keeps one behind a mutex).
pub struct Renderer {
    pub(super) ctx: GpuContext,
    project: ProjectKernel,
    sort: SortKernels,
    tiles: TileKernels,
    blend: BlendKernel,
    backward: BackwardKernels,
    present: PresentKernel,
    pub(super) buffers: Buffers,
    /// Tile intersections a frame has room for (0 until the first frame sizes it).
    intersection_capacity: u32,
    /// The status buffer's overflow count at the last `check_intersections`.
    overflows_seen: u32,
}

impl Renderer {
    pub fn new(ctx: GpuContext) -> Result<Self, RasterError> {
        let device = &ctx.device;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let renderer = Self {
            project: ProjectKernel::new(device),
            sort: SortKernels::new(device),
            tiles: TileKernels::new(device),
            blend: BlendKernel::new(device),
            backward: BackwardKernels::new(device, ctx.has_subgroups(), ctx.has_float_atomics()),
            present: PresentKernel::new(device),
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

    /// Submits `encoder`, turning validation errors into [`RasterError::Gpu`].
    fn submit(&self, encoder: wgpu::CommandEncoder) -> Result<(), RasterError> {
        submit_checked(&self.ctx.device, &self.ctx.queue, encoder)
    }

    /// Copies `bytes` of `src` from byte `offset` to the host (waits for the queue).
    fn read_back(
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
    /// renders; the viewer keeps a [`GpuScene`] instead).
    pub(super) fn upload(&mut self, scene: &SceneInput<'_>) -> Result<SceneBuffer, RasterError> {
        let (n, k) = scene.validate().map_err(RasterError::InvalidInput)?;
        let device = &self.ctx.device;
        let bytes = GpuScene::bytes_for(n as usize, k as usize);
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
            n_static: 0,
        })
    }

    // ---- One frame, encoded without waiting (docs/rasterizer.md, "Frames without a
    // wait"): projection, depth sort and the tile counts' scan; then, sized on the GPU
    // from the scan's total (tiles.wgsl, `plan_intersections`), the intersections, their
    // tile sort, the tiles' ranges and the blending. The per-intersection buffers have a
    // capacity; a frame with more intersections draws only the background and is
    // recorded as overflowed, for `check_intersections` to report and make room for.

    /// Encodes and submits one frame of `scene` (stages 1–7) without waiting for the GPU,
    /// except on a renderer whose intersection buffers no frame has sized yet: that first
    /// frame waits once for its intersection count (call
    /// [`Self::reserve_intersections`] first to avoid even that). The frame may overflow
    /// (see [`Self::frame_status`]); [`Self::check_intersections`] counts such frames and makes
    /// room. Chain [`Self::encode_backward`] on the returned frame before the next
    /// `encode_frame`.
    ///
    /// `static_render`: the render (H·W·5, [`Self::frame_pixels`]' layout) of the scene's
    /// static prefix alone (`scene.n_static` Gaussians) from this camera with these settings,
    /// where the caller keeps one: the tiles no trained Gaussian reaches are copied from it
    /// instead of blended (the same pixels: the same Gaussians in the same order).
    pub fn encode_frame(
        &mut self,
        scene: SceneBuffer,
        camera: &Camera,
        settings: &RenderSettings,
        static_render: Option<&wgpu::Buffer>,
    ) -> Result<Frame, RasterError> {
        self.encode_frame_for(scene, camera, settings, true, static_render)
    }

    /// [`Self::encode_frame`]; `record`: whether an overflow counts in
    /// [`Self::check_intersections`] (not for callers that check the frame themselves).
    fn encode_frame_for(
        &mut self,
        scene: SceneBuffer,
        camera: &Camera,
        settings: &RenderSettings,
        record: bool,
        static_render: Option<&wgpu::Buffer>,
    ) -> Result<Frame, RasterError> {
        validate_camera(camera)?;
        validate_settings(settings)?;
        let pixel_bytes = 4 * PIXEL_CHANNELS as u64 * camera.width as u64 * camera.height as u64;
        if let Some(buffer) = static_render {
            if scene.n_static == 0 || buffer.size() < pixel_bytes {
                return Err(RasterError::InvalidInput(format!(
                    "a static render needs a static prefix and {pixel_bytes} bytes for a \
                     {}x{} frame, got {} static Gaussians and {} bytes",
                    camera.width,
                    camera.height,
                    scene.n_static,
                    buffer.size()
                )));
            }
        }
        let device = self.ctx.device.clone();
        let mut params = RenderParams::new(camera, settings, &scene);
        params.record_overflow = record as u32;
        params.static_render = static_render.is_some() as u32;
        params.intersection_capacity = self.intersection_capacity;
        self.write_params(&params);
        let mut encoder = device.create_command_encoder(&Default::default());
        let depth_sorted = self.encode_geometry(&mut encoder, &scene);
        if self.intersection_capacity == 0 {
            // Nothing has sized the intersection buffers yet: wait for this frame's count.
            self.submit(encoder)?;
            let offsets = self.buffers.offsets.allocated();
            let total = self.read_back(&offsets, 4 * scene.len as u64, 4)?;
            self.reserve_intersections(u32::from_le_bytes(total[..4].try_into().expect("4")))?;
            params.intersection_capacity = self.intersection_capacity;
            self.write_params(&params);
            encoder = device.create_command_encoder(&Default::default());
        }
        let frame = self.encode_blend(&mut encoder, scene, params, depth_sorted, static_render);
        self.submit(encoder)?;
        Ok(frame)
    }

    fn write_params(&self, params: &RenderParams) {
        self.ctx
            .queue
            .write_buffer(&self.buffers.params, 0, bytemuck::bytes_of(params));
    }

    /// Stages 1–3: projection, depth sort, tile counts in depth order and their scan.
    /// Returns which ping-pong buffer holds the depth-sorted Gaussian ids.
    fn encode_geometry(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        scene: &SceneBuffer,
    ) -> usize {
        let n = scene.len;
        let device = self.ctx.device.clone();
        let queue = &self.ctx.queue;
        let b = &mut self.buffers;
        let n64 = n as u64;
        let (counts_len, sums_len) = scratch_len(n + 1);
        let projected_bytes = std::mem::size_of::<Projected>() as u64 * n64;
        let projected = b.projected.get(&device, projected_bytes).clone();
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
        b.depth_plan.write(queue, n);
        queue.write_buffer(&b.offsets_plan, 0, bytemuck::bytes_of(&scan_plan(n + 1)));
        if n > 0 {
            let project = ProjectBuffers {
                params: &b.params,
                gaussians: &scene.buffer,
                projected: &projected,
                tile_counts: &tile_counts,
                depth_keys: &dk[0],
                depth_vals: &dv[0],
            };
            let mut pass = encoder.begin_compute_pass(&Default::default());
            self.project.encode(&mut pass, &device, &project, n);
        }
        let depth_sorted = self.sort.encode_sort(
            &device,
            encoder,
            [&dk[0], &dk[1]],
            [&dv[0], &dv[1]],
            &sort_counts,
            &block_sums,
            &b.depth_plan,
            32,
        );
        let gather = GatherBuffers {
            params: &b.params,
            tile_counts: &tile_counts,
            depth_order: &dv[depth_sorted],
            offsets: &offsets,
        };
        self.tiles.encode_gather(
            &mut encoder.begin_compute_pass(&Default::default()),
            &device,
            &gather,
            n,
        );
        self.sort
            .encode_scan(&device, encoder, &offsets, &block_sums, &b.offsets_plan);
        depth_sorted
    }

    /// Stages 4–7, sized on the GPU: the plan from the scan's total, intersections, tile
    /// sort, ranges, blending.
    fn encode_blend(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        scene: SceneBuffer,
        params: RenderParams,
        depth_sorted: usize,
        static_render: Option<&wgpu::Buffer>,
    ) -> Frame {
        let device = self.ctx.device.clone();
        let b = &mut self.buffers;
        let n = params.num_gaussians;
        let num_tiles = params.tiles_x * params.tiles_y;
        let pixels = params.width as u64 * params.height as u64;
        let projected = b.projected.allocated();
        let tile_counts = b.tile_counts.allocated();
        let depth_order = b.depth_vals[depth_sorted].allocated();
        let offsets = b.offsets.allocated();
        let ranges = b.ranges.get(&device, 8 * num_tiles as u64).clone();
        let out_pixels = b
            .pixels
            .get(&device, 4 * PIXEL_CHANNELS as u64 * pixels)
            .clone();
        let pixel_state = b.pixel_state.get(&device, 8 * pixels).clone();
        let keys = [b.isect_keys[0].allocated(), b.isect_keys[1].allocated()];
        let gaussians = [
            b.isect_gaussians[0].allocated(),
            b.isect_gaussians[1].allocated(),
        ];
        let (counts_len, sums_len) = scratch_len(self.intersection_capacity);
        let sort_counts = b.sort_counts.get(&device, 4 * counts_len as u64).clone();
        let block_sums = b.block_sums.get(&device, 4 * sums_len as u64).clone();
        let intersections = IntersectionBuffers {
            params: &b.params,
            projected: &projected,
            tile_counts: &tile_counts,
            depth_order: &depth_order,
            offsets: &offsets,
            keys: &keys[0],
            gaussians: &gaussians[0],
            tile_plan: &b.tile_plan.sort,
            tile_scan_plan: &b.tile_plan.scan,
            status: &b.status,
        };
        self.tiles.encode_intersections(
            &mut encoder.begin_compute_pass(&Default::default()),
            &device,
            &intersections,
            n,
        );
        let tile_bits = u32::BITS - (num_tiles - 1).leading_zeros();
        let sorted = self.sort.encode_sort(
            &device,
            encoder,
            [&keys[0], &keys[1]],
            [&gaussians[0], &gaussians[1]],
            &sort_counts,
            &block_sums,
            &b.tile_plan,
            tile_bits,
        );
        encoder.clear_buffer(&ranges, 0, None);
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            self.tiles.encode_ranges(
                &mut pass,
                &device,
                &b.tile_plan.sort,
                &keys[sorted],
                &ranges,
            );
            let blend = BlendBuffers {
                params: &b.params,
                projected: &projected,
                sorted_gaussians: &gaussians[sorted],
                ranges: &ranges,
                pixels: &out_pixels,
                pixel_state: &pixel_state,
                static_pixels: static_render.unwrap_or(&b.no_static_render),
            };
            self.blend
                .encode(&mut pass, &device, &blend, params.tiles());
        }
        Frame {
            scene,
            params,
            projected,
            tile_counts,
            sorted_gaussians: gaussians[sorted].clone(),
            ranges,
            pixel_state,
            pixels: out_pixels,
        }
    }

    /// Encodes and submits the backward of `frame` (the last [`Self::encode_frame`]):
    /// `v_pixels` holds the loss's gradient w.r.t. the forward's H·W·5 output (the layout
    /// of [`Renderer::frame_pixels`]), and `grads` receives the gradients in [`Gradients`]' order as
    /// one SoA buffer of `BASE_FLOATS · n + 3 k n` floats (sections of n, whatever the
    /// scene's stride). Nothing is read back and nothing waits: a training loop chains this
    /// with its optimiser on the device. Gradients are summed with atomics, so their float
    /// rounding may differ between runs (docs/rasterizer.md, "Backward").
    pub fn encode_backward(
        &mut self,
        frame: &Frame,
        v_pixels: &wgpu::Buffer,
        grads: &wgpu::Buffer,
    ) -> Result<(), RasterError> {
        let device = self.ctx.device.clone();
        let n = frame.params.num_gaussians as u64;
        let k = frame.params.sh_coeffs as u64;
        let (width, height) = frame.size();
        let pixel_bytes = 4 * PIXEL_CHANNELS as u64 * width as u64 * height as u64;
        let grad_bytes = 4 * (BASE_FLOATS as u64 * n + 3 * k * n);
        if v_pixels.size() < pixel_bytes || grads.size() < grad_bytes {
            return Err(RasterError::InvalidInput(format!(
                "the backward of a {width}x{height} frame of {n} Gaussians needs a pixel \
                 gradient of {pixel_bytes} bytes and room for {grad_bytes} bytes of \
                 gradients, got {} and {}",
                v_pixels.size(),
                grads.size()
            )));
        }
        let sums = self
            .buffers
            .gaussian_grads
            .get(&device, 4 * GAUSSIAN_GRAD_FLOATS * n)
            .clone();
        let mut encoder = device.create_command_encoder(&Default::default());
        encoder.clear_buffer(&sums, 0, None);
        let buffers = BackwardBuffers {
            params: &self.buffers.params,
            gaussians: &frame.scene.buffer,
            projected: &frame.projected,
            tile_counts: &frame.tile_counts,
            sorted_gaussians: &frame.sorted_gaussians,
            ranges: &frame.ranges,
            pixel_state: &frame.pixel_state,
            v_pixels,
            sums: &sums,
            grads,
        };
        self.backward.encode(
            &mut encoder.begin_compute_pass(&Default::default()),
            &device,
            &buffers,
            n as u32,
            frame.params.tiles(),
        );
        self.submit(encoder)
    }

    // ---- Room for intersections.

    /// Makes room for frames of `m` tile intersections (the per-intersection buffers grow,
    /// with a quarter of headroom within the binding limit, and never shrink); fails when
    /// `m` of them exceed one storage binding. A training loop may call this up front
    /// (after densification, say) to keep frames from overflowing.
    pub fn reserve_intersections(&mut self, m: u32) -> Result<(), RasterError> {
        let device = self.ctx.device.clone();
        ensure_intersections_fit(&device, m, 4)?;
        if m <= self.intersection_capacity && self.intersection_capacity > 0 {
            return Ok(());
        }
        let b = &mut self.buffers;
        let room = b
            .isect_keys
            .iter_mut()
            .chain(b.isect_gaussians.iter_mut())
            .map(|grow| grow.get(&device, 4 * m.max(1) as u64).size() / 4)
            .min()
            .expect("four buffers");
        self.intersection_capacity = u32::try_from(room).unwrap_or(u32::MAX);
        Ok(())
    }

    /// The buffer the last [`Self::encode_frame`] left the forward's output in: per pixel,
    /// row-major, `PIXEL_CHANNELS` f32 (r, g, b with the background, alpha, Σ z·α·T).
    pub fn frame_pixels(&self) -> &wgpu::Buffer {
        self.buffers
            .pixels
            .buffer
            .as_ref()
            .expect("allocated by encode_frame")
    }

    /// The status of the last [`Self::encode_frame`]: `STATUS_WORDS` u32, of which word
    /// [`super::STATUS_DRAWN`] is 1 if the frame was drawn and 0 if it overflowed its
    /// intersection buffers (it then shows only the background and its backward gives zero
    /// gradients): a training loop's optimiser can skip that step on the device by reading
    /// it.
    pub fn frame_status(&self) -> &wgpu::Buffer {
        &self.buffers.status
    }

    /// Tile intersections a frame has room for (0 before the first frame).
    pub fn intersection_capacity(&self) -> u32 {
        self.intersection_capacity
    }

    /// Reads the counts the frames of `encode_frame` left (a 16-byte read-back: it waits
    /// for the queue, so call it where the loop waits anyway, e.g. with its loss every N
    /// steps) and makes room: when the largest frame so far used more than four fifths of
    /// the capacity, the buffers grow to a quarter more than it. Fails when that frame
    /// needs more than the device's binding limit.
    pub fn check_intersections(&mut self) -> Result<IntersectionCheck, RasterError> {
        let status = self.buffers.status.clone();
        let words: Vec<u32> =
            bytemuck::pod_collect_to_vec(&self.read_back(&status, 0, 4 * STATUS_WORDS as u64)?);
        let overflowed = words[0].wrapping_sub(self.overflows_seen);
        self.overflows_seen = words[0];
        let max_intersections = words[1];
        if max_intersections as u64 * 5 > self.intersection_capacity as u64 * 4 {
            let limit = binding_limit(&self.ctx.device) / 4;
            let wanted = (max_intersections as u64 * 5 / 4)
                .min(limit)
                .max(max_intersections as u64);
            self.reserve_intersections(u32::try_from(wanted).unwrap_or(u32::MAX))?;
        }
        Ok(IntersectionCheck {
            overflowed,
            max_intersections,
            capacity: self.intersection_capacity,
        })
    }

    // ---- The calls that wait for their results.

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
            let frame = self.encode_frame_for(scene.clone(), camera, settings, false, None)?;
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

    /// Gradients of a loss w.r.t. the scene, given its gradient w.r.t. the forward
    /// output (`v_pixels`: H·W·5 floats in the forward's layout). Re-runs the forward
    /// geometry, so it needs no state from an earlier call.
    pub fn backward(
        &mut self,
        scene: &SceneInput<'_>,
        camera: &Camera,
        settings: &RenderSettings,
        v_pixels: &[f32],
    ) -> Result<Gradients, RasterError> {
        let pixels = camera.width as usize * camera.height as usize;
        if v_pixels.len() != PIXEL_CHANNELS * pixels {
            return Err(RasterError::InvalidInput(format!(
                "pixel gradient has {} values, expected {}",
                v_pixels.len(),
                PIXEL_CHANNELS * pixels
            )));
        }
        let scene = self.upload(scene)?;
        let device = self.ctx.device.clone();
        let v_buf = self
            .buffers
            .v_pixels
            .get(&device, 4 * v_pixels.len() as u64)
            .clone();
        self.ctx
            .queue
            .write_buffer(&v_buf, 0, bytemuck::cast_slice(v_pixels));
        let n = scene.len as u64;
        let k = scene.sh_coeffs as u64;
        let grad_bytes = 4 * (BASE_FLOATS as u64 * n + 3 * k * n);
        let (_, flat) = self.render_and_read(&scene, camera, settings, |renderer, frame| {
            let grads = renderer.buffers.grads.get(&device, grad_bytes).clone();
            renderer.encode_backward(frame, &v_buf, &grads)?;
            Ok(Some((grads, grad_bytes)))
        })?;
        let flat: Vec<f32> = bytemuck::pod_collect_to_vec(&flat);
        let n = n as usize;
        let k = k as usize;
        let mut parts = [3 * n, 3 * n, 4 * n, n, 3 * k * n]
            .into_iter()
            .scan(0, |start, len| {
                let range = *start..*start + len;
                *start += len;
                Some(flat[range].to_vec())
            });
        let mut next = || parts.next().expect("five parts");
        Ok(Gradients {
            means: next(),
            log_scales: next(),
            quats: next(),
            opacity_logits: next(),
            sh: next(),
        })
    }

    /// Each Gaussian's footprint as the projection (stage 1 alone) computes it for the
    /// blending: pixel centre x, y and radius, the pixels beyond which it changes nothing;
    /// radius 0 where it is culled (not finite, behind the near plane, degenerate, below
    /// the least opacity, or no tile of the image within its radius).
    pub fn footprints(
        &mut self,
        scene: &SceneInput<'_>,
        camera: &Camera,
        settings: &RenderSettings,
    ) -> Result<Vec<[f32; 3]>, RasterError> {
        validate_camera(camera)?;
        validate_settings(settings)?;
        let scene = self.upload(scene)?;
        let n = scene.len as u64;
        if n == 0 {
            return Ok(Vec::new());
        }
        self.write_params(&RenderParams::new(camera, settings, &scene));
        let device = self.ctx.device.clone();
        let b = &mut self.buffers;
        let projected_bytes = std::mem::size_of::<Projected>() as u64 * n;
        let projected = b.projected.get(&device, projected_bytes).clone();
        let tile_counts = b.tile_counts.get(&device, 4 * n).clone();
        let depth_keys = b.depth_keys[0].get(&device, 4 * n).clone();
        let depth_vals = b.depth_vals[0].get(&device, 4 * n).clone();
        let buffers = ProjectBuffers {
            params: &b.params,
            gaussians: &scene.buffer,
            projected: &projected,
            tile_counts: &tile_counts,
            depth_keys: &depth_keys,
            depth_vals: &depth_vals,
        };
        let mut encoder = device.create_command_encoder(&Default::default());
        self.project.encode(
            &mut encoder.begin_compute_pass(&Default::default()),
            &device,
            &buffers,
            scene.len,
        );
        self.submit(encoder)?;
        let bytes = self.read_back(&projected, 0, projected_bytes)?;
        let projected: Vec<Projected> = bytemuck::pod_collect_to_vec(&bytes);
        Ok(projected.iter().map(Projected::footprint).collect())
    }

    /// Draws `scene`, kept on the GPU, into `target` (a [`super::target_texture`] of the camera's size)
    /// without a trip of the image through the host; waits for it and returns the number
    /// of tile intersections.
    pub fn draw(
        &mut self,
        scene: &GpuScene,
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
                let device = &renderer.ctx.device;
                let mut encoder = device.create_command_encoder(&Default::default());
                let params = &renderer.buffers.params;
                let tiles = frame.params.tiles();
                let present = &renderer.present;
                present.encode(&mut encoder, device, params, &frame.pixels, &view, tiles);
                renderer.submit(encoder)?;
                Ok(None)
            })?;
        Ok(count)
    }

    /// The pixels of a [`super::target_texture`] as tightly packed RGBA8 rows.
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
