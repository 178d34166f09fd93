//! Gaussians kept on the GPU between frames, for the viewer: the static set is written
//! once and each timestamp's dynamic set overwrites only the part after it.

use super::RasterError;
use crate::gaussians::{SceneInput, BASE_FLOATS};

/// A Gaussian buffer in the shaders' SoA layout (`SceneInput::packed`'s, with sections of
/// `stride` entries: means, log-scales, quaternions, opacity logits, SH) of which the first
/// `len` are drawn.
#[derive(Clone, Debug)]
pub struct SceneBuffer {
    pub buffer: wgpu::Buffer,
    pub len: u32,
    pub stride: u32,
    pub sh_coeffs: u32,
}

/// The most bytes one storage buffer may hold and bind on `device`.
pub fn binding_limit(device: &wgpu::Device) -> u64 {
    let limits = device.limits();
    limits
        .max_storage_buffer_binding_size
        .min(limits.max_buffer_size)
}

/// Errors when `n` Gaussians with `k` SH coefficients exceed one storage binding.
pub(crate) fn check_scene_fits(
    device: &wgpu::Device,
    n: usize,
    k: usize,
) -> Result<(), RasterError> {
    let bytes = ResidentScene::bytes_for(n, k);
    let allowed = binding_limit(device);
    if bytes > allowed {
        return Err(RasterError::TooLarge {
            gaussians: n,
            bytes,
            allowed,
        });
    }
    Ok(())
}

/// Room for `capacity` Gaussians of one SH degree on the GPU, of which the first
/// [`Self::len`] are drawn by [`super::Renderer::draw`].
pub struct ResidentScene {
    buffer: wgpu::Buffer,
    capacity: u32,
    sh_coeffs: u32,
    len: u32,
}

impl ResidentScene {
    /// Bytes of the buffer for `n` Gaussians with `k` SH coefficients per channel.
    pub fn bytes_for(n: usize, k: usize) -> u64 {
        4 * n as u64 * (BASE_FLOATS + 3 * k) as u64
    }

    /// An empty scene with room for `capacity` Gaussians with `sh_coeffs` coefficients per
    /// channel (1, 4, 9 or 16); fails when that is over the device's buffer limits.
    pub fn new(
        device: &wgpu::Device,
        capacity: usize,
        sh_coeffs: usize,
    ) -> Result<Self, RasterError> {
        if ![1, 4, 9, 16].contains(&sh_coeffs) {
            return Err(RasterError::InvalidInput(format!(
                "SH coefficients per channel must be 1, 4, 9 or 16, got {sh_coeffs}"
            )));
        }
        let capacity32 = u32::try_from(capacity)
            .ok()
            .filter(|&c| c < u32::MAX / 64)
            .ok_or_else(|| RasterError::InvalidInput(format!("too many Gaussians: {capacity}")))?;
        check_scene_fits(device, capacity, sh_coeffs)?;
        // Runtime-sized arrays need at least one element bound, whatever the capacity
        // (bytes_for is a multiple of 4, as copies need, so a scene under the limit fits).
        let bytes = Self::bytes_for(capacity, sh_coeffs).max(256);
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("resident gaussians"),
            size: bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(Self {
            buffer,
            capacity: capacity32,
            sh_coeffs: sh_coeffs as u32,
            len: 0,
        })
    }

    pub fn capacity(&self) -> usize {
        self.capacity as usize
    }

    /// Gaussians drawn: those written by the last [`Self::write`] and before it.
    pub fn len(&self) -> usize {
        self.len as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn sh_coeffs(&self) -> usize {
        self.sh_coeffs as usize
    }

    /// Writes `part` as Gaussians `first..first + part.len()`; the scene then draws exactly
    /// those and the ones before them. Writing the static set at 0 and then each
    /// timestamp's dynamic set after it uploads only what changes.
    pub fn write(
        &mut self,
        queue: &wgpu::Queue,
        first: usize,
        part: &SceneInput<'_>,
    ) -> Result<(), RasterError> {
        let (n, k) = part.validate().map_err(RasterError::InvalidInput)?;
        let end = first + n as usize;
        if end > self.capacity as usize || first > self.len as usize {
            return Err(RasterError::InvalidInput(format!(
                "cannot write Gaussians {first}..{end}: the scene holds {} of room for {}",
                self.len, self.capacity
            )));
        }
        if n > 0 && k != self.sh_coeffs {
            return Err(RasterError::InvalidInput(format!(
                "{k} SH coefficients per channel written to a scene of {}",
                self.sh_coeffs
            )));
        }
        let widths = [3, 3, 4, 1, 3 * self.sh_coeffs as usize];
        let mut section_start = 0;
        for (data, width) in part.sections().into_iter().zip(widths) {
            if !data.is_empty() {
                let offset = section_start + first * width;
                queue.write_buffer(&self.buffer, 4 * offset as u64, bytemuck::cast_slice(data));
            }
            section_start += width * self.capacity as usize;
        }
        self.len = end as u32;
        Ok(())
    }

    pub fn as_buffer(&self) -> SceneBuffer {
        SceneBuffer {
            buffer: self.buffer.clone(),
            len: self.len,
            stride: self.capacity,
            sh_coeffs: self.sh_coeffs,
        }
    }
}
