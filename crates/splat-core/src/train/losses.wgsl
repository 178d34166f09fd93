// The lifting phase's photometric and geometric losses and their gradient w.r.t. the
// forward's pixels (r, g, b, alpha, D = Σ z·α·T), for one view, on the device.
// The torch reference is `GaussianTrainer.loss_at` (python/pano4d/lift/torch_trainer.py):
//
//   L = λ_l1 L1 + λ_ssim (1 − SSIM) + λ_temporal L_temporal + λ_geo (1 − Pearson)
//
// (λ_l1 = 0.8 λ_rgb and λ_ssim = 0.2 λ_rgb in the lifting phase), every term weighted per
// pixel by the view's weight w and normalised by ws = max(Σ w, 1e-6) (computed by the host,
// as torch does). The pixels may be a window of the view (a dynamic step renders only what
// the moving region reaches): ws is then the whole view's, and the sums over the rest of the
// view come in LossParams (`outside_*`), so the loss, L_geo's statistics and the gradient
// are the whole view's. SSIM is kornia's `metrics.ssim`: a separable Gaussian window (σ = 1.5,
// 2r + 1 taps), rows first, then columns, each padded by reflection; C1 = 0.01²,
// C2 = 0.03², eps = 1e-12 in the denominator; pixels of weight 0 take no part (their
// target is the rendered value and they get no SSIM gradient, as `ssim_loss` detaches
// them): the windows reach across the mask's edge. Its gradient runs the adjoint passes in the
// opposite order (columns, then rows); near a border the adjoint also collects the taps
// that read a pixel through its mirror image. L_geo compares the expected depth D / alpha
// with Θ's depth over the covered pixels (weight · [alpha > 0.5]) and applies only when
// their weight sums to more than 16.
//
// Passes (train/losses.rs): ssim_rows; ssim_columns (also every per-pixel summand of sums
// A, summed per workgroup); totals_a; pearson_terms (sums B per workgroup); totals_b;
// adjoint_columns; pixel_grads; loss_value. Sums are fixed trees (no atomics), so a step
// is deterministic. After common.wgsl (`linear_workgroup`).

// Rust: train/losses.rs's `LossParams` (the one declaration; the wgsl tests check this one
// against it).
struct LossParams {
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
    // The sums over the pixels of the view outside the rendered window (all 0 when the
    // window is the whole view): Σ w·mean|x − t|, Σ w·mean SSIM, Σ w·mean|x − prev| (SSIM's
    // as the window's own computation misses them), then L_geo's covered weight, the means
    // of the rendered and of Θ's depth over it and the centred sums Σ c·da², Σ c·db²,
    // Σ c·da·db about those means (lift/windows.py computes them; train/losses.rs).
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
    // The window's taps (at most 11), four to a vector.
    taps: array<vec4<f32>, 3>,
}

@group(0) @binding(0) var<uniform> lp: LossParams;
@group(0) @binding(1) var<storage, read> pixels: array<f32>;
@group(0) @binding(2) var<storage, read> target_rgb: array<f32>;
@group(0) @binding(3) var<storage, read> weights: array<f32>;
@group(0) @binding(4) var<storage, read> target_depth: array<f32>;
@group(0) @binding(5) var<storage, read> previous_rgb: array<f32>;
// Row-filtered x, t, x², t², x·t (MOMENTS per pixel; rgb in xyz).
@group(0) @binding(6) var<storage, read_write> moments: array<vec4<f32>>;
// Upstream gradient times dS/dμx, dS/dE[x²], dS/dE[xt] (COEFFS per pixel), then their
// column adjoints (in `adjoint`).
@group(0) @binding(7) var<storage, read_write> coeffs: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> adjoint: array<vec4<f32>>;
// Per-workgroup partial sums, 8 per workgroup.
@group(0) @binding(9) var<storage, read_write> partials: array<f32>;
// Sums A in [0, 8), sums B in [8, 16).
@group(0) @binding(10) var<storage, read_write> totals: array<f32>;
@group(0) @binding(11) var<storage, read_write> v_pixels: array<f32>;
@group(0) @binding(12) var<storage, read_write> loss_out: array<f32>;

const PIXEL_CHANNELS: u32 = 5u;
const MOMENTS: u32 = 5u;
const COEFFS: u32 = 3u;
const C1: f32 = 0.0001;
const C2: f32 = 0.0009;
const SSIM_EPS: f32 = 1e-12;
const MIN_WEIGHT_SUM: f32 = 1e-6;
const MIN_ALPHA_FOR_DEPTH: f32 = 1e-6;
const COVERED_ALPHA: f32 = 0.5;
const MIN_COVERED: f32 = 16.0;
const MIN_VARIANCE_PRODUCT: f32 = 1e-12;

// Sums A: Σ w·mean|x − t|, Σ w·mean SSIM, Σ w·mean|x − prev|, Σ c, Σ c·a, Σ c·b
// (c = covered weight, a = rendered depth, b = Θ's depth).
const SUM_L1: u32 = 0u;
const SUM_SSIM: u32 = 1u;
const SUM_TEMPORAL: u32 = 2u;
const SUM_COVERED: u32 = 3u;
const SUM_COVERED_A: u32 = 4u;
const SUM_COVERED_B: u32 = 5u;
// Sums B, with w = c / Σc: Σ w·da·db, Σ w·da², Σ w·db², Σ w·da, Σ w·db.
const SUM_COV: u32 = 8u;
const SUM_VAR_A: u32 = 9u;
const SUM_VAR_B: u32 = 10u;
const SUM_DA: u32 = 11u;
const SUM_DB: u32 = 12u;

const GROUP: u32 = 256u;
const PIXELS_PER_INVOCATION: u32 = 8u;
// Eight sums per invocation, as two vectors.
var<workgroup> scratch: array<array<vec4<f32>, 2>, 256>;

fn pixel_count() -> u32 {
    return lp.width * lp.height;
}

fn tap(t: i32) -> f32 {
    return lp.taps[u32(t) / 4u][u32(t) % 4u];
}

// torch's 'reflect' padding: −1 → 1, n → n − 2.
fn reflect(i: i32, n: i32) -> u32 {
    var j = abs(i);
    if j >= n {
        j = 2 * (n - 1) - j;
    }
    return u32(j);
}

// PIXELS_PER_INVOCATION consecutive pixels of a row or a column: each invocation of the
// window passes takes one, so that it reads each pixel its windows need once (count + 2r
// reads, not count·(2r + 1): on a CPU adapter the passes' time is their reads) and adds a
// window's taps in the order of its pixels, as one window at a time would.
struct Run {
    // The pixel index of the row's (column's) item 0; items are 1 (width) pixels apart.
    start: u32,
    // The run's first item and its number of items (0: this invocation has no run).
    first: i32,
    count: i32,
}

// Run `index` of the rows, each row split into runs from its left.
fn row_run(index: u32) -> Run {
    let per_row = (lp.width + PIXELS_PER_INVOCATION - 1u) / PIXELS_PER_INVOCATION;
    let y = index / per_row;
    let first = index % per_row * PIXELS_PER_INVOCATION;
    if y >= lp.height {
        return Run(0u, 0, 0);
    }
    return Run(y * lp.width, i32(first), i32(min(PIXELS_PER_INVOCATION, lp.width - first)));
}

// Run `index` of the columns: neighbouring invocations take neighbouring columns.
fn column_run(index: u32) -> Run {
    let first = index / lp.width * PIXELS_PER_INVOCATION;
    if first >= lp.height {
        return Run(0u, 0, 0);
    }
    return Run(index % lp.width, i32(first),
               i32(min(PIXELS_PER_INVOCATION, lp.height - first)));
}

// x, t, x², t², x·t (rgb each) of a pixel, or their sums over its window.
struct Moments {
    x: vec3<f32>,
    t: vec3<f32>,
    xx: vec3<f32>,
    tt: vec3<f32>,
    xt: vec3<f32>,
}

// Adds item j's moments `v` to the window sums of the run's items whose window reads j,
// each with its tap (the two window passes' accumulation).
fn add_to_windows(sums: ptr<function, array<Moments, PIXELS_PER_INVOCATION>>, run: Run, j: i32,
                  v: Moments) {
    let r = i32(lp.radius);
    for (var o = max(0, j - r - run.first); o <= min(run.count - 1, j + r - run.first); o++) {
        let k = tap(j - run.first - o + r);
        (*sums)[o].x += k * v.x;
        (*sums)[o].t += k * v.t;
        (*sums)[o].xx += k * v.xx;
        (*sums)[o].tt += k * v.tt;
        (*sums)[o].xt += k * v.xt;
    }
}

fn rendered_rgb(p: u32) -> vec3<f32> {
    let b = p * PIXEL_CHANNELS;
    return vec3<f32>(pixels[b], pixels[b + 1u], pixels[b + 2u]);
}

fn target_at(p: u32) -> vec3<f32> {
    return vec3<f32>(target_rgb[3u * p], target_rgb[3u * p + 1u], target_rgb[3u * p + 2u]);
}

// The target SSIM's windows read: the rendered value where the weight is 0.
fn ssim_target(p: u32) -> vec3<f32> {
    return select(target_at(p), rendered_rgb(p), weights[p] <= 0.0);
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

// Sums (lo, hi) over the workgroup; every invocation must call it.
fn workgroup_sums(lo: vec4<f32>, hi: vec4<f32>, lid: u32) -> array<vec4<f32>, 2> {
    scratch[lid][0] = lo;
    scratch[lid][1] = hi;
    workgroupBarrier();
    for (var half = GROUP / 2u; half > 0u; half /= 2u) {
        if lid < half {
            scratch[lid][0] += scratch[lid + half][0];
            scratch[lid][1] += scratch[lid + half][1];
        }
        workgroupBarrier();
    }
    return scratch[0];
}

fn write_partials(group: u32, sums: array<vec4<f32>, 2>, lid: u32) {
    if lid == 0u {
        for (var q = 0u; q < 4u; q++) {
            partials[8u * group + q] = sums[0][q];
            partials[8u * group + 4u + q] = sums[1][q];
        }
    }
}

// One workgroup: the sum of every workgroup's partials, into totals[first..first + 8].
fn total_partials(first: u32, lid: u32) {
    // The column runs' workgroups (ssim_columns; pearson_terms has as many).
    let runs = lp.width * ((lp.height + PIXELS_PER_INVOCATION - 1u) / PIXELS_PER_INVOCATION);
    let groups = (runs + GROUP - 1u) / GROUP;
    var lo = vec4<f32>(0.0);
    var hi = vec4<f32>(0.0);
    for (var g = lid; g < groups; g += GROUP) {
        lo += vec4<f32>(partials[8u * g], partials[8u * g + 1u], partials[8u * g + 2u],
                        partials[8u * g + 3u]);
        hi += vec4<f32>(partials[8u * g + 4u], partials[8u * g + 5u], partials[8u * g + 6u],
                        partials[8u * g + 7u]);
    }
    let sums = workgroup_sums(lo, hi, lid);
    if lid == 0u {
        for (var q = 0u; q < 4u; q++) {
            totals[first + q] = sums[0][q];
            totals[first + 4u + q] = sums[1][q];
        }
    }
}

// Row pass of the window over x, t, x², t², x·t (kornia filters along x first), a row run
// of PIXELS_PER_INVOCATION pixels per invocation (`row_run`).
@compute @workgroup_size(256)
fn ssim_rows(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
             @builtin(local_invocation_index) lid: u32) {
    let run = row_run(linear_workgroup(wid, nwg) * GROUP + lid);
    if run.count == 0 {
        return;
    }
    let w = i32(lp.width);
    let r = i32(lp.radius);
    var sums: array<Moments, PIXELS_PER_INVOCATION>;
    for (var j = run.first - r; j < run.first + run.count + r; j++) {
        let q = run.start + reflect(j, w);
        let x = rendered_rgb(q);
        let y = ssim_target(q);
        add_to_windows(&sums, run, j, Moments(x, y, x * x, y * y, x * y));
    }
    for (var o = 0; o < run.count; o++) {
        let base = (run.start + u32(run.first + o)) * MOMENTS;
        moments[base] = vec4<f32>(sums[o].x, 0.0);
        moments[base + 1u] = vec4<f32>(sums[o].t, 0.0);
        moments[base + 2u] = vec4<f32>(sums[o].xx, 0.0);
        moments[base + 3u] = vec4<f32>(sums[o].tt, 0.0);
        moments[base + 4u] = vec4<f32>(sums[o].xt, 0.0);
    }
}

// The SSIM map and its gradient coefficients at pixel p from its window sums `m` (the
// column pass of the row-filtered x, t, x², t², x·t); returns p's summands of sums A.
fn ssim_at(p: u32, m: Moments) -> array<vec4<f32>, 2> {
    let mu1 = m.x;
    let mu2 = m.t;
    let exx = m.xx;
    let ett = m.tt;
    let ext = m.xt;
    // S = A1 A2 / (B1 B2 + eps) per channel: A1 = 2μxμt + C1, A2 = 2(E[xt] − μxμt) + C2,
    // B1 = μx² + μt² + C1, B2 = E[x²] − μx² + E[t²] − μt² + C2.
    let mu1_sq = mu1 * mu1;
    let mu2_sq = mu2 * mu2;
    let mu1_mu2 = mu1 * mu2;
    let a1 = 2.0 * mu1_mu2 + C1;
    let a2 = 2.0 * (ext - mu1_mu2) + C2;
    let b1 = mu1_sq + mu2_sq + C1;
    let b2 = (exx - mu1_sq) + (ett - mu2_sq) + C2;
    let den = b1 * b2 + SSIM_EPS;
    let s = (a1 * a2) / den;
    // dL/dS of each channel: the map is averaged over channels, weighted, normalised.
    let w = weights[p];
    let upstream = -lp.lambda_ssim / lp.weight_sum * w / 3.0;
    let base = p * COEFFS;
    coeffs[base] = vec4<f32>(upstream * (2.0 * mu2 * (a2 - a1) + 2.0 * mu1 * s * (b1 - b2))
                             / den, 0.0);
    coeffs[base + 1u] = vec4<f32>(upstream * (-s * b1 / den), 0.0);
    coeffs[base + 2u] = vec4<f32>(upstream * (2.0 * a1 / den), 0.0);

    let x = rendered_rgb(p);
    var temporal = 0.0;
    if lp.has_previous != 0u {
        temporal = w * mean3(abs(x - previous_at(p)));
    }
    let c = covered_weight(p);
    return array<vec4<f32>, 2>(
        vec4<f32>(w * mean3(abs(x - target_at(p))), w * mean3(s), temporal, c),
        vec4<f32>(c * rendered_depth(p), c * target_depth[p], 0.0, 0.0),
    );
}

// Column pass, a column run per invocation (`column_run`); its pixels' summands of sums A
// are summed per workgroup.
@compute @workgroup_size(256)
fn ssim_columns(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) lid: u32) {
    let group = linear_workgroup(wid, nwg);
    let run = column_run(group * GROUP + lid);
    let h = i32(lp.height);
    let r = i32(lp.radius);
    var sums: array<Moments, PIXELS_PER_INVOCATION>;
    for (var j = run.first - r; run.count > 0 && j < run.first + run.count + r; j++) {
        let q = (run.start + reflect(j, h) * lp.width) * MOMENTS;
        let row = Moments(moments[q].xyz, moments[q + 1u].xyz, moments[q + 2u].xyz,
                          moments[q + 3u].xyz, moments[q + 4u].xyz);
        add_to_windows(&sums, run, j, row);
    }
    var lo = vec4<f32>(0.0);
    var hi = vec4<f32>(0.0);
    for (var o = 0; o < run.count; o++) {
        let p = run.start + u32(run.first + o) * lp.width;
        let terms = ssim_at(p, sums[o]);
        lo += terms[0];
        hi += terms[1];
    }
    write_partials(group, workgroup_sums(lo, hi, lid), lid);
}

@compute @workgroup_size(256)
fn totals_a(@builtin(local_invocation_index) lid: u32) {
    total_partials(0u, lid);
    if lid == 0u {
        totals[SUM_L1] += lp.outside_l1;
        totals[SUM_SSIM] += lp.outside_ssim;
        totals[SUM_TEMPORAL] += lp.outside_temporal;
        totals[SUM_COVERED] += lp.outside_covered;
        totals[SUM_COVERED_A] += lp.outside_covered * lp.outside_mean_a;
        totals[SUM_COVERED_B] += lp.outside_covered * lp.outside_mean_b;
    }
}

// The weighted moments of the centred depths (sums B) per workgroup, PIXELS_PER_INVOCATION
// pixels per invocation (as many workgroups as the column runs'): few workgroups pay for
// the tree's barriers, costly on CPU adapters.
@compute @workgroup_size(256)
fn pearson_terms(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) lid: u32) {
    let group = linear_workgroup(wid, nwg);
    let covered = max(totals[SUM_COVERED], MIN_WEIGHT_SUM);
    let mean_a = totals[SUM_COVERED_A] / covered;
    let mean_b = totals[SUM_COVERED_B] / covered;
    var lo = vec4<f32>(0.0);
    var hi = vec4<f32>(0.0);
    for (var k = 0u; k < PIXELS_PER_INVOCATION; k++) {
        let p = (group * PIXELS_PER_INVOCATION + k) * GROUP + lid;
        if p < pixel_count() {
            let w = covered_weight(p) / covered;
            let da = rendered_depth(p) - mean_a;
            let db = target_depth[p] - mean_b;
            lo += vec4<f32>(w * da * db, w * da * da, w * db * db, w * da);
            hi += vec4<f32>(w * db, 0.0, 0.0, 0.0);
        }
    }
    write_partials(group, workgroup_sums(lo, hi, lid), lid);
}

@compute @workgroup_size(256)
fn totals_b(@builtin(local_invocation_index) lid: u32) {
    total_partials(SUM_COV, lid);
    if lid == 0u {
        // The outside pixels' share, from their centred sums moved to the view's means.
        let covered = max(totals[SUM_COVERED], MIN_WEIGHT_SUM);
        let ea = lp.outside_mean_a - totals[SUM_COVERED_A] / covered;
        let eb = lp.outside_mean_b - totals[SUM_COVERED_B] / covered;
        let c = lp.outside_covered;
        totals[SUM_COV] += (lp.outside_cov + c * ea * eb) / covered;
        totals[SUM_VAR_A] += (lp.outside_var_a + c * ea * ea) / covered;
        totals[SUM_VAR_B] += (lp.outside_var_b + c * eb * eb) / covered;
        totals[SUM_DA] += c * ea / covered;
        totals[SUM_DB] += c * eb / covered;
    }
}

// The three coefficient vectors, summed with the window's taps.
struct Adjoint {
    mu: vec3<f32>,
    exx: vec3<f32>,
    ext: vec3<f32>,
}

// The three coefficient vectors of item q: the SSIM coefficients for the column adjoint,
// their column adjoints for the row adjoint.
fn coefficients(q: u32, columns: bool) -> Adjoint {
    let b = q * COEFFS;
    if columns {
        return Adjoint(coeffs[b].xyz, coeffs[b + 1u].xyz, coeffs[b + 2u].xyz);
    }
    return Adjoint(adjoint[b].xyz, adjoint[b + 1u].xyz, adjoint[b + 2u].xyz);
}

// Adjoint of a reflect-padded window pass along an axis of n items (`stride` apart from
// `run.start`), at each item i of `run`: Σ tap · coefficients(o) over the outputs o whose
// window read i, directly or, near a border, through its mirror image. Those outputs lie
// within r of the run (a mirror image is read only within r of the border, where i is),
// and each is read once.
fn window_adjoints(run: Run, n: i32, stride: u32, columns: bool)
        -> array<Adjoint, PIXELS_PER_INVOCATION> {
    let r = i32(lp.radius);
    var a: array<Adjoint, PIXELS_PER_INVOCATION>;
    let last = min(run.first + run.count - 1 + r, n - 1);
    for (var o = max(run.first - r, 0); run.count > 0 && o <= last; o++) {
        let c = coefficients(run.start + u32(o) * stride, columns);
        for (var t = -r; t <= r; t++) {
            let i = i32(reflect(o + t, n)) - run.first;
            if i >= 0 && i < run.count {
                let k = tap(t + r);
                a[i].mu += k * c.mu;
                a[i].exx += k * c.exx;
                a[i].ext += k * c.ext;
            }
        }
    }
    return a;
}

// Column adjoint of the SSIM coefficients, a column run per invocation.
@compute @workgroup_size(256)
fn adjoint_columns(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                   @builtin(local_invocation_index) lid: u32) {
    let run = column_run(linear_workgroup(wid, nwg) * GROUP + lid);
    let a = window_adjoints(run, i32(lp.height), lp.width, true);
    for (var o = 0; o < run.count; o++) {
        let base = (run.start + u32(run.first + o) * lp.width) * COEFFS;
        adjoint[base] = vec4<f32>(a[o].mu, 0.0);
        adjoint[base + 1u] = vec4<f32>(a[o].exx, 0.0);
        adjoint[base + 2u] = vec4<f32>(a[o].ext, 0.0);
    }
}

// Whether L_geo applies this step (the coverage rule of loss_at).
fn geo_active() -> bool {
    return lp.lambda_geo > 0.0 && totals[SUM_COVERED] > MIN_COVERED;
}

// Gradient of 1 − Pearson w.r.t. the rendered depth at pixel p (autograd's, including the
// term through the weighted mean, which is zero in exact arithmetic).
fn pearson_grad(p: u32) -> f32 {
    let covered = max(totals[SUM_COVERED], MIN_WEIGHT_SUM);
    let w = covered_weight(p) / covered;
    let da = rendered_depth(p) - totals[SUM_COVERED_A] / covered;
    let db = target_depth[p] - totals[SUM_COVERED_B] / covered;
    let cov = totals[SUM_COV];
    let va = totals[SUM_VAR_A];
    let product = va * totals[SUM_VAR_B];
    if product >= MIN_VARIANCE_PRODUCT {
        let denom = sqrt(product);
        let ratio = cov / va;
        let sum_g = (-totals[SUM_DB] + ratio * totals[SUM_DA]) / denom;
        return w * (-db + ratio * da) / denom - w * sum_g;
    }
    // The variance product is clamped at 1e-12: only the covariance carries a gradient.
    let denom = sqrt(MIN_VARIANCE_PRODUCT);
    return -w * db / denom + w * totals[SUM_DB] / denom;
}

// The gradient w.r.t. the forward's pixels, a row run per invocation: the row adjoint of
// the SSIM coefficients, the L1 and temporal signs, and L_geo through depth = D / alpha.
@compute @workgroup_size(256)
fn pixel_grads(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) lid: u32) {
    let run = row_run(linear_workgroup(wid, nwg) * GROUP + lid);
    let a = window_adjoints(run, i32(lp.width), 1u, false);
    for (var o = 0; o < run.count; o++) {
        pixel_gradient(run.start + u32(run.first + o), a[o]);
    }
}

// Pixel p's gradient, given the row adjoint `a` of its SSIM coefficients.
fn pixel_gradient(p: u32, a: Adjoint) {
    let x = rendered_rgb(p);
    let t = target_at(p);
    let w = weights[p];
    // x̄ = F̃ᵀ(ḡ ∂S/∂μx) + 2x F̃ᵀ(ḡ ∂S/∂E[x²]) + t F̃ᵀ(ḡ ∂S/∂E[xt]) where the weight is
    // not 0, then the L1 sign.
    var v_rgb = select(a.mu + 2.0 * x * a.exx + t * a.ext, vec3<f32>(0.0), w <= 0.0);
    v_rgb += lp.lambda_l1 / lp.weight_sum * w / 3.0 * sign(x - t);
    if lp.has_previous != 0u {
        v_rgb += lp.lambda_temporal / lp.weight_sum * w / 3.0 * sign(x - previous_at(p));
    }
    var v_alpha = 0.0;
    var v_depth = 0.0;
    let alpha = pixels[p * PIXEL_CHANNELS + 3u];
    if geo_active() && alpha > MIN_ALPHA_FOR_DEPTH {
        let g = lp.lambda_geo * pearson_grad(p);
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
    let ws = lp.weight_sum;
    let l1 = totals[SUM_L1] / ws;
    let ssim = 1.0 - totals[SUM_SSIM] / ws;
    var loss = lp.lambda_l1 * l1 + lp.lambda_ssim * ssim;
    var temporal = 0.0;
    if lp.has_previous != 0u {
        temporal = totals[SUM_TEMPORAL] / ws;
        loss += lp.lambda_temporal * temporal;
    }
    var pearson = 0.0;
    let geo = geo_active();
    if geo {
        let product = max(totals[SUM_VAR_A] * totals[SUM_VAR_B], MIN_VARIANCE_PRODUCT);
        pearson = 1.0 - totals[SUM_COV] / sqrt(product);
        loss += lp.lambda_geo * pearson;
    }
    loss_out[0] = loss;
    loss_out[1] = l1;
    loss_out[2] = ssim;
    loss_out[3] = temporal;
    loss_out[4] = pearson;
    loss_out[5] = totals[SUM_COVERED];
    loss_out[6] = select(0.0, 1.0, geo);
}
