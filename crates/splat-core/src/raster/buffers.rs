//! The renderer's reusable GPU buffers: each grows to the largest size a call has asked
//! of it and is kept for the next call, so a training loop allocates nothing per step.

use super::frame::STATUS_WORDS;
use super::gpu_scene::binding_limit;
use super::params::{RenderParams, PIXEL_CHANNELS};
use super::sort::{plan_buffer, SortPlan};
use super::RasterError;

/// Errors when `m` intersections of `bytes_each` exceed one storage binding.
pub(super) fn ensure_intersections_fit(
    device: &wgpu::Device,
    m: u32,
    bytes_each: u64,
) -> Result<(), RasterError> {
    let binding_limit = binding_limit(device);
    if bytes_each * m as u64 > binding_limit {
        return Err(RasterError::Gpu(format!(
            "{m} tile intersections need more than this device's storage binding limit \
             ({binding_limit} bytes); render at a lower resolution or with fewer Gaussians"
        )));
    }
    Ok(())
}

/// A storage buffer that grows (never shrinks) to the largest size asked of it.
pub(super) struct GrowBuffer {
    label: &'static str,
    usage: wgpu::BufferUsages,
    pub(super) buffer: Option<wgpu::Buffer>,
}

impl GrowBuffer {
    pub(super) fn new(label: &'static str, extra: wgpu::BufferUsages) -> Self {
        Self {
            label,
            usage: wgpu::BufferUsages::STORAGE | extra,
            buffer: None,
        }
    }

    pub(super) fn get(&mut self, device: &wgpu::Device, bytes: u64) -> &wgpu::Buffer {
        // Runtime-sized arrays need at least one element bound, whatever n is; sizes are
        // multiples of 4 (copies), not more, or one just under the limit would pass it.
        let align = wgpu::COPY_BUFFER_ALIGNMENT;
        let bytes = bytes.max(256).next_multiple_of(align);
        let big_enough = self.buffer.as_ref().is_some_and(|b| b.size() >= bytes);
        if !big_enough {
            // Headroom so that slowly growing scenes do not reallocate every call, but none
            // past what one binding may hold: a buffer just under the limit must still bind.
            let limit = (binding_limit(device) / align * align).max(bytes);
            let size = (bytes + bytes / 4).next_multiple_of(align).min(limit);
            self.buffer = Some(device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(self.label),
                size,
                usage: self.usage,
                mapped_at_creation: false,
            }));
        }
        self.buffer.as_ref().expect("allocated above")
    }

    /// The buffer as the last [`Self::get`] left it: what a later stage of the frame reads
    /// of an earlier one's.
    pub(super) fn allocated(&self) -> wgpu::Buffer {
        self.buffer.clone().expect("allocated before the frame")
    }
}

pub(super) struct Buffers {
    pub(super) params: wgpu::Buffer,
    pub(super) gaussians: GrowBuffer,
    pub(super) projected: GrowBuffer,
    pub(super) tile_counts: GrowBuffer,
    pub(super) depth_keys: [GrowBuffer; 2],
    pub(super) depth_vals: [GrowBuffer; 2],
    pub(super) offsets: GrowBuffer,
    pub(super) sort_counts: GrowBuffer,
    pub(super) block_sums: GrowBuffer,
    /// Sizes of the depth sort and the offsets' scan (from the host), and of the tile sort
    /// and its ranges (from the GPU).
    pub(super) depth_plan: SortPlan,
    pub(super) offsets_plan: wgpu::Buffer,
    pub(super) tile_plan: SortPlan,
    pub(super) status: wgpu::Buffer,
    /// The per-intersection arrays (tile id, Gaussian id), sized by
    /// `Renderer::reserve_intersections`.
    pub(super) isect_keys: [GrowBuffer; 2],
    pub(super) isect_gaussians: [GrowBuffer; 2],
    pub(super) ranges: GrowBuffer,
    pub(super) pixels: GrowBuffer,
    pub(super) pixel_state: GrowBuffer,
    /// Bound as the static render of a frame that has none (the blending does not read it).
    pub(super) no_static_render: wgpu::Buffer,
    pub(super) v_pixels: GrowBuffer,
    /// Each Gaussian's ten 2D gradient sums (rasterize_backward.wgsl).
    pub(super) gaussian_grads: GrowBuffer,
    pub(super) grads: GrowBuffer,
    pub(super) readback: GrowBuffer,
}

impl Buffers {
    pub(super) fn new(device: &wgpu::Device) -> Self {
        let copy = wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST;
        let pair = |label| [GrowBuffer::new(label, copy), GrowBuffer::new(label, copy)];
        Self {
            params: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("render params"),
                size: std::mem::size_of::<RenderParams>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            gaussians: GrowBuffer::new("gaussians", copy),
            projected: GrowBuffer::new("projected", copy),
            tile_counts: GrowBuffer::new("tile counts", copy),
            depth_keys: pair("depth keys"),
            depth_vals: pair("depth values"),
            offsets: GrowBuffer::new("offsets", copy),
            sort_counts: GrowBuffer::new("sort counts", copy),
            block_sums: GrowBuffer::new("block sums", copy),
            depth_plan: SortPlan::new(device, "depth sort plan"),
            offsets_plan: plan_buffer(device, "offsets scan plan"),
            tile_plan: SortPlan::new(device, "tile sort plan"),
            status: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("render status"),
                size: 4 * STATUS_WORDS as u64,
                usage: wgpu::BufferUsages::STORAGE | copy,
                mapped_at_creation: false,
            }),
            no_static_render: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("no static render"),
                size: 4 * PIXEL_CHANNELS as u64,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            }),
            isect_keys: pair("intersection keys"),
            isect_gaussians: pair("intersection gaussians"),
            ranges: GrowBuffer::new("tile ranges", copy),
            pixels: GrowBuffer::new("pixels", copy),
            pixel_state: GrowBuffer::new("pixel state", copy),
            v_pixels: GrowBuffer::new("pixel gradients", copy),
            gaussian_grads: GrowBuffer::new("gaussian 2d gradients", copy),
            grads: GrowBuffer::new("gradients", copy),
            readback: GrowBuffer {
                label: "readback",
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                buffer: None,
            },
        }
    }
}
