//! One frame, encoded without waiting for the GPU: projection, depth sort and the tile
//! counts' scan; then, sized on the GPU from the scan's total (tiles.wgsl,
//! `plan_intersections`), the intersections, their tile sort, the tiles' ranges and the
//! blending. The per-intersection buffers have a capacity; a frame with more
//! intersections draws only the background and is recorded as overflowed, for
//! [`Renderer::check_intersections`] to report and make room for (docs/rasterizer.md,
//! "Frames without a wait").

use super::buffers::{ensure_intersections_fit, GrowBuffer, STATUS_WORDS};
use super::kernels::{bind_group, div_ceil, run_linear, scan_plan, scratch_len};
use super::renderer::{
    render_params, validate_camera, validate_settings, Frame, RenderParams, RenderSettings,
    Renderer, PIXEL_CHANNELS, PROJECTED_FLOATS,
};
use super::resident::{binding_limit, SceneBuffer};
use super::RasterError;
use crate::camera::Camera;

/// Byte offset of the ranges' workgroups in the tile plan (tiles.wgsl, `tile_plan`).
const RANGES_GROUPS_OFFSET: u64 = 20;
/// Index of the status word that says whether the last frame was drawn (1) or overflowed
/// its intersection buffers and drew only the background (0).
pub const STATUS_DRAWN: usize = 3;

/// What [`Renderer::check_intersections`] found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IntersectionCheck {
    /// Frames of `encode_frame` since the last check that had more tile intersections than
    /// room: each drew only the background and gave zero gradients.
    pub overflowed: u32,
    /// The most tile intersections of any frame of `encode_frame` so far.
    pub max_intersections: u32,
    /// Room per frame from now on: at least a quarter more than `max_intersections`
    /// (unless that is past the device's binding limit).
    pub capacity: u32,
}

fn buffer(grow: &GrowBuffer) -> wgpu::Buffer {
    grow.buffer.clone().expect("allocated before the frame")
}

impl Renderer {
    /// Encodes and submits one frame of `scene` (stages 1–7) without waiting for the GPU,
    /// except on a renderer whose intersection buffers no frame has sized yet: that first
    /// frame waits once for its intersection count (call
    /// [`Self::reserve_intersections`] first to avoid even that). The frame may overflow
    /// (see [`Self::frame_status`]); [`Self::check_intersections`] counts such frames and makes
    /// room. Chain [`Self::encode_backward`] on the returned frame before the next
    /// `encode_frame`.
    pub fn encode_frame(
        &mut self,
        scene: SceneBuffer,
        camera: &Camera,
        settings: &RenderSettings,
    ) -> Result<Frame, RasterError> {
        self.encode_frame_for(scene, camera, settings, true)
    }

    /// [`Self::encode_frame`]; `record`: whether an overflow counts in
    /// [`Self::check_intersections`] (not for callers that check the frame themselves).
    pub(super) fn encode_frame_for(
        &mut self,
        scene: SceneBuffer,
        camera: &Camera,
        settings: &RenderSettings,
        record: bool,
    ) -> Result<Frame, RasterError> {
        validate_camera(camera)?;
        validate_settings(settings)?;
        let device = self.ctx.device.clone();
        let mut params = render_params(camera, settings, &scene);
        params.record_overflow = record as u32;
        params.intersection_capacity = self.intersection_capacity;
        self.write_params(&params);
        let mut encoder = device.create_command_encoder(&Default::default());
        let depth_sorted = self.encode_geometry(&mut encoder, &scene);
        if self.intersection_capacity == 0 {
            // Nothing has sized the intersection buffers yet: wait for this frame's count.
            self.submit(encoder)?;
            let offsets = buffer(&self.buffers.offsets);
            let total = self.read_back(&offsets, 4 * scene.len as u64, 4)?;
            self.reserve_intersections(u32::from_le_bytes(total[..4].try_into().expect("4")))?;
            params.intersection_capacity = self.intersection_capacity;
            self.write_params(&params);
            encoder = device.create_command_encoder(&Default::default());
        }
        let frame = self.encode_blend(&mut encoder, scene, params, depth_sorted);
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
        b.depth_plan.write(queue, n);
        queue.write_buffer(&b.offsets_plan, 0, bytemuck::cast_slice(&scan_plan(n + 1)));
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
            encoder,
            [&dk[0], &dk[1]],
            [&dv[0], &dv[1]],
            &sort_counts,
            &block_sums,
            &b.depth_plan,
            32,
        );
        run_linear(
            &mut encoder.begin_compute_pass(&Default::default()),
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
    ) -> Frame {
        let device = self.ctx.device.clone();
        let b = &mut self.buffers;
        let n = params.num_gaussians;
        let num_tiles = params.tiles_x * params.tiles_y;
        let pixels = params.width as u64 * params.height as u64;
        let projected = buffer(&b.projected);
        let tile_counts = buffer(&b.tile_counts);
        let depth_order = buffer(&b.depth_vals[depth_sorted]);
        let offsets = buffer(&b.offsets);
        let ranges = b.ranges.get(&device, 8 * num_tiles as u64).clone();
        let out_pixels = b
            .pixels
            .get(&device, 4 * PIXEL_CHANNELS as u64 * pixels)
            .clone();
        let pixel_state = b.pixel_state.get(&device, 8 * pixels).clone();
        let keys = [buffer(&b.isect_keys[0]), buffer(&b.isect_keys[1])];
        let gaussians = [buffer(&b.isect_gaussians[0]), buffer(&b.isect_gaussians[1])];
        let (counts_len, sums_len) = scratch_len(self.intersection_capacity);
        let sort_counts = b.sort_counts.get(&device, 4 * counts_len as u64).clone();
        let block_sums = b.block_sums.get(&device, 4 * sums_len as u64).clone();
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            run_linear(
                &mut pass,
                &device,
                &self.plan_intersections,
                &[
                    (0, &b.params),
                    (4, &offsets),
                    (7, &b.tile_plan.sort),
                    (8, &b.tile_plan.scan),
                    (9, &b.status),
                ],
                1,
            );
            if n > 0 {
                run_linear(
                    &mut pass,
                    &device,
                    &self.emit,
                    &[
                        (0, &b.params),
                        (1, &projected),
                        (2, &tile_counts),
                        (3, &depth_order),
                        (4, &offsets),
                        (5, &keys[0]),
                        (6, &gaussians[0]),
                        (7, &b.tile_plan.sort),
                    ],
                    div_ceil(n, 256),
                );
            }
        }
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
            pass.set_pipeline(&self.ranges);
            let group = bind_group(
                &device,
                &self.ranges,
                &[(0, &b.tile_plan.sort), (1, &keys[sorted]), (2, &ranges)],
            );
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups_indirect(&b.tile_plan.sort, RANGES_GROUPS_OFFSET);
            pass.set_pipeline(&self.rasterize);
            let group = bind_group(
                &device,
                &self.rasterize,
                &[
                    (0, &b.params),
                    (1, &projected),
                    (2, &gaussians[sorted]),
                    (3, &ranges),
                    (4, &out_pixels),
                    (5, &pixel_state),
                ],
            );
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(params.tiles_x, params.tiles_y, 1);
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
    /// [`STATUS_DRAWN`] is 1 if the frame was drawn and 0 if it overflowed its intersection
    /// buffers (it then shows only the background and its backward gives zero gradients): a
    /// training loop's optimiser can skip that step on the device by reading it.
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
}
