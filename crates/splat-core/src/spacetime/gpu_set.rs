//! A spacetime set kept on the GPU and drawn at any time there: uploaded once (its
//! canonical Gaussians and time parameters), then evaluated by the evaluate pass
//! (evaluate.rs, the training session's own) into the part of a [`GpuScene`] after the
//! static set whenever the shown time changes. The viewer plays a version-2 scene so: no
//! evaluation on the CPU and nothing uploaded per frame but the pass's uniform.

use super::evaluate::{EvaluateKernels, TimeLayout, TimeParams};
use super::{packed_parameters, SpacetimeSet, TimeModel};
use crate::gaussians::{SceneInput, BASE_FLOATS};
use crate::raster::{binding_limit, GpuScene, RasterError};

/// A spacetime set on the GPU, evaluated into a [`GpuScene`] by [`Self::evaluate_into`].
pub struct GpuSpacetimeSet {
    model: TimeModel,
    len: u32,
    sh_coeffs: u32,
    /// The canonical Gaussians, then the time sections, each section `len` long: a training
    /// session's layout ([`packed_parameters`]), which the pass reads.
    params: wgpu::Buffer,
    /// The pass's uniform: the functions of time at the time evaluated last.
    uniform: wgpu::Buffer,
    kernels: EvaluateKernels,
}

impl GpuSpacetimeSet {
    /// Bytes of the parameters of `n` Gaussians with `sh_coeffs` SH coefficients per channel
    /// and time model `model`.
    pub fn bytes_for(n: usize, sh_coeffs: usize, model: &TimeModel) -> u64 {
        4 * n as u64 * (BASE_FLOATS + 3 * sh_coeffs + model.floats_per_gaussian()) as u64
    }

    /// Uploads `set`; fails when its parameters are over the device's storage-binding limit
    /// (the pass binds them whole).
    pub fn upload(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        set: &SpacetimeSet,
    ) -> Result<Self, RasterError> {
        let canonical = SceneInput::from(&set.canonical);
        let (n, k) = canonical.validate().map_err(RasterError::InvalidInput)?;
        let time = set.time_input();
        time.check(n as usize).map_err(RasterError::InvalidInput)?;
        let bytes = Self::bytes_for(n as usize, k as usize, &set.model);
        let allowed = binding_limit(device);
        if bytes > allowed {
            return Err(RasterError::TooLarge {
                gaussians: n as usize,
                bytes,
                allowed,
            });
        }
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("spacetime parameters"),
            // Runtime-sized arrays need at least one element bound.
            size: bytes.max(256),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        if n > 0 {
            let packed = packed_parameters(&canonical, Some(time));
            queue.write_buffer(&params, 0, bytemuck::cast_slice(&packed));
        }
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("spacetime time params"),
            size: std::mem::size_of::<TimeParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(Self {
            model: set.model,
            len: n,
            sh_coeffs: k,
            params,
            uniform,
            kernels: EvaluateKernels::new(device),
        })
    }

    pub fn model(&self) -> TimeModel {
        self.model
    }

    pub fn len(&self) -> usize {
        self.len as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes its parameters hold on the GPU.
    pub fn bytes(&self) -> u64 {
        self.params.size()
    }

    /// Writes the set at `time` (frames, any real value: the functions of time take it
    /// modulo the period, as [`SpacetimeSet::at`]) as Gaussians `first..first + len` of
    /// `scene`, which then draws exactly those and the ones before them: one compute pass,
    /// submitted, so the next draw shows it.
    pub fn evaluate_into(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        scene: &mut GpuScene,
        first: usize,
        time: f64,
    ) -> Result<(), RasterError> {
        let target = scene.claim(first, self.len, self.sh_coeffs)?;
        let layout = TimeLayout {
            n_static: first as u32,
            n_train: self.len,
            scene_len: target.stride,
            sh_coeffs: self.sh_coeffs,
            has_extra: false,
        };
        let params = TimeParams::new(&self.model, time, layout);
        queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&params));
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("evaluate spacetime set"),
        });
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            self.kernels.encode_evaluate(
                device,
                &mut pass,
                &self.uniform,
                &self.params,
                &target.buffer,
                self.len,
            );
        }
        queue.submit([encoder.finish()]);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gaussians::{sh_coeffs, GaussianSet};
    use crate::raster::gpu::read_mapped;
    use crate::raster::GpuContext;

    /// Deterministic values in [-1, 1).
    fn noise(seed: &mut u64, n: usize) -> Vec<f32> {
        (0..n)
            .map(|_| {
                *seed = seed
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                ((*seed >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }

    /// `n` Gaussians of SH degree 1 a few units out, with every time term set: centres
    /// across the loop (and beyond it), widths of 1.5–4 frames, colour and position waves.
    fn spacetime_set(n: usize, model: TimeModel, seed: u64) -> SpacetimeSet {
        let mut s = seed;
        let mut r = |count: usize| noise(&mut s, count);
        let period = model.period as f32;
        let canonical = GaussianSet {
            sh_degree: 1,
            means: r(3 * n)
                .chunks(3)
                .map(|v| [4.0 + v[0], 2.0 * v[1], 2.0 * v[2]])
                .collect(),
            log_scales: r(3 * n)
                .chunks(3)
                .map(|v| [v[0] - 2.0, v[1] - 2.0, v[2] - 2.0])
                .collect(),
            quats: r(4 * n)
                .chunks(4)
                .map(|v| [1.0, v[1], v[2], v[3]])
                .collect(),
            opacity_logits: r(n).iter().map(|v| 2.0 * v).collect(),
            sh: r(12 * n),
        };
        SpacetimeSet {
            model,
            canonical,
            time_centre: r(n).iter().map(|v| (v + 1.0) * period).collect(),
            time_log_width: r(n).iter().map(|v| (2.75 + 1.25 * v).ln()).collect(),
            colour_terms: r(6 * model.colour_harmonics as usize * n)
                .iter()
                .map(|v| 0.3 * v)
                .collect(),
            position_terms: r(6 * model.position_harmonics as usize * n)
                .iter()
                .map(|v| 0.2 * v)
                .collect(),
        }
    }

    /// Gaussians `first..first + n` of `scene` (SH degree 1), read back from the GPU.
    fn read_part(ctx: &GpuContext, scene: &GpuScene, first: usize, n: usize) -> GaussianSet {
        let buffer = scene.as_buffer();
        let size = buffer.buffer.size();
        let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read back"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(&buffer.buffer, 0, &staging, 0, size);
        ctx.queue.submit([encoder.finish()]);
        let bytes = read_mapped(&ctx.device, &staging, size).expect("read back");
        let all: &[f32] = bytemuck::cast_slice(&bytes);
        let capacity = scene.capacity();
        let mut packed = Vec::new();
        let mut start = 0;
        for width in [3, 3, 4, 1, 3 * sh_coeffs(1)] {
            packed.extend_from_slice(&all[start + width * first..start + width * (first + n)]);
            start += width * capacity;
        }
        GaussianSet::from_packed(&packed, n, 1)
    }

    /// The largest difference between two sets' values, relative to each value's size
    /// where that is over 1.
    fn worst_difference(a: &GaussianSet, b: &GaussianSet) -> f32 {
        let (a, b) = (SceneInput::from(a), SceneInput::from(b));
        a.sections()
            .iter()
            .zip(b.sections())
            .flat_map(|(x, y)| x.iter().zip(y))
            .fold(0.0f32, |worst, (x, y)| {
                worst.max((x - y).abs() / x.abs().max(1.0))
            })
    }

    #[test]
    fn the_gpu_evaluates_at_any_time_what_the_cpu_form_evaluates() {
        let ctx = GpuContext::new().expect("adapter");
        let (device, queue) = (&ctx.device, &ctx.queue);
        let model = TimeModel {
            period: 6,
            colour_harmonics: 2,
            position_harmonics: 1,
        };
        let set = spacetime_set(300, model, 7);
        let static_set = spacetime_set(50, model, 8).canonical;
        let gpu = GpuSpacetimeSet::upload(device, queue, &set).expect("upload");
        assert_eq!(gpu.len(), 300);
        assert_eq!(gpu.bytes(), GpuSpacetimeSet::bytes_for(300, 4, &model));
        let mut scene = GpuScene::new(device, 400, 4).expect("scene");
        scene
            .write(queue, 0, &SceneInput::from(&static_set))
            .expect("static set");
        let at = |time: f64, scene: &mut GpuScene| {
            gpu.evaluate_into(device, queue, scene, 50, time)
                .expect("evaluate");
            assert_eq!(scene.len(), 350);
            read_part(&ctx, scene, 50, 300)
        };
        // Between frames (where holding a frame would show another set), on them, across
        // the loop's seam and outside one loop.
        for time in [0.37, 2.5, 5.93, 0.0, 3.0, -1.25, 13.1] {
            let got = at(time, &mut scene);
            let worst = worst_difference(&got, &set.at(time));
            // The pass sums the Fourier terms before adding them, the CPU form one by one:
            // float32 rounding apart (measured: 5e-7).
            assert!(worst < 1e-5, "t = {time}: off the CPU form by {worst}");
            let again = at(time + 6.0, &mut scene);
            let worst = worst_difference(&got, &again);
            assert!(worst < 1e-5, "t = {time} and t + period differ by {worst}");
        }
        // The moving part changes between frames; the static set stays as written.
        let worst = worst_difference(&at(2.5, &mut scene), &at(2.0, &mut scene));
        assert!(worst > 0.01, "half a frame moves nothing ({worst})");
        assert_eq!(read_part(&ctx, &scene, 0, 50), static_set);
        // The same checks as a write (GpuScene::place): room, the scene's SH degree.
        let mut small = GpuScene::new(device, 320, 4).expect("scene");
        small
            .write(queue, 0, &SceneInput::from(&static_set))
            .expect("static set");
        assert!(gpu
            .evaluate_into(device, queue, &mut small, 50, 0.0)
            .is_err());
        let mut other_degree = GpuScene::new(device, 400, 1).expect("scene");
        assert!(gpu
            .evaluate_into(device, queue, &mut other_degree, 0, 0.0)
            .is_err());
    }
}
