//! The backward pass: gradients of a loss w.r.t. the Gaussians, given its gradient w.r.t.
//! the forward's output (docs/rasterizer.md, "Backward").

use super::kernels::{bind_group, div_ceil, run_linear};
use super::renderer::{Frame, RenderSettings, Renderer, PIXEL_CHANNELS};
use super::RasterError;
use crate::camera::Camera;
use crate::gaussians::{SceneInput, BASE_FLOATS};

/// Floats of each Gaussian's 2D gradient sums: mean2d (2), conic (3), rgb (3), opacity,
/// depth (rasterize_backward.wgsl).
const GAUSSIAN_GRAD_FLOATS: u64 = 10;

/// Gradients in the layout of [`SceneInput`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Gradients {
    pub means: Vec<f32>,
    pub log_scales: Vec<f32>,
    pub quats: Vec<f32>,
    pub opacity_logits: Vec<f32>,
    pub sh: Vec<f32>,
}

impl Renderer {
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
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.rasterize_backward);
            let group = bind_group(
                &device,
                &self.rasterize_backward,
                &[
                    (0, &self.buffers.params),
                    (1, &frame.projected),
                    (2, &frame.sorted_gaussians),
                    (3, &frame.ranges),
                    (4, &frame.pixel_state),
                    (5, v_pixels),
                    (6, &sums),
                ],
            );
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(frame.params.tiles_x, frame.params.tiles_y, 1);
            if n > 0 {
                run_linear(
                    &mut pass,
                    &device,
                    &self.project_backward,
                    &[
                        (0, &self.buffers.params),
                        (1, &frame.scene.buffer),
                        (2, &frame.tile_counts),
                        (3, &sums),
                        (4, grads),
                    ],
                    div_ceil(n as u32, 256),
                );
            }
        }
        self.submit(encoder)
    }
}
