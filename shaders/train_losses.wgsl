// The lifting phase's photometric and geometric losses and their gradient w.r.t. the
// forward's pixels (r, g, b, alpha, D = Σ z·α·T), for one view, on the device.
// The torch reference is `GaussianTrainer.loss_at` (python/pano4d/lift/optimize.py):
//
//   L = λ_l1 L1 + λ_ssim (1 − SSIM) + λ_temporal L_temporal + λ_geo (1 − Pearson)
//
// (λ_l1 = 0.8 λ_rgb and λ_ssim = 0.2 λ_rgb in the lifting phase),
// with every term weighted per pixel by the view's weight w and normalised by
// ws = max(Σ w, 1e-6) (computed by the host, as torch does). SSIM is kornia's
// `metrics.ssim`: a separable Gaussian window (σ = 1.5, 2R + 1 taps), rows first, then
// columns, each padded by reflection; C1 = 0.01², C2 = 0.03², eps = 1e-12 in the
// denominator. Its gradient runs the adjoint filters in the opposite order (columns, then
// rows), folding the reflected taps back onto the pixels they were read from.
// L_geo compares the expected depth D / alpha with Θ's depth over the covered pixels
// (weight · [alpha > 0.5]) and applies only when their weight sums to more than 16.
//
// Passes, in order (train/losses.rs): pixel_terms, ssim_rows, ssim_columns,
// reduce_partials/reduce_totals (sums A), pearson_terms, reduce_partials/reduce_totals
// (sums B), ssim_adjoint_columns, pixel_grads, loss_value. Sums use fixed trees (no
// atomics), so a step is deterministic.

struct TrainParams {
    width: u32,
    height: u32,
    // Window half-width: the window has 2·radius + 1 taps.
    radius: u32,
    has_previous: u32,
    weight_sum: f32,
    lambda_l1: f32,
    lambda_ssim: f32,
    lambda_temporal: f32,
    lambda_geo: f32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
    // The window's taps (at most 11), four to a vector.
    taps: array<vec4<f32>, 3>,
}

struct ReduceParams {
    // Items (pixels or partial sums) and quantities per item.
    count: u32,
    quantities: u32,
    // Where reduce_totals writes its sums in `totals`.
    first_total: u32,
    // Where the items start in `terms_in`, in floats.
    first_term: u32,
}

@group(0) @binding(0) var<uniform> tp: TrainParams;
@group(0) @binding(1) var<storage, read> pixels: array<f32>;
@group(0) @binding(2) var<storage, read> target_rgb: array<f32>;
@group(0) @binding(3) var<storage, read> weights: array<f32>;
@group(0) @binding(4) var<storage, read> target_depth: array<f32>;
@group(0) @binding(5) var<storage, read> previous_rgb: array<f32>;
// Row-filtered moments (15 per pixel), later the column adjoints (9 per pixel).
@group(0) @binding(6) var<storage, read_write> rows: array<f32>;
// Upstream gradient times dS/dμ1, dS/dE[x²], dS/dE[xy], per channel (9 per pixel).
@group(0) @binding(7) var<storage, read_write> coeffs: array<f32>;
// Per-pixel summands of sums A (TERMS_A per pixel) and B (TERMS_B per pixel).
@group(0) @binding(8) var<storage, read_write> terms: array<f32>;
@group(0) @binding(9) var<storage, read_write> partials: array<f32>;
@group(0) @binding(10) var<storage, read_write> totals: array<f32>;
@group(0) @binding(11) var<storage, read_write> v_pixels: array<f32>;
@group(0) @binding(12) var<storage, read_write> loss_out: array<f32>;
@group(0) @binding(13) var<uniform> reduction: ReduceParams;
@group(0) @binding(14) var<storage, read> terms_in: array<f32>;

const PIXEL_CHANNELS: u32 = 5u;
const C1: f32 = 0.0001;
const C2: f32 = 0.0009;
const SSIM_EPS: f32 = 1e-12;
const MIN_WEIGHT_SUM: f32 = 1e-6;
const MIN_ALPHA_FOR_DEPTH: f32 = 1e-6;
const COVERED_ALPHA: f32 = 0.5;
const MIN_COVERED: f32 = 16.0;
const MIN_VARIANCE_PRODUCT: f32 = 1e-12;

// Sums A (totals[0..6]): Σ w·mean|x − t|, Σ w·mean SSIM, Σ w·mean|x − prev|, Σ c, Σ c·a, Σ c·b
// (c = covered weight, a = rendered depth, b = Θ's depth).
const TERMS_A: u32 = 6u;
// Sums B (totals[8..13]), with w = c / Σc: Σ w·da·db, Σ w·da², Σ w·db², Σ w·da, Σ w·db.
const TERMS_B: u32 = 5u;
const TOTALS_B: u32 = 8u;

const GROUP: u32 = 256u;
var<workgroup> scratch: array<f32, 256>;

fn pixel_index(wid: vec3<u32>, nwg: vec3<u32>, lid: u32) -> u32 {
    return linear_workgroup(wid, nwg) * GROUP + lid;
}

fn pixel_count() -> u32 {
    return tp.width * tp.height;
}

fn tap(t: u32) -> f32 {
    return tp.taps[t / 4u][t % 4u];
}

// torch's 'reflect' padding: −1 → 1, n → n − 2.
fn reflect(i: i32, n: i32) -> u32 {
    var j = i;
    if j < 0 {
        j = -j;
    }
    if j >= n {
        j = 2 * (n - 1) - j;
    }
    return u32(j);
}

fn rendered_rgb(p: u32) -> vec3<f32> {
    return vec3<f32>(pixels[p * PIXEL_CHANNELS], pixels[p * PIXEL_CHANNELS + 1u],
                     pixels[p * PIXEL_CHANNELS + 2u]);
}

fn target_at(p: u32) -> vec3<f32> {
    return vec3<f32>(target_rgb[3u * p], target_rgb[3u * p + 1u], target_rgb[3u * p + 2u]);
}

fn previous_at(p: u32) -> vec3<f32> {
    return vec3<f32>(previous_rgb[3u * p], previous_rgb[3u * p + 1u], previous_rgb[3u * p + 2u]);
}

// Expected depth D / alpha where something was drawn, else 0 (pano4d.render).
fn rendered_depth(p: u32) -> f32 {
    let alpha = pixels[p * PIXEL_CHANNELS + 3u];
    if alpha > MIN_ALPHA_FOR_DEPTH {
        return pixels[p * PIXEL_CHANNELS + 4u] / alpha;
    }
    return 0.0;
}

fn covered_weight(p: u32) -> f32 {
    return select(0.0, weights[p], pixels[p * PIXEL_CHANNELS + 3u] > COVERED_ALPHA);
}

fn mean3(v: vec3<f32>) -> f32 {
    return (v.x + v.y + v.z) / 3.0;
}

// Per-pixel summands of sums A except the SSIM one (written by ssim_columns).
@compute @workgroup_size(256)
fn pixel_terms(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) lid: u32) {
    let p = pixel_index(wid, nwg, lid);
    if p >= pixel_count() {
        return;
    }
    let w = weights[p];
    let x = rendered_rgb(p);
    terms[p * TERMS_A] = w * mean3(abs(x - target_at(p)));
    var temporal = 0.0;
    if tp.has_previous != 0u {
        temporal = w * mean3(abs(x - previous_at(p)));
    }
    terms[p * TERMS_A + 2u] = temporal;
    let c = covered_weight(p);
    terms[p * TERMS_A + 3u] = c;
    terms[p * TERMS_A + 4u] = c * rendered_depth(p);
    terms[p * TERMS_A + 5u] = c * target_depth[p];
}

// Row pass of the window over x, t, x², t², x·t per channel (kornia filters x first).
@compute @workgroup_size(256)
fn ssim_rows(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
             @builtin(local_invocation_index) lid: u32) {
    let p = pixel_index(wid, nwg, lid);
    if p >= pixel_count() {
        return;
    }
    let w = i32(tp.width);
    let x0 = i32(p % tp.width);
    let row = p - p % tp.width;
    let r = i32(tp.radius);
    var acc: array<vec3<f32>, 5>;
    for (var t = -r; t <= r; t++) {
        let q = row + reflect(x0 + t, w);
        let k = tap(u32(t + r));
        let x = rendered_rgb(q);
        let y = target_at(q);
        acc[0] += k * x;
        acc[1] += k * y;
        acc[2] += k * (x * x);
        acc[3] += k * (y * y);
        acc[4] += k * (x * y);
    }
    for (var c = 0u; c < 3u; c++) {
        for (var j = 0u; j < 5u; j++) {
            rows[p * 15u + c * 5u + j] = acc[j][c];
        }
    }
}

// Column pass, the SSIM map, its summand of sums A, and the coefficients of its gradient.
@compute @workgroup_size(256)
fn ssim_columns(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) lid: u32) {
    let p = pixel_index(wid, nwg, lid);
    if p >= pixel_count() {
        return;
    }
    let x0 = p % tp.width;
    let y0 = i32(p / tp.width);
    let r = i32(tp.radius);
    var m: array<f32, 15>;
    for (var t = -r; t <= r; t++) {
        let q = reflect(y0 + t, i32(tp.height)) * tp.width + x0;
        let k = tap(u32(t + r));
        for (var j = 0u; j < 15u; j++) {
            m[j] += k * rows[q * 15u + j];
        }
    }
    // dL/dS for each channel's SSIM: the map is averaged over channels, weighted, normalised.
    let upstream = -tp.lambda_ssim / tp.weight_sum * weights[p] / 3.0;
    var ssim_sum = 0.0;
    for (var c = 0u; c < 3u; c++) {
        let mu1 = m[c * 5u];
        let mu2 = m[c * 5u + 1u];
        let mu1_sq = mu1 * mu1;
        let mu2_sq = mu2 * mu2;
        let mu1_mu2 = mu1 * mu2;
        let sigma1_sq = m[c * 5u + 2u] - mu1_sq;
        let sigma2_sq = m[c * 5u + 3u] - mu2_sq;
        let sigma12 = m[c * 5u + 4u] - mu1_mu2;
        let a1 = 2.0 * mu1_mu2 + C1;
        let a2 = 2.0 * sigma12 + C2;
        let b1 = mu1_sq + mu2_sq + C1;
        let b2 = sigma1_sq + sigma2_sq + C2;
        let den = b1 * b2 + SSIM_EPS;
        let s = (a1 * a2) / den;
        ssim_sum += s;
        // S = A1 A2 / (B1 B2 + eps) with A1 = 2μ1μ2 + C1, A2 = 2(E[xy] − μ1μ2) + C2,
        // B1 = μ1² + μ2² + C1, B2 = E[x²] − μ1² + E[y²] − μ2² + C2.
        let d_mu1 = (2.0 * mu2 * (a2 - a1) + 2.0 * mu1 * s * (b1 - b2)) / den;
        let d_exx = -s * b1 / den;
        let d_exy = 2.0 * a1 / den;
        coeffs[p * 9u + c * 3u] = upstream * d_mu1;
        coeffs[p * 9u + c * 3u + 1u] = upstream * d_exx;
        coeffs[p * 9u + c * 3u + 2u] = upstream * d_exy;
    }
    terms[p * TERMS_A + 1u] = weights[p] * (ssim_sum / 3.0);
}

// Adjoint of a reflect-padded window pass along an axis of length n: input index i received
// the taps of every output o that read it, directly (index i) or through a mirror (index −i
// for i ≥ 1, 2(n − 1) − i for i ≤ n − 2, both only within the padding). Mirror s of i:
const NO_MIRROR: i32 = 2147483647;

fn mirror(s: u32, i: i32, n: i32) -> i32 {
    switch s {
        case 0u: {
            return i;
        }
        case 1u: {
            return select(NO_MIRROR, -i, i >= 1);
        }
        default: {
            return select(NO_MIRROR, 2 * (n - 1) - i, i <= n - 2);
        }
    }
}

// Σ over outputs o reading (unreflected) index j of tap(j − o + r) · src[o], 9 values per
// item, items along the axis `stride` apart from `first`. Mirrors outside the padding
// (|j − o| > r for every o) add nothing.
fn adjoint_sum(j: i32, n: i32, first: u32, stride: u32, src_is_rows: bool) -> array<f32, 9> {
    var acc: array<f32, 9>;
    let r = i32(tp.radius);
    let lo = max(j - r, 0);
    let hi = min(j + r, n - 1);
    for (var o = lo; o <= hi; o++) {
        let k = tap(u32(j - o + r));
        let q = first + u32(o) * stride;
        for (var c = 0u; c < 9u; c++) {
            if src_is_rows {
                acc[c] += k * rows[q * 9u + c];
            } else {
                acc[c] += k * coeffs[q * 9u + c];
            }
        }
    }
    return acc;
}

// Column adjoint of the 9 coefficient maps, into `rows`.
@compute @workgroup_size(256)
fn ssim_adjoint_columns(@builtin(workgroup_id) wid: vec3<u32>,
                        @builtin(num_workgroups) nwg: vec3<u32>,
                        @builtin(local_invocation_index) lid: u32) {
    let p = pixel_index(wid, nwg, lid);
    if p >= pixel_count() {
        return;
    }
    let i = i32(p / tp.width);
    let n = i32(tp.height);
    var acc: array<f32, 9>;
    for (var s = 0u; s < 3u; s++) {
        let j = mirror(s, i, n);
        if j == NO_MIRROR {
            continue;
        }
        let part = adjoint_sum(j, n, p % tp.width, tp.width, false);
        for (var c = 0u; c < 9u; c++) {
            acc[c] += part[c];
        }
    }
    for (var c = 0u; c < 9u; c++) {
        rows[p * 9u + c] = acc[c];
    }
}

// Per-pixel summands of sums B: the weighted moments of the centred depths.
@compute @workgroup_size(256)
fn pearson_terms(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) lid: u32) {
    let p = pixel_index(wid, nwg, lid);
    if p >= pixel_count() {
        return;
    }
    let covered = max(totals[3], MIN_WEIGHT_SUM);
    let w = covered_weight(p) / covered;
    let da = rendered_depth(p) - totals[4] / covered;
    let db = target_depth[p] - totals[5] / covered;
    let base = pixel_count() * TERMS_A + p * TERMS_B;
    terms[base] = w * da * db;
    terms[base + 1u] = w * da * da;
    terms[base + 2u] = w * db * db;
    terms[base + 3u] = w * da;
    terms[base + 4u] = w * db;
}

// Tree sums of `count` items of `quantities` values over each workgroup's 256 items (first
// level), then over the workgroups' partial sums (reduce_totals, one workgroup).
@compute @workgroup_size(256)
fn reduce_partials(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                   @builtin(local_invocation_index) lid: u32) {
    let group = linear_workgroup(wid, nwg);
    let item = group * GROUP + lid;
    for (var q = 0u; q < reduction.quantities; q++) {
        var v = 0.0;
        if item < reduction.count {
            v = terms_in[reduction.first_term + item * reduction.quantities + q];
        }
        let total = workgroup_sum(v, lid);
        if lid == 0u {
            partials[group * reduction.quantities + q] = total;
        }
    }
}

@compute @workgroup_size(256)
fn reduce_totals(@builtin(local_invocation_index) lid: u32) {
    let groups = (reduction.count + GROUP - 1u) / GROUP;
    for (var q = 0u; q < reduction.quantities; q++) {
        var v = 0.0;
        for (var g = lid; g < groups; g += GROUP) {
            v += partials[g * reduction.quantities + q];
        }
        let total = workgroup_sum(v, lid);
        if lid == 0u {
            totals[reduction.first_total + q] = total;
        }
    }
}

fn workgroup_sum(v: f32, lid: u32) -> f32 {
    scratch[lid] = v;
    workgroupBarrier();
    for (var half = GROUP / 2u; half > 0u; half /= 2u) {
        if lid < half {
            scratch[lid] += scratch[lid + half];
        }
        workgroupBarrier();
    }
    let total = scratch[0];
    workgroupBarrier();
    return total;
}

// Whether L_geo applies this step (the coverage rule of loss_at).
fn geo_active() -> bool {
    return tp.lambda_geo > 0.0 && totals[3] > MIN_COVERED;
}

// Gradient of 1 − Pearson w.r.t. the rendered depth at pixel p (autograd's, including the
// term through the weighted mean, which is zero in exact arithmetic).
fn pearson_grad(p: u32) -> f32 {
    let covered = max(totals[3], MIN_WEIGHT_SUM);
    let w = covered_weight(p) / covered;
    let da = rendered_depth(p) - totals[4] / covered;
    let db = target_depth[p] - totals[5] / covered;
    let cov = totals[TOTALS_B];
    let va = totals[TOTALS_B + 1u];
    let vb = totals[TOTALS_B + 2u];
    let product = va * vb;
    if product >= MIN_VARIANCE_PRODUCT {
        let denom = sqrt(product);
        let ratio = cov / va;
        let sum_g = (-totals[TOTALS_B + 4u] + ratio * totals[TOTALS_B + 3u]) / denom;
        return w * (-db + ratio * da) / denom - w * sum_g;
    }
    // The variance product is clamped at 1e-12: only the covariance carries a gradient.
    let denom = sqrt(MIN_VARIANCE_PRODUCT);
    return -w * db / denom + w * totals[TOTALS_B + 4u] / denom;
}

// The gradient w.r.t. the forward's pixels: row adjoint of the SSIM coefficients, the L1
// and temporal signs, and L_geo through depth = D / alpha.
@compute @workgroup_size(256)
fn pixel_grads(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) lid: u32) {
    let p = pixel_index(wid, nwg, lid);
    if p >= pixel_count() {
        return;
    }
    let i = i32(p % tp.width);
    let n = i32(tp.width);
    var acc: array<f32, 9>;
    for (var s = 0u; s < 3u; s++) {
        let j = mirror(s, i, n);
        if j == NO_MIRROR {
            continue;
        }
        let part = adjoint_sum(j, n, p - p % tp.width, 1u, true);
        for (var c = 0u; c < 9u; c++) {
            acc[c] += part[c];
        }
    }
    let x = rendered_rgb(p);
    let t = target_at(p);
    let w = weights[p];
    let l1 = tp.lambda_l1 / tp.weight_sum * w / 3.0;
    var v_rgb = l1 * sign(x - t);
    if tp.has_previous != 0u {
        v_rgb += tp.lambda_temporal / tp.weight_sum * w / 3.0 * sign(x - previous_at(p));
    }
    for (var c = 0u; c < 3u; c++) {
        // x̄ = F̃ᵀ(ḡ ∂S/∂μ1) + 2x F̃ᵀ(ḡ ∂S/∂E[x²]) + t F̃ᵀ(ḡ ∂S/∂E[xt]).
        v_rgb[c] += acc[c * 3u] + 2.0 * x[c] * acc[c * 3u + 1u] + t[c] * acc[c * 3u + 2u];
    }
    var v_alpha = 0.0;
    var v_depth = 0.0;
    let alpha = pixels[p * PIXEL_CHANNELS + 3u];
    if geo_active() && alpha > MIN_ALPHA_FOR_DEPTH {
        let g = tp.lambda_geo * pearson_grad(p);
        v_depth = g / alpha;
        v_alpha = -g * pixels[p * PIXEL_CHANNELS + 4u] / (alpha * alpha);
    }
    let base = p * PIXEL_CHANNELS;
    v_pixels[base] = v_rgb.x;
    v_pixels[base + 1u] = v_rgb.y;
    v_pixels[base + 2u] = v_rgb.z;
    v_pixels[base + 3u] = v_alpha;
    v_pixels[base + 4u] = v_depth;
}

// The loss and its parts: [L, L1, 1 − SSIM, L_temporal, 1 − Pearson, covered weight,
// whether L_geo applied (1 or 0)].
@compute @workgroup_size(1)
fn loss_value() {
    let ws = tp.weight_sum;
    let l1 = totals[0] / ws;
    let ssim = 1.0 - totals[1] / ws;
    var loss = tp.lambda_l1 * l1 + tp.lambda_ssim * ssim;
    var temporal = 0.0;
    if tp.has_previous != 0u {
        temporal = totals[2] / ws;
        loss += tp.lambda_temporal * temporal;
    }
    var pearson = 0.0;
    let geo = geo_active();
    if geo {
        let cov = totals[TOTALS_B];
        let denom = sqrt(max(totals[TOTALS_B + 1u] * totals[TOTALS_B + 2u], MIN_VARIANCE_PRODUCT));
        pearson = 1.0 - cov / denom;
        loss += tp.lambda_geo * pearson;
    }
    loss_out[0] = loss;
    loss_out[1] = l1;
    loss_out[2] = ssim;
    loss_out[3] = temporal;
    loss_out[4] = pearson;
    loss_out[5] = totals[3];
    loss_out[6] = select(0.0, 1.0, geo);
}
