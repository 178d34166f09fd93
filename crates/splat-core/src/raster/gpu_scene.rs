//! Gaussian sets on the GPU: the [`SceneBuffer`] every frame draws, the viewer's
//! [`GpuScene`] kept between frames (the static set written once, each timestamp's
//! dynamic set over the part after it) and [`StoredSet`]s copied into it, and the binding
//! limit that bounds them. A version-2 scene's spacetime set is evaluated into a
//! `GpuScene` on the GPU instead (crate::spacetime::GpuSpacetimeSet).

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
    /// The leading Gaussians nobody trains (a training session's frozen static set): the
    /// backward gives them zero gradients without working them out, and stops each pixel's
    /// walk at the front-most Gaussian that is trained.
    pub n_static: u32,
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
    let bytes = GpuScene::bytes_for(n, k);
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
pub struct GpuScene {
    buffer: wgpu::Buffer,
    capacity: u32,
    sh_coeffs: u32,
    len: u32,
}

impl GpuScene {
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
            label: Some("gpu scene"),
            size: bytes,
            // COPY_SRC: the tests read what a kernel wrote into it.
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
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
        let places = self.place(first, n, k)?;
        for (data, (offset, _)) in part.sections().into_iter().zip(places) {
            if !data.is_empty() {
                queue.write_buffer(&self.buffer, offset, bytemuck::cast_slice(data));
            }
        }
        self.len = first as u32 + n;
        Ok(())
    }

    /// [`Self::write`] of a set already on the GPU: a GPU-side copy of `set` into Gaussians
    /// `first..first + set.len()`, with no upload from the host.
    pub fn copy_from(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        first: usize,
        set: &StoredSet,
    ) -> Result<(), RasterError> {
        let places = self.place(first, set.len, set.sh_coeffs)?;
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("copy stored set"),
        });
        let mut source = 0;
        for (offset, bytes) in places {
            if bytes > 0 {
                encoder.copy_buffer_to_buffer(&set.buffer, source, &self.buffer, offset, bytes);
            }
            source += bytes;
        }
        queue.submit([encoder.finish()]);
        self.len = first as u32 + set.len;
        Ok(())
    }

    /// [`Self::write`] done by a kernel: makes Gaussians `first..first + n` (with `k` SH
    /// coefficients per channel) the last ones drawn, after the same checks, and returns the
    /// buffer a kernel writes them into (the spacetime evaluate pass), which must be
    /// submitted before the next draw.
    pub(crate) fn claim(
        &mut self,
        first: usize,
        n: u32,
        k: u32,
    ) -> Result<SceneBuffer, RasterError> {
        self.place(first, n, k)?;
        self.len = first as u32 + n;
        Ok(self.as_buffer())
    }

    /// (byte offset, bytes) of each SoA section of `n` Gaussians with `k` SH coefficients
    /// placed at `first`, or why they cannot go there.
    fn place(&self, first: usize, n: u32, k: u32) -> Result<[(u64, u64); 5], RasterError> {
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
        let mut section_start = 0;
        Ok(section_widths(self.sh_coeffs).map(|width| {
            let place = (
                4 * (section_start + first as u64 * width),
                4 * n as u64 * width,
            );
            section_start += width * self.capacity as u64;
            place
        }))
    }

    pub fn as_buffer(&self) -> SceneBuffer {
        SceneBuffer {
            buffer: self.buffer.clone(),
            len: self.len,
            stride: self.capacity,
            sh_coeffs: self.sh_coeffs,
            n_static: 0,
        }
    }
}

/// Floats per Gaussian in each SoA section: means, log-scales, quaternions, opacity, SH.
fn section_widths(sh_coeffs: u32) -> [u64; 5] {
    [3, 3, 4, 1, 3 * sh_coeffs as u64]
}

/// A Gaussian set uploaded once into a GPU buffer of its own, in the SoA layout with a
/// stride of its own length. No shader binds it, so only the device's buffer size limit
/// applies (not the binding limit); [`GpuScene::copy_from`] copies it into the
/// scene on the GPU. The viewer keeps every timestamp's dynamic set this way when they fit.
pub struct StoredSet {
    buffer: wgpu::Buffer,
    len: u32,
    sh_coeffs: u32,
}

impl StoredSet {
    /// Uploads `part`; fails when it is over the device's buffer size limit.
    pub fn upload(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        part: &SceneInput<'_>,
    ) -> Result<Self, RasterError> {
        let (n, k) = part.validate().map_err(RasterError::InvalidInput)?;
        let bytes = GpuScene::bytes_for(n as usize, k as usize);
        let allowed = device.limits().max_buffer_size;
        if bytes > allowed {
            return Err(RasterError::TooLarge {
                gaussians: n as usize,
                bytes,
                allowed,
            });
        }
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("stored gaussians"),
            size: bytes.max(4),
            usage: wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        if n > 0 {
            queue.write_buffer(&buffer, 0, bytemuck::cast_slice(&part.packed()));
        }
        Ok(Self {
            buffer,
            len: n,
            sh_coeffs: k,
        })
    }

    pub fn len(&self) -> usize {
        self.len as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes it holds on the GPU.
    pub fn bytes(&self) -> u64 {
        self.buffer.size()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::gaussians::GaussianSet;
    use crate::raster::{target_texture, GpuContext, RenderSettings, Renderer};
    use glam::DVec3;

    /// `n` SH-degree-1 Gaussians spread in front of a camera at the origin looking along +x.
    fn set(n: usize, shift: f32) -> GaussianSet {
        let mut set = GaussianSet::with_capacity(1, n);
        for i in 0..n {
            let a = i as f32 * 0.37 + shift;
            set.means
                .push([4.0 + a.sin(), 1.5 * (1.3 * a).cos(), (0.7 * a).sin()]);
            set.log_scales.push([-2.5, -2.0 - 0.3 * a.sin(), -2.2]);
            set.quats.push([1.0, 0.1 * a.cos(), 0.0, 0.2]);
            set.opacity_logits.push(a.cos());
            set.sh.extend((0..12).map(|j| (a + j as f32).sin()));
        }
        set
    }

    #[test]
    fn a_stored_set_copied_in_draws_what_the_same_set_written_draws() {
        let mut renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
        let (device, queue) = {
            let ctx = renderer.context();
            (ctx.device.clone(), ctx.queue.clone())
        };
        let camera = Camera::from_fov(60.0, 40, 30, DVec3::ZERO, DVec3::X, DVec3::Z);
        let target = target_texture(&device, 40, 30);
        let settings = RenderSettings::default();
        let static_set = set(120, 0.0);
        let [first, second] = [set(70, 5.0), set(30, 9.0)];
        let stored = [&first, &second]
            .map(|s| StoredSet::upload(&device, &queue, &SceneInput::from(s)).expect("stored set"));
        assert_eq!(stored[0].bytes(), GpuScene::bytes_for(70, 4));
        let mut written = GpuScene::new(&device, 200, 4).expect("scene");
        let mut copied = GpuScene::new(&device, 200, 4).expect("scene");
        for scene in [&mut written, &mut copied] {
            scene
                .write(&queue, 0, &SceneInput::from(&static_set))
                .expect("static set");
        }
        // Both dynamic sets in turn, the smaller after the larger, as playback does.
        for (dynamic, stored) in [(&first, &stored[0]), (&second, &stored[1])] {
            written
                .write(&queue, 120, &SceneInput::from(dynamic))
                .expect("write");
            copied
                .copy_from(&device, &queue, 120, stored)
                .expect("copy");
            assert_eq!(copied.len(), 120 + dynamic.len());
            let mut frames = Vec::new();
            for scene in [&written, &copied] {
                renderer
                    .draw(scene, &camera, &settings, &target)
                    .expect("draw");
                frames.push(renderer.read_rgba8(&target).expect("read back"));
            }
            assert!(
                frames[0].chunks(4).any(|p| p[..3] != [0, 0, 0]),
                "nothing drawn"
            );
            assert!(frames[0] == frames[1], "{} dynamic", dynamic.len());
        }
        // The same checks as a write: room, no gap, the scene's SH degree.
        assert!(copied.copy_from(&device, &queue, 140, &stored[0]).is_err());
        let mut degree_zero = GaussianSet::with_capacity(0, 1);
        degree_zero.means.push([4.0, 0.0, 0.0]);
        degree_zero.log_scales.push([-2.0; 3]);
        degree_zero.quats.push([1.0, 0.0, 0.0, 0.0]);
        degree_zero.opacity_logits.push(0.0);
        degree_zero.sh.extend([0.5; 3]);
        let other =
            StoredSet::upload(&device, &queue, &SceneInput::from(&degree_zero)).expect("stored");
        assert!(copied.copy_from(&device, &queue, 120, &other).is_err());
        assert_eq!(copied.len(), 150);
    }
}
