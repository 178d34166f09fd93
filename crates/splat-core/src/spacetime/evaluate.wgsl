// The evaluate pass of a spacetime set and its adjoint (spacetime/evaluate.rs holds the
// Rust side; a training session launches both, the viewer's GpuSpacetimeSet `evaluate`
// alone; time_layout.wgsl holds the functions of time they share with Adam).
//
// `evaluate` draws the set at the uniform's time (a step's view time, or the time the viewer
// shows): it writes the snapshot the rasteriser reads (scene Gaussian n_static + i,
// sections `scene_len` long) from the parameters (sections `n_train` long, the time
// sections after the Gaussians'), as SpacetimeGaussians.at does in torch:
//
//   mean(t)  = mean + Σⱼ position_basisⱼ · position_termsⱼ
//   dc(t)    = dc + Σⱼ colour_basisⱼ · colour_termsⱼ
//   logit(t) = logit − ½·z²,   z = d(t, τ) · exp(−log width)
//
// and copies the rest (log-scales, quaternions, the higher SH bands).
//
// `adjoint` carries the backward's gradient of that snapshot (of the whole scene, sections
// `grad_len` long; plus a second render's when `has_extra`) to the time parameters, into
// `time_grads` (the time sections alone, from 0):
//
//   ∂L/∂position_termsⱼ = position_basisⱼ · ∂L/∂mean(t)
//   ∂L/∂colour_termsⱼ   = colour_basisⱼ · ∂L/∂dc(t)
//   ∂L/∂τ               = ∂L/∂logit(t) · z · exp(−log width)   (d falls as τ rises; the
//                                                               wrap's floor is flat)
//   ∂L/∂log width       = ∂L/∂logit(t) · z²
//
// Every canonical parameter enters its value at t with slope 1, so its gradient is the
// snapshot's own: Adam reads it there (adam.wgsl), as for a set of Gaussians.

@group(0) @binding(0) var<uniform> tp: TimeParams;
// The trained set's parameters (read by time_layout.wgsl).
@group(0) @binding(1) var<storage, read> params: array<f32>;
// evaluate's output: the scene the frames draw.
@group(0) @binding(2) var<storage, read_write> scene: array<f32>;
// adjoint's input and output.
@group(0) @binding(3) var<storage, read> grads: array<f32>;
@group(0) @binding(4) var<storage, read> grads_extra: array<f32>;
@group(0) @binding(5) var<storage, read_write> time_grads: array<f32>;

@compute @workgroup_size(256)
fn evaluate(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_index) lid: u32) {
    let i = linear_workgroup(wid, nwg) * 256u + lid;
    if i >= tp.n_train {
        return;
    }
    let si = tp.n_static + i;
    let s = gaussian_offsets(tp.scene_len);
    let p = gaussian_offsets(tp.n_train);
    let k = tp.sh_coeffs;

    let motion = mean_motion(i);
    let wave = colour_wave(i);
    for (var c = 0u; c < 3u; c++) {
        scene[s.means + 3u * si + c] = params[p.means + 3u * i + c] + motion[c];
        scene[s.log_scales + 3u * si + c] = params[p.log_scales + 3u * i + c];
        scene[s.sh + 3u * k * si + c] = params[p.sh + 3u * k * i + c] + wave[c];
    }
    for (var c = 0u; c < 4u; c++) {
        scene[s.quats + 4u * si + c] = params[p.quats + 4u * i + c];
    }
    let z = presence_z(i);
    scene[s.opacity + si] = params[p.opacity + i] - 0.5 * z * z;
    for (var c = 3u; c < 3u * k; c++) {
        scene[s.sh + 3u * k * si + c] = params[p.sh + 3u * k * i + c];
    }
}

fn gradient(at: u32) -> f32 {
    if tp.has_extra != 0u {
        return grads[at] + grads_extra[at];
    }
    return grads[at];
}

@compute @workgroup_size(256)
fn adjoint(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let i = linear_workgroup(wid, nwg) * 256u + lid;
    if i >= tp.n_train {
        return;
    }
    let gi = tp.n_static + i;
    let g = gaussian_offsets(tp.grad_len);
    let out = time_offsets(0u, tp.n_train);
    let p = param_time_offsets();

    let g_logit = gradient(g.opacity + gi);
    let z = presence_z(i);
    time_grads[out.centre + i] = g_logit * z * exp(-params[p.log_width + i]);
    time_grads[out.log_width + i] = g_logit * z * z;

    let colour_terms = 2u * tp.colour_harmonics;
    for (var c = 0u; c < 3u; c++) {
        let g_dc = gradient(g.sh + 3u * tp.sh_coeffs * gi + c);
        for (var j = 0u; j < colour_terms; j++) {
            time_grads[out.colour + 3u * (colour_terms * i + j) + c] = colour_basis(j) * g_dc;
        }
    }
    let position_terms = 2u * tp.position_harmonics;
    for (var c = 0u; c < 3u; c++) {
        let g_mean = gradient(g.means + 3u * gi + c);
        for (var j = 0u; j < position_terms; j++) {
            time_grads[out.position + 3u * (position_terms * i + j) + c] =
                position_basis(j) * g_mean;
        }
    }
}
