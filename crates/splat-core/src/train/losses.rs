//! The lifting phase's losses and their per-pixel gradient on the device
//! (`shaders/train_losses.wgsl`; the torch reference is `GaussianTrainer.loss_at`).

use crate::raster::kernels::{compile, div_ceil, run_linear, COMMON_WGSL};
use crate::raster::renderer::PIXEL_CHANNELS;

const LOSSES_WGSL: &str = include_str!("../../../../shaders/train_losses.wgsl");

/// kornia's SSIM window: 11 taps, σ = 1.5.
pub const SSIM_WINDOW: u32 = 11;
const SSIM_SIGMA: f32 = 1.5;
/// Per-pixel summands of sums A and B, and where B's totals start (train_losses.wgsl).
const TERMS_A: u32 = 6;
const TERMS_B: u32 = 5;
const TOTALS_B: u32 = 8;
const TOTALS: u64 = 16;
/// Floats of the loss read-back: [L, L1, 1 − SSIM, L_temporal, 1 − Pearson, covered weight,
/// whether L_geo applied].
pub const LOSS_PARTS: usize = 7;

/// Weights of the loss terms: L1 and D-SSIM (0.8 and 0.2 times λ_rgb in optimize.py),
/// λ_temporal, λ_geo. L_temporal applies only to views with a previous render, L_geo only
/// to views with a depth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossWeights {
    pub l1: f32,
    pub ssim: f32,
    pub temporal: f32,
    pub geo: f32,
}

/// The window the torch trainer uses for an image of `width`×`height`: 11 taps, fewer
/// (odd) where the image is too small for them.
pub fn ssim_window(width: u32, height: u32) -> u32 {
    SSIM_WINDOW.min((width.min(height) / 2) * 2 - 1)
}

/// kornia's `get_gaussian_kernel1d(window, 1.5)` in f32: exp(−x²/2σ²) normalised to sum 1.
pub fn ssim_taps(window: u32) -> Vec<f32> {
    let half = (window / 2) as f32;
    let denominator = 2.0 * SSIM_SIGMA * SSIM_SIGMA;
    let gauss: Vec<f32> = (0..window)
        .map(|i| {
            let x = i as f32 - half;
            (-(x * x) / denominator).exp()
        })
        .collect();
    let sum: f32 = gauss.iter().sum();
    gauss.iter().map(|g| g / sum).collect()
}

#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct LossParams {
    width: u32,
    height: u32,
    radius: u32,
    has_previous: u32,
    weight_sum: f32,
    lambda_l1: f32,
    lambda_ssim: f32,
    lambda_temporal: f32,
    lambda_geo: f32,
    pad: [u32; 3],
    taps: [f32; 12],
}

impl LossParams {
    /// The constants of one view: its size, its weight sum ws = max(Σ w, 1e-6) (computed
    /// by the caller as torch does) and the loss weights; a λ is 0 where its target is
    /// missing.
    pub(super) fn new(
        width: u32,
        height: u32,
        weight_sum: f32,
        weights: LossWeights,
        has_previous: bool,
        has_depth: bool,
    ) -> Self {
        let window = ssim_window(width, height);
        let mut taps = [0.0; 12];
        taps[..window as usize].copy_from_slice(&ssim_taps(window));
        Self {
            width,
            height,
            radius: window / 2,
            has_previous: (has_previous && weights.temporal > 0.0) as u32,
            weight_sum,
            lambda_l1: weights.l1,
            lambda_ssim: weights.ssim,
            lambda_temporal: weights.temporal,
            lambda_geo: if has_depth { weights.geo } else { 0.0 },
            pad: [0; 3],
            taps,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct ReduceParams {
    count: u32,
    quantities: u32,
    first_total: u32,
    first_term: u32,
}

/// A view's targets on the device (`depth` and `previous` are a placeholder when absent).
pub(super) struct ViewBuffers<'a> {
    pub params: &'a wgpu::Buffer,
    pub rgb: &'a wgpu::Buffer,
    pub weight: &'a wgpu::Buffer,
    pub depth: &'a wgpu::Buffer,
    pub previous: &'a wgpu::Buffer,
}

fn storage(
    device: &wgpu::Device,
    label: &str,
    floats: u64,
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        // Runtime-sized arrays need at least one element bound.
        size: (4 * floats).max(256).next_multiple_of(16),
        usage: wgpu::BufferUsages::STORAGE | usage,
        mapped_at_creation: false,
    })
}

/// The scratch buffers of the loss passes for views of one size, and their outputs:
/// the pixel gradient (`v_pixels`, the forward's layout) and the loss parts (`loss`).
pub(super) struct LossBuffers {
    pixels: u32,
    rows: wgpu::Buffer,
    coeffs: wgpu::Buffer,
    terms: wgpu::Buffer,
    partials: wgpu::Buffer,
    totals: wgpu::Buffer,
    reduce_a: wgpu::Buffer,
    reduce_b: wgpu::Buffer,
    pub v_pixels: wgpu::Buffer,
    pub loss: wgpu::Buffer,
}

impl LossBuffers {
    /// Buffers for `pixels` pixels; returns them and the bytes of the two small uniforms
    /// it uploads.
    pub(super) fn new(device: &wgpu::Device, queue: &wgpu::Queue, pixels: u32) -> (Self, u64) {
        let p = pixels as u64;
        let none = wgpu::BufferUsages::empty();
        let groups = div_ceil(pixels, 256) as u64;
        let reduce = |label, params: ReduceParams| {
            let buffer = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: std::mem::size_of::<ReduceParams>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            queue.write_buffer(&buffer, 0, bytemuck::bytes_of(&params));
            buffer
        };
        let buffers = Self {
            pixels,
            rows: storage(device, "ssim rows", 15 * p, none),
            coeffs: storage(device, "ssim coefficients", 9 * p, none),
            terms: storage(device, "loss terms", (TERMS_A + TERMS_B) as u64 * p, none),
            partials: storage(device, "loss partial sums", TERMS_A as u64 * groups, none),
            totals: storage(device, "loss sums", TOTALS, none),
            reduce_a: reduce(
                "reduce A",
                ReduceParams {
                    count: pixels,
                    quantities: TERMS_A,
                    first_total: 0,
                    first_term: 0,
                },
            ),
            reduce_b: reduce(
                "reduce B",
                ReduceParams {
                    count: pixels,
                    quantities: TERMS_B,
                    first_total: TOTALS_B,
                    first_term: TERMS_A * pixels,
                },
            ),
            v_pixels: storage(
                device,
                "pixel gradients",
                PIXEL_CHANNELS as u64 * p,
                wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            ),
            loss: storage(
                device,
                "loss",
                LOSS_PARTS as u64,
                wgpu::BufferUsages::COPY_SRC,
            ),
        };
        (buffers, 2 * std::mem::size_of::<ReduceParams>() as u64)
    }
}

pub(super) struct LossKernels {
    pixel_terms: wgpu::ComputePipeline,
    ssim_rows: wgpu::ComputePipeline,
    ssim_columns: wgpu::ComputePipeline,
    reduce_partials: wgpu::ComputePipeline,
    reduce_totals: wgpu::ComputePipeline,
    pearson_terms: wgpu::ComputePipeline,
    ssim_adjoint_columns: wgpu::ComputePipeline,
    pixel_grads: wgpu::ComputePipeline,
    loss_value: wgpu::ComputePipeline,
}

impl LossKernels {
    pub(super) fn new(device: &wgpu::Device) -> Self {
        let entries = [
            "pixel_terms",
            "ssim_rows",
            "ssim_columns",
            "reduce_partials",
            "reduce_totals",
            "pearson_terms",
            "ssim_adjoint_columns",
            "pixel_grads",
            "loss_value",
        ];
        let [pixel_terms, ssim_rows, ssim_columns, reduce_partials, reduce_totals, pearson_terms, ssim_adjoint_columns, pixel_grads, loss_value]: [wgpu::ComputePipeline; 9] =
            compile(device, "train losses", &[COMMON_WGSL, LOSSES_WGSL], &entries)
                .try_into()
                .expect("nine entry points");
        Self {
            pixel_terms,
            ssim_rows,
            ssim_columns,
            reduce_partials,
            reduce_totals,
            pearson_terms,
            ssim_adjoint_columns,
            pixel_grads,
            loss_value,
        }
    }

    /// Encodes every loss pass for the forward output `pixels` of `view`: leaves the pixel
    /// gradient in `b.v_pixels` and the loss parts in `b.loss`.
    pub(super) fn encode(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        b: &LossBuffers,
        view: &ViewBuffers<'_>,
        pixels: &wgpu::Buffer,
    ) {
        let groups = div_ceil(b.pixels, 256);
        let mut pass = encoder.begin_compute_pass(&Default::default());
        let reduce = |pass: &mut wgpu::ComputePass<'_>, params: &wgpu::Buffer| {
            run_linear(
                pass,
                device,
                &self.reduce_partials,
                &[(13, params), (14, &b.terms), (9, &b.partials)],
                groups,
            );
            run_linear(
                pass,
                device,
                &self.reduce_totals,
                &[(13, params), (9, &b.partials), (10, &b.totals)],
                1,
            );
        };
        let p = view.params;
        run_linear(
            &mut pass,
            device,
            &self.pixel_terms,
            &[
                (0, p),
                (1, pixels),
                (2, view.rgb),
                (3, view.weight),
                (4, view.depth),
                (5, view.previous),
                (8, &b.terms),
            ],
            groups,
        );
        run_linear(
            &mut pass,
            device,
            &self.ssim_rows,
            &[(0, p), (1, pixels), (2, view.rgb), (6, &b.rows)],
            groups,
        );
        run_linear(
            &mut pass,
            device,
            &self.ssim_columns,
            &[
                (0, p),
                (3, view.weight),
                (6, &b.rows),
                (7, &b.coeffs),
                (8, &b.terms),
            ],
            groups,
        );
        reduce(&mut pass, &b.reduce_a);
        run_linear(
            &mut pass,
            device,
            &self.pearson_terms,
            &[
                (0, p),
                (1, pixels),
                (3, view.weight),
                (4, view.depth),
                (8, &b.terms),
                (10, &b.totals),
            ],
            groups,
        );
        reduce(&mut pass, &b.reduce_b);
        run_linear(
            &mut pass,
            device,
            &self.ssim_adjoint_columns,
            &[(0, p), (6, &b.rows), (7, &b.coeffs)],
            groups,
        );
        run_linear(
            &mut pass,
            device,
            &self.pixel_grads,
            &[
                (0, p),
                (1, pixels),
                (2, view.rgb),
                (3, view.weight),
                (4, view.depth),
                (5, view.previous),
                (6, &b.rows),
                (7, &b.coeffs),
                (10, &b.totals),
                (11, &b.v_pixels),
            ],
            groups,
        );
        run_linear(
            &mut pass,
            device,
            &self.loss_value,
            &[(0, p), (10, &b.totals), (12, &b.loss)],
            1,
        );
    }
}
