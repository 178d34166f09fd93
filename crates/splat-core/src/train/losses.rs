//! The lifting phase's losses and their per-pixel gradient on the device
//! (`losses.wgsl`; the torch reference is `GaussianTrainer.loss_at`).

use crate::raster::gpu::{compile, div_ceil, run_linear};
use crate::raster::{COMMON_WGSL, PIXEL_CHANNELS};
use crate::wgsl::{gpu_struct, KernelModule, WgslPart};

const LOSSES_WGSL: WgslPart = WgslPart {
    file: "losses.wgsl",
    source: include_str!("losses.wgsl"),
    needs: &[COMMON_WGSL.file],
    reads: &[],
};

pub(crate) fn module() -> KernelModule {
    KernelModule {
        label: "train losses",
        parts: vec![&COMMON_WGSL, &LOSSES_WGSL],
    }
}

/// kornia's SSIM window: 11 taps, σ = 1.5.
pub const SSIM_WINDOW: u32 = 11;
const SSIM_SIGMA: f32 = 1.5;
/// Floats per pixel of the moments (5 × vec4) and of the gradient coefficients (3 × vec4);
/// partial sums per workgroup; sums (losses.wgsl).
const MOMENT_FLOATS: u64 = 20;
const COEFF_FLOATS: u64 = 12;
const PARTIALS: u64 = 8;
/// Pixels per invocation of the window and summing passes: a run along a row or a column
/// (losses.wgsl, `Run`).
const PIXELS_PER_INVOCATION: u32 = 8;
const TOTALS: u64 = 16;
/// Floats of the loss read-back, in `loss_value`'s order (losses.wgsl): [L, L1, 1 − SSIM,
/// L_temporal, 1 − Pearson, covered weight, whether L_geo applied]; read as [`LossParts`].
pub const LOSS_PARTS: usize = 7;

/// One step's loss and its parts, by name.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossParts {
    /// L = λ_l1 L1 + λ_ssim (1 − SSIM) + λ_temporal L_temporal + λ_geo (1 − Pearson).
    pub total: f32,
    pub l1: f32,
    /// 1 − SSIM.
    pub d_ssim: f32,
    /// L_temporal; 0 where the view has no previous render.
    pub temporal: f32,
    /// L_geo before its weight: 1 − the Pearson correlation of the rendered depth with Θ's
    /// over the covered pixels; 0 where L_geo did not apply.
    pub one_minus_pearson: f32,
    /// Σ weight over the covered pixels (alpha > 0.5), the view's rest included.
    pub covered_weight: f32,
    /// Whether L_geo applied this step (a view with a depth, λ_geo > 0 and `loss_at`'s
    /// coverage rule met).
    pub geo_applied: bool,
}

impl LossParts {
    /// The read-back floats, in `loss_value`'s order.
    pub(super) fn from_floats(v: [f32; LOSS_PARTS]) -> Self {
        Self {
            total: v[0],
            l1: v[1],
            d_ssim: v[2],
            temporal: v[3],
            one_minus_pearson: v[4],
            covered_weight: v[5],
            geo_applied: v[6] != 0.0,
        }
    }
}

/// Weights of the loss terms: L1 and D-SSIM (1 − λ_dssim and λ_dssim, the `lambda_dssim`
/// knob: `train_settings` in lift/resident.py),
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

gpu_struct! {
    /// The uniform of one view's loss passes (losses.wgsl documents each field).
    pub(crate) struct LossParams {
        width: u32,
        height: u32,
        radius: u32,
        has_previous: u32,
        weight_sum: f32,
        lambda_l1: f32,
        lambda_ssim: f32,
        lambda_temporal: f32,
        lambda_geo: f32,
        outside_l1: f32,
        outside_ssim: f32,
        outside_temporal: f32,
        outside_covered: f32,
        outside_mean_a: f32,
        outside_mean_b: f32,
        outside_var_a: f32,
        outside_var_b: f32,
        outside_cov: f32,
        pad0: u32,
        pad1: u32,
        /// The window's taps, four to a vector.
        taps: [[f32; 4]; 3],
    }
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
        outside: [f32; OUTSIDE_SUMS],
    ) -> Self {
        let window = ssim_window(width, height);
        let mut taps = [[0.0; 4]; 3];
        taps.as_flattened_mut()[..window as usize].copy_from_slice(&ssim_taps(window));
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
            outside_l1: outside[0],
            outside_ssim: outside[1],
            outside_temporal: outside[2],
            outside_covered: outside[3],
            outside_mean_a: outside[4],
            outside_mean_b: outside[5],
            outside_var_a: outside[6],
            outside_var_b: outside[7],
            outside_cov: outside[8],
            pad0: 0,
            pad1: 0,
            taps,
        }
    }
}

/// The loss sums over the pixels of a view outside the window its steps render (all zero
/// when they render the whole view), in losses.wgsl's `outside_*` order: Σ w·mean|x − t|,
/// Σ w·mean SSIM, Σ w·mean|x − prev|, L_geo's covered weight Σ c, the means of the
/// rendered and of Θ's depth over it, and Σ c·da², Σ c·db², Σ c·da·db about those means.
/// The static render outside a dynamic step's window cannot change during the stage, so
/// the host computes them once (python/pano4d/lift/windows.py).
pub const OUTSIDE_SUMS: usize = 9;

/// A view's size and targets on the device (`depth` and `previous` are a placeholder when
/// absent).
pub(super) struct ViewBuffers<'a> {
    pub width: u32,
    pub height: u32,
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
    /// The row-filtered moments, later the column adjoints (never both alive).
    moments: wgpu::Buffer,
    coeffs: wgpu::Buffer,
    partials: wgpu::Buffer,
    totals: wgpu::Buffer,
    pub v_pixels: wgpu::Buffer,
    pub loss: wgpu::Buffer,
}

impl LossBuffers {
    pub(super) fn new(device: &wgpu::Device, pixels: u32) -> Self {
        let p = pixels as u64;
        let none = wgpu::BufferUsages::empty();
        Self {
            moments: storage(device, "ssim moments", MOMENT_FLOATS * p, none),
            coeffs: storage(device, "ssim coefficients", COEFF_FLOATS * p, none),
            partials: storage(
                device,
                "loss partial sums",
                PARTIALS * div_ceil(pixels, 256) as u64,
                none,
            ),
            totals: storage(device, "loss sums", TOTALS, none),
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
        }
    }
}

pub(super) struct LossKernels {
    ssim_rows: wgpu::ComputePipeline,
    ssim_columns: wgpu::ComputePipeline,
    totals_a: wgpu::ComputePipeline,
    pearson_terms: wgpu::ComputePipeline,
    totals_b: wgpu::ComputePipeline,
    adjoint_columns: wgpu::ComputePipeline,
    pixel_grads: wgpu::ComputePipeline,
    loss_value: wgpu::ComputePipeline,
}

impl LossKernels {
    pub(super) fn new(device: &wgpu::Device) -> Self {
        let entries = [
            "ssim_rows",
            "ssim_columns",
            "totals_a",
            "pearson_terms",
            "totals_b",
            "adjoint_columns",
            "pixel_grads",
            "loss_value",
        ];
        let [ssim_rows, ssim_columns, totals_a, pearson_terms, totals_b, adjoint_columns, pixel_grads, loss_value]: [wgpu::ComputePipeline; 8] =
            compile(device, &module(), &entries)
                .try_into()
                .expect("eight entry points");
        Self {
            ssim_rows,
            ssim_columns,
            totals_a,
            pearson_terms,
            totals_b,
            adjoint_columns,
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
        // One invocation per run of a row (`rows`) or a column (`columns`, also the summing
        // passes' workgroups: totals_a and totals_b sum as many partials).
        let (w, h) = (view.width, view.height);
        let rows = div_ceil(h * div_ceil(w, PIXELS_PER_INVOCATION), 256);
        let columns = div_ceil(w * div_ceil(h, PIXELS_PER_INVOCATION), 256);
        // The shader's bindings by number (8, the column adjoints, reuses the moments'
        // buffer) and, per pass, the ones its entry point uses.
        let buffers: [&wgpu::Buffer; 13] = [
            view.params,
            pixels,
            view.rgb,
            view.weight,
            view.depth,
            view.previous,
            &b.moments,
            &b.coeffs,
            &b.moments,
            &b.partials,
            &b.totals,
            &b.v_pixels,
            &b.loss,
        ];
        let passes: [(&wgpu::ComputePipeline, &[u32], u32); 8] = [
            (&self.ssim_rows, &[0, 1, 2, 3, 6], rows),
            (&self.ssim_columns, &[0, 1, 2, 3, 4, 5, 6, 7, 9], columns),
            (&self.totals_a, &[0, 9, 10], 1),
            (&self.pearson_terms, &[0, 1, 3, 4, 9, 10], columns),
            (&self.totals_b, &[0, 9, 10], 1),
            (&self.adjoint_columns, &[0, 7, 8], columns),
            (&self.pixel_grads, &[0, 1, 2, 3, 4, 5, 7, 8, 10, 11], rows),
            (&self.loss_value, &[0, 10, 12], 1),
        ];
        let mut pass = encoder.begin_compute_pass(&Default::default());
        for (pipeline, used, groups) in passes {
            let bindings: Vec<(u32, &wgpu::Buffer)> =
                used.iter().map(|&i| (i, buffers[i as usize])).collect();
            run_linear(&mut pass, device, pipeline, &bindings, groups);
        }
    }
}
