//! The backward pass: gradients of a loss w.r.t. the Gaussians, given its gradient w.r.t.
//! the forward's output (docs/rasterizer.md, "Backward").

use super::buffers::{check_intersections, GrowBuffer};
use super::kernels::{bind_group, div_ceil, run_linear};
use super::renderer::{pop_error, Frame, RenderSettings, Renderer, PIXEL_CHANNELS};
use super::RasterError;
use crate::camera::Camera;
use crate::gaussians::{SceneInput, BASE_FLOATS};

/// Floats per intersection gradient (rasterize_backward.wgsl).
const ISECT_GRAD_FLOATS: u64 = 10;

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
        let frame = self.encode_frame(scene, camera, settings)?;
        let device = self.ctx.device.clone();
        let v_buf = self
            .buffers
            .v_pixels
            .get(&device, 4 * v_pixels.len() as u64)
            .clone();
        self.ctx
            .queue
            .write_buffer(&v_buf, 0, bytemuck::cast_slice(v_pixels));
        let n = frame.params.num_gaussians as u64;
        let k = frame.params.sh_coeffs as u64;
        let grad_floats = BASE_FLOATS as u64 * n + 3 * k * n;
        let grads = self.buffers.grads.get(&device, 4 * grad_floats).clone();
        self.encode_backward(&frame, &v_buf, &grads)?;
        let flat: Vec<f32> = if n == 0 {
            Vec::new()
        } else {
            bytemuck::pod_collect_to_vec(&self.read_back(&grads, 4 * grad_floats)?)
        };
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
    /// `v_pixels` holds the loss's gradient w.r.t. the forward's H·W·5 output, and `grads`
    /// receives the gradients in [`Gradients`]' order as one SoA buffer of
    /// `BASE_FLOATS · n + 3 k n` floats. Nothing is read back: a training loop chains this
    /// with its optimiser on the device.
    pub(crate) fn encode_backward(
        &mut self,
        frame: &Frame,
        v_pixels: &wgpu::Buffer,
        grads: &wgpu::Buffer,
    ) -> Result<(), RasterError> {
        let device = self.ctx.device.clone();
        let n = frame.params.num_gaussians;
        let b = &mut self.buffers;
        check_intersections(&device, frame.num_intersections, 4 * ISECT_GRAD_FLOATS)?;
        let m = frame.num_intersections as u64;
        let isect_grads = b
            .isect_grads
            .get(&device, 4 * ISECT_GRAD_FLOATS * m)
            .clone();
        let get = |g: &GrowBuffer| g.buffer.clone().expect("allocated by encode_frame");
        let depth_vals = get(&b.depth_vals[frame.depth_sorted]);
        let mut encoder = device.create_command_encoder(&Default::default());
        encoder.clear_buffer(&isect_grads, 0, None);
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.rasterize_backward);
            let group = bind_group(
                &device,
                &self.rasterize_backward,
                &[
                    (0, &b.params),
                    (1, &get(&b.projected)),
                    (2, &get(&b.isect_slots[frame.sorted])),
                    (3, &get(&b.isect_gaussian)),
                    (4, &get(&b.ranges)),
                    (5, &get(&b.pixel_state)),
                    (6, v_pixels),
                    (7, &isect_grads),
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
                        (0, &b.params),
                        (1, &frame.scene.buffer),
                        (2, &get(&b.tile_counts)),
                        (3, &depth_vals),
                        (4, &get(&b.offsets)),
                        (5, &isect_grads),
                        (6, grads),
                    ],
                    div_ceil(n, 256),
                );
            }
        }
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        self.ctx.queue.submit([encoder.finish()]);
        pop_error(scope)
    }
}
