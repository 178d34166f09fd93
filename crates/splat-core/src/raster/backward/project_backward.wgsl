// Backward of project.wgsl: carries each Gaussian's 2D gradients (summed over its tiles
// by rasterize_backward.wgsl) to the 3D parameters (mean, log-scale, quaternion, opacity
// logit, SH), in the same SoA layout as the input. Culled and static Gaussians get zeros.
// After common.wgsl, gaussian_layout.wgsl and gaussian.wgsl; binds the `params` and
// `gaussians` gaussian.wgsl reads.

@group(0) @binding(0) var<uniform> params: RenderParams;
@group(0) @binding(1) var<storage, read> gaussians: array<f32>;
@group(0) @binding(2) var<storage, read> tile_counts: array<u32>;
// Per Gaussian: mean2d (2), conic (3), rgb (3), opacity, depth.
@group(0) @binding(3) var<storage, read> gaussian_grads: array<f32>;
@group(0) @binding(4) var<storage, read_write> grads: array<f32>;

const GRAD_STRIDE: u32 = 10u;

fn adj2(a: f32, b: f32, c: f32) -> mat2x2<f32> {
    return mat2x2<f32>(vec2<f32>(c, -b), vec2<f32>(-b, a));
}

fn write_vec3(base: u32, v: vec3<f32>) {
    grads[base] = v.x;
    grads[base + 1u] = v.y;
    grads[base + 2u] = v.z;
}

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let gid = linear_workgroup(wid, nwg) * 256u + lid;
    let n = params.num_gaussians;
    if gid >= n {
        return;
    }
    let offs = gaussian_offsets(params.gaussian_stride);
    // Gradients are packed densely: sections of n.
    let grad_offs = gaussian_offsets(n);
    let k_count = params.sh_coeffs;

    // A static Gaussian's gradient is not worked out, and a culled one has none.
    if gid < params.n_static || tile_counts[gid] == 0u {
        write_vec3(grad_offs.means + 3u * gid, vec3<f32>(0.0));
        write_vec3(grad_offs.log_scales + 3u * gid, vec3<f32>(0.0));
        for (var c = 0u; c < 4u; c++) {
            grads[grad_offs.quats + 4u * gid + c] = 0.0;
        }
        grads[grad_offs.opacity + gid] = 0.0;
        for (var k = 0u; k < k_count * 3u; k++) {
            grads[grad_offs.sh + gid * k_count * 3u + k] = 0.0;
        }
        return;
    }
    var acc: array<f32, 10>;
    for (var c = 0u; c < GRAD_STRIDE; c++) {
        acc[c] = gaussian_grads[gid * GRAD_STRIDE + c];
    }
    let v_xy = vec2<f32>(acc[0], acc[1]);
    let v_conic = vec3<f32>(acc[2], acc[3], acc[4]);
    let v_rgb_out = vec3<f32>(acc[5], acc[6], acc[7]);
    let v_opacity = acc[8];
    let v_z = acc[9];

    // Recompute the forward quantities (same expressions as project_gaussian).
    let g = load_gaussian(gid, offs);
    let w = world_to_cam_rotation();
    let t = w * g.mean + vec3<f32>(params.rot_row0.w, params.rot_row1.w, params.rot_row2.w);
    let fx = params.intrinsics.x;
    let fy = params.intrinsics.y;
    let rz = 1.0 / t.z;
    let u_raw = t.x * rz;
    let v_raw = t.y * rz;
    let lim = params.jacobian_limits.xy;
    let u = clamp(u_raw, -lim.x, lim.x);
    let v = clamp(v_raw, -lim.y, lim.y);
    let j = mat3x3<f32>(
        vec3<f32>(fx * rz, 0.0, 0.0),
        vec3<f32>(0.0, fy * rz, 0.0),
        vec3<f32>(-fx * u * rz, -fy * v * rz, 0.0),
    );
    let q_norm2 = dot(g.quat, g.quat);
    let qn = normalized_quat(g.quat);
    let r = quat_to_mat(qn);
    let ls_clamped = clamp(g.log_scale, vec3<f32>(MIN_LOG_SCALE), vec3<f32>(MAX_LOG_SCALE));
    let s = exp(ls_clamped);
    let m = r * mat3x3<f32>(vec3<f32>(s.x, 0.0, 0.0), vec3<f32>(0.0, s.y, 0.0),
                            vec3<f32>(0.0, 0.0, s.z));
    let jw = j * w;
    let tm = jw * m;
    let cov = tm * transpose(tm);
    let a0 = cov[0][0];
    let b0 = cov[1][0];
    let c0 = cov[1][1];
    let det0 = a0 * c0 - b0 * b0;
    let filter_px2 = screen_filter(params.antialiased);
    let a1 = a0 + filter_px2;
    let c1 = c0 + filter_px2;
    let det1 = a1 * c1 - b0 * b0;
    let conic = mat2x2<f32>(vec2<f32>(c1, -b0), vec2<f32>(-b0, a1)) * (1.0 / det1);
    let sig = sigmoid(g.opacity_logit);

    // Opacity: o = sigmoid(logit) * sqrt(det0 / det1) in antialiased mode.
    var factor = 1.0;
    var v_det0 = 0.0;
    var v_det1 = 0.0;
    if params.antialiased != 0u {
        factor = sqrt(max(det0, 0.0) / det1);
        let v_factor = v_opacity * sig;
        v_det0 = v_factor * 0.5 * factor / det0;
        v_det1 = -v_factor * 0.5 * factor / det1;
    }
    let v_logit = v_opacity * factor * sig * (1.0 - sig);

    // Conic = inverse(cov + filter_px2 I): d/dcov1 = -C G C; the b entry appears twice in power.
    let g_conic = mat2x2<f32>(vec2<f32>(v_conic.x, 0.5 * v_conic.y),
                              vec2<f32>(0.5 * v_conic.y, v_conic.z));
    let g_cov2 = (conic * g_conic * conic) * -1.0 + v_det1 * adj2(a1, b0, c1) + v_det0 * adj2(a0, b0, c0);
    let g_cov = mat3x3<f32>(vec3<f32>(g_cov2[0], 0.0), vec3<f32>(g_cov2[1], 0.0), vec3<f32>(0.0));

    // cov = tm tm^T, tm = J W M, M = R S.
    let v_tm = 2.0 * g_cov * tm;
    let v_m = transpose(jw) * v_tm;
    let v_j = v_tm * transpose(m) * transpose(w);
    let v_r = mat3x3<f32>(v_m[0] * s.x, v_m[1] * s.y, v_m[2] * s.z);
    let v_s = vec3<f32>(dot(v_m[0], r[0]), dot(v_m[1], r[1]), dot(v_m[2], r[2]));
    let in_range = ls_clamped == g.log_scale;
    let v_log_scale = select(vec3<f32>(0.0), v_s * s, in_range);

    // Quaternion (w, x, y, z) from the rotation gradient; G[i][j] = dL/dR_ij (row i, col j).
    let qw = qn.x;
    let qx = qn.y;
    let qy = qn.z;
    let qz = qn.w;
    let g00 = v_r[0][0];
    let g01 = v_r[1][0];
    let g02 = v_r[2][0];
    let g10 = v_r[0][1];
    let g11 = v_r[1][1];
    let g12 = v_r[2][1];
    let g20 = v_r[0][2];
    let g21 = v_r[1][2];
    let g22 = v_r[2][2];
    let v_qn = 2.0 * vec4<f32>(
        qx * (g21 - g12) + qy * (g02 - g20) + qz * (g10 - g01),
        -2.0 * qx * (g11 + g22) + qy * (g10 + g01) + qz * (g20 + g02) + qw * (g21 - g12),
        qx * (g10 + g01) - 2.0 * qy * (g00 + g22) + qz * (g21 + g12) + qw * (g02 - g20),
        qx * (g20 + g02) + qy * (g21 + g12) - 2.0 * qz * (g00 + g11) + qw * (g10 - g01),
    );
    var v_quat = vec4<f32>(0.0);
    if q_norm2 >= QUAT_MIN_NORM2 {
        v_quat = (v_qn - qn * dot(qn, v_qn)) / sqrt(q_norm2);
    }

    // J entries: J00 = fx/z, J02 = -fx u/z, J11 = fy/z, J12 = -fy v/z (u, v clamped).
    let v_j00 = v_j[0][0];
    let v_j02 = v_j[2][0];
    let v_j11 = v_j[1][1];
    let v_j12 = v_j[2][1];
    var v_rz = fx * (v_j00 - v_j02 * u) + fy * (v_j11 - v_j12 * v);
    var v_t = vec3<f32>(0.0);
    if abs(u_raw) <= lim.x {
        let v_u = -v_j02 * fx * rz;
        v_t.x += v_u * rz;
        v_rz += v_u * t.x;
    }
    if abs(v_raw) <= lim.y {
        let v_v = -v_j12 * fy * rz;
        v_t.y += v_v * rz;
        v_rz += v_v * t.y;
    }
    // mean2d = (fx x/z + cx, fy y/z + cy)
    v_t.x += v_xy.x * fx * rz;
    v_t.y += v_xy.y * fy * rz;
    v_rz += v_xy.x * fx * t.x + v_xy.y * fy * t.y;
    v_t.z += v_z - v_rz * rz * rz;
    var v_mean = transpose(w) * v_t;

    // SH colour, clamped at 0, for the direction from the camera centre.
    let offset = g.mean - params.cam_pos.xyz;
    let dist = length(offset);
    let dir = offset / dist;
    let raw_rgb = sh_to_rgb(gid, offs, dir);
    let v_rgb = select(vec3<f32>(0.0), v_rgb_out, raw_rgb >= vec3<f32>(0.0));
    var basis = sh_basis(dir);
    var basis_grad = sh_basis_grad(dir);
    var v_dir = vec3<f32>(0.0);
    for (var k = 0u; k < k_count; k++) {
        let base = offs.sh + (gid * k_count + k) * 3u;
        let coeff = vec3<f32>(gaussians[base], gaussians[base + 1u], gaussians[base + 2u]);
        write_vec3(grad_offs.sh + (gid * k_count + k) * 3u, basis[k] * v_rgb);
        v_dir += basis_grad[k] * dot(coeff, v_rgb);
    }
    v_mean += (v_dir - dir * dot(dir, v_dir)) / dist;

    write_vec3(grad_offs.means + 3u * gid, v_mean);
    write_vec3(grad_offs.log_scales + 3u * gid, v_log_scale);
    for (var c = 0u; c < 4u; c++) {
        grads[grad_offs.quats + 4u * gid + c] = v_quat[c];
    }
    grads[grad_offs.opacity + gid] = v_logit;
}
