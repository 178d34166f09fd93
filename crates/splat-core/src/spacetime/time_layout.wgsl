// A spacetime set's functions of time at the uniform's time (crate::spacetime; the
// reference is pano4d.spacetime's SpacetimeGaussians.at): where its time parameters lie
// and what they give at that time. Shared by the evaluate pass and its adjoint
// (evaluate.wgsl) and by the trainer's Adam (train/adam.wgsl, for the position the step
// drew a Gaussian at), each of which binds the set's parameters as `params` and this
// uniform as `tp`. "Trained" below names the evaluated set, as in a training session; the
// viewer's GpuSpacetimeSet fills the same fields for the set it plays.

// Rust: spacetime/evaluate.rs's `TimeParams` (the one declaration; the wgsl tests check
// this one against it).
struct TimeParams {
    // The frozen static set's and the trained set's counts: the snapshot of trained
    // Gaussian i is scene Gaussian n_static + i.
    n_static: u32,
    n_train: u32,
    // Section lengths: the scene's (its capacity) and the backward's gradient's
    // (n_static + n_train).
    scene_len: u32,
    grad_len: u32,
    sh_coeffs: u32,
    colour_harmonics: u32,
    position_harmonics: u32,
    // 1 when the adjoint adds `grads_extra` (a second render's gradients, the semantic loss).
    has_extra: u32,
    // Frames per loop, and the time drawn in frames (f32, as the torch form's arithmetic).
    period: f32,
    time: f32,
    pad0: f32,
    pad1: f32,
    // cos(h·u), sin(h·u) for h = 1.. (cos₁, sin₁, cos₂, …), u = 2π·time / period, computed
    // on the host in f64 as TimeModel.basis; four to a vector, up to 2·MAX_HARMONICS.
    colour_basis: array<vec4<f32>, 4>,
    position_basis: array<vec4<f32>, 4>,
}

// Where the time sections of n Gaussians start: after `start` floats (in the parameters,
// after the Gaussians' own sections, gaussian_layout.wgsl; in their gradient, at 0). Terms
// are (Gaussian, term, xyz or rgb), row-major.
struct TimeOffsets {
    centre: u32,
    log_width: u32,
    colour: u32,
    position: u32,
}

fn time_offsets(start: u32, n: u32) -> TimeOffsets {
    let colour = start + 2u * n;
    return TimeOffsets(start, start + n, colour, colour + 6u * tp.colour_harmonics * n);
}

// The time sections of the trained parameters.
fn param_time_offsets() -> TimeOffsets {
    return time_offsets(gaussian_offsets(tp.n_train).sh + 3u * tp.sh_coeffs * tp.n_train,
                        tp.n_train);
}

fn colour_basis(j: u32) -> f32 {
    return tp.colour_basis[j / 4u][j % 4u];
}

fn position_basis(j: u32) -> f32 {
    return tp.position_basis[j / 4u][j % 4u];
}

// Σⱼ position_basisⱼ · position_termsⱼ of Gaussian i: how far its mean is moved at `time`.
fn mean_motion(i: u32) -> vec3<f32> {
    let terms = 2u * tp.position_harmonics;
    let at = param_time_offsets().position + 3u * terms * i;
    var motion = vec3<f32>(0.0);
    for (var j = 0u; j < terms; j++) {
        let w = position_basis(j);
        for (var c = 0u; c < 3u; c++) {
            motion[c] += w * params[at + 3u * j + c];
        }
    }
    return motion;
}

// Σⱼ colour_basisⱼ · colour_termsⱼ of Gaussian i: how far its SH DC is moved at `time`.
fn colour_wave(i: u32) -> vec3<f32> {
    let terms = 2u * tp.colour_harmonics;
    let at = param_time_offsets().colour + 3u * terms * i;
    var wave = vec3<f32>(0.0);
    for (var j = 0u; j < terms; j++) {
        let w = colour_basis(j);
        for (var c = 0u; c < 3u; c++) {
            wave[c] += w * params[at + 3u * j + c];
        }
    }
    return wave;
}

// Gaussian i's distance from its centre time, in widths: z = d · exp(−log width), d the
// signed distance from τ to `time` around the loop, in [−period/2, period/2). Its opacity
// logit at `time` is its own less ½·z².
fn presence_z(i: u32) -> f32 {
    let t = param_time_offsets();
    let d = tp.time - params[t.centre + i];
    let wrapped = d - tp.period * floor(d / tp.period + 0.5);
    return wrapped * exp(-params[t.log_width + i]);
}
