// One Adam step of the trained Gaussians, in place on their parameters (not on the
// snapshot the rasteriser draws, which session.rs's evaluate pass makes from them), with the
// operations of torch.optim.Adam (single-tensor path, float32) for each element:
//
//   m ← lerp(m, g, 1 − β1)                  (fma(1 − β1, g − m, m), as torch's lerp)
//   v ← v·β2 + (1 − β2)·g·g                 (fma((1 − β2)·g, g, v·β2), as torch's addcmul)
//   p ← p + (−lr / (1 − β1ᵗ)) · m / (sqrt(v) / sqrt(1 − β2ᵗ) + eps)
//
// The host computes the bias corrections in f64 from the step count, as torch does, and
// passes them rounded to f32 (train/adam.rs). One learning rate per parameter group:
// means, log-scales, quaternions, opacity logits, SH DC, SH rest, and a spacetime set's
// colour terms, position terms, centre times and log-widths (`learning_rates()` in
// python/pano4d/lift/trainer.py).
//
// Means: the torch trainer optimises offsets o with mean = anchor + o·unit (unit = each
// Gaussian's initial distance from the centre). Its gradient is g_o = unit·g_mean, and
// Adam's step Δo moves the mean by unit·Δo. So Adam here runs on g_o (the moments are
// the torch trainer's moments of the offsets) and adds unit·Δo to the mean: the same
// update in exact arithmetic, without storing anchors and offsets. A spacetime set's
// position terms are optimised the same way, in the same unit. The accumulated
// densification statistic is torch's too: the norm of g_o across the ray from the origin
// (the training views' centre) to where the step drew the Gaussian (the screen-space part,
// as 3DGS's) and whether it is non-zero.
//
// The parameters and the moments hold the trained set alone, in SoA sections `n_train`
// long (a spacetime set's time sections after the Gaussians', time_layout.wgsl). The
// gradients are the backward's, of the whole scene drawn: the frozen static set first
// (`n_static` Gaussians, never updated), then the trained set's snapshot, whose gradient is
// the parameters' (the evaluate pass gives each parameter of the Gaussians its value with
// slope 1: a copy, or a spacetime set's value at the step's time); their sections are
// `grad_len` (= static set + trained) long (gaussian_layout.wgsl's `gaussian_offsets`
// places each; after common.wgsl for `linear_workgroup`). A spacetime set's time parameters
// take their gradient from the evaluate pass's adjoint (`time_grads`, evaluate.wgsl), and
// its log-widths are held at ≥ `min_log_width` after the update (torch's clamp_).

// Rust: train/adam.rs's `AdamParams` (the one declaration; the wgsl tests check this one
// against it).
struct AdamParams {
    n_static: u32,
    n_train: u32,
    grad_len: u32,
    sh_coeffs: u32,
    // 1 when `grads_extra` (a second render's gradients, the semantic loss) is added.
    has_extra: u32,
    // 1 for a spacetime set (its time sections and `tp` are there).
    timed: u32,
    pad0: u32,
    pad1: u32,
    beta1_complement: f32,
    beta2: f32,
    beta2_complement: f32,
    eps: f32,
    bias2_sqrt: f32,
    // ln(MIN_WIDTH_FRAMES) (crate::spacetime), the log-widths' floor.
    min_log_width: f32,
    pad2: f32,
    pad3: f32,
    // −lr / (1 − β1ᵗ) per group: means, log-scales, quats, opacity, SH DC, SH rest, colour
    // terms, position terms, centre times, log-widths.
    neg_step: array<vec4<f32>, 3>,
}

@group(0) @binding(0) var<uniform> ap: AdamParams;
// The trained set's parameters.
@group(0) @binding(1) var<storage, read_write> params: array<f32>;
@group(0) @binding(2) var<storage, read> grads: array<f32>;
@group(0) @binding(3) var<storage, read> grads_extra: array<f32>;
@group(0) @binding(4) var<storage, read_write> exp_avg: array<f32>;
@group(0) @binding(5) var<storage, read_write> exp_avg_sq: array<f32>;
@group(0) @binding(6) var<storage, read> unit: array<f32>;
// Accumulated ‖g_o‖ across the ray (first n_train) and count of non-zero ones (next n_train).
@group(0) @binding(7) var<storage, read_write> stats: array<f32>;
// A spacetime set's time parameters' gradient (the adjoint's) and the step's time.
@group(0) @binding(8) var<storage, read> time_grads: array<f32>;
@group(0) @binding(9) var<uniform> tp: TimeParams;

fn gradient(i: u32) -> f32 {
    if ap.has_extra != 0u {
        return grads[i] + grads_extra[i];
    }
    return grads[i];
}

// Updates the moments at `mi` with gradient g and returns the step for group `group`.
fn adam_step(mi: u32, g: f32, group: u32) -> f32 {
    let m = fma(ap.beta1_complement, g - exp_avg[mi], exp_avg[mi]);
    let v = fma(ap.beta2_complement * g, g, exp_avg_sq[mi] * ap.beta2);
    exp_avg[mi] = m;
    exp_avg_sq[mi] = v;
    let denom = sqrt(v) / ap.bias2_sqrt + ap.eps;
    return (ap.neg_step[group / 4u][group % 4u] * m) / denom;
}

// Parameters `count` wide starting at section offsets (gradient, parameter and moment) of
// one group.
fn update_plain(grad_at: u32, at: u32, count: u32, group: u32) {
    for (var c = 0u; c < count; c++) {
        params[at + c] += adam_step(at + c, gradient(grad_at + c), group);
    }
}

// A spacetime set's time parameters of Gaussian i (`u` its offset unit).
fn update_time(i: u32, u: f32) {
    let p = param_time_offsets();
    let g = time_offsets(0u, ap.n_train);
    params[p.centre + i] += adam_step(p.centre + i, time_grads[g.centre + i], 8u);
    let w = p.log_width + i;
    params[w] = max(params[w] + adam_step(w, time_grads[g.log_width + i], 9u), ap.min_log_width);
    let colour = 6u * tp.colour_harmonics;
    for (var c = 0u; c < colour; c++) {
        let at = p.colour + colour * i + c;
        params[at] += adam_step(at, time_grads[g.colour + colour * i + c], 6u);
    }
    let position = 6u * tp.position_harmonics;
    for (var c = 0u; c < position; c++) {
        let at = p.position + position * i + c;
        params[at] += adam_step(at, time_grads[g.position + position * i + c] * u, 7u) * u;
    }
}

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let i = linear_workgroup(wid, nwg) * 256u + lid;
    if i >= ap.n_train {
        return;
    }
    let gi = ap.n_static + i;
    let g = gaussian_offsets(ap.grad_len);
    // The parameters' and the moments' sections.
    let p = gaussian_offsets(ap.n_train);
    let k = ap.sh_coeffs;

    // Means, through the offsets (see the header). The densification statistic is the
    // gradient's part across the ray from the views' centre (the origin) to where the step
    // drew the Gaussian, before the update.
    let u = unit[i];
    let at = p.means + 3u * i;
    var ray = vec3<f32>(params[at], params[at + 1u], params[at + 2u]);
    if ap.timed != 0u {
        ray += mean_motion(i);
    }
    var g_offset = vec3<f32>(0.0);
    for (var c = 0u; c < 3u; c++) {
        g_offset[c] = gradient(g.means + 3u * gi + c) * u;
        params[at + c] += adam_step(at + c, g_offset[c], 0u) * u;
    }
    let along = select(vec3<f32>(0.0), normalize(ray), dot(ray, ray) > 0.0);
    let norm = length(g_offset - dot(g_offset, along) * along);
    stats[i] += norm;
    stats[ap.n_train + i] += select(0.0, 1.0, norm > 0.0);

    update_plain(g.log_scales + 3u * gi, p.log_scales + 3u * i, 3u, 1u);
    update_plain(g.quats + 4u * gi, p.quats + 4u * i, 4u, 2u);
    update_plain(g.opacity + gi, p.opacity + i, 1u, 3u);
    update_plain(g.sh + 3u * k * gi, p.sh + 3u * k * i, 3u, 4u);
    update_plain(g.sh + 3u * k * gi + 3u, p.sh + 3u * k * i + 3u, 3u * (k - 1u), 5u);
    if ap.timed != 0u {
        update_time(i, u);
    }
}
