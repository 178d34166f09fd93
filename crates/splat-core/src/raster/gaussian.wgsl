// Per-Gaussian maths shared by the projection (forward) and its backward pass.
// After common.wgsl and gaussian_layout.wgsl. Reads two globals the including kernel
// declares (its part list in Rust says so too): `params: RenderParams` and
// `gaussians: array<f32>`, the Gaussian buffer in SoA sections of
// `params.gaussian_stride` entries.

struct Gaussian {
    mean: vec3<f32>,
    log_scale: vec3<f32>,
    quat: vec4<f32>, // w, x, y, z (raw)
    opacity_logit: f32,
}

fn load_gaussian(i: u32, o: GaussianOffsets) -> Gaussian {
    let m = vec3<f32>(gaussians[o.means + 3u * i], gaussians[o.means + 3u * i + 1u],
                      gaussians[o.means + 3u * i + 2u]);
    let s = vec3<f32>(gaussians[o.log_scales + 3u * i], gaussians[o.log_scales + 3u * i + 1u],
                      gaussians[o.log_scales + 3u * i + 2u]) + params.log_scale_offset;
    let q = vec4<f32>(gaussians[o.quats + 4u * i], gaussians[o.quats + 4u * i + 1u],
                      gaussians[o.quats + 4u * i + 2u], gaussians[o.quats + 4u * i + 3u]);
    return Gaussian(m, s, q, gaussians[o.opacity + i]);
}

fn gaussian_is_finite(g: Gaussian) -> bool {
    return is_finite_f32(g.opacity_logit) && all_finite3(g.mean) && all_finite3(g.log_scale)
        && all_finite4(g.quat);
}

const QUAT_MIN_NORM2: f32 = 1e-12;

// Unit quaternion; one with squared norm below QUAT_MIN_NORM2 becomes the identity.
fn normalized_quat(q: vec4<f32>) -> vec4<f32> {
    let n2 = dot(q, q);
    if n2 < QUAT_MIN_NORM2 {
        return vec4<f32>(1.0, 0.0, 0.0, 0.0);
    }
    return q / sqrt(n2);
}

// Rotation matrix of a unit quaternion (w, x, y, z); WGSL matrices are column-major.
fn quat_to_mat(q: vec4<f32>) -> mat3x3<f32> {
    let w = q.x;
    let x = q.y;
    let y = q.z;
    let z = q.w;
    return mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    );
}

fn world_to_cam_rotation() -> mat3x3<f32> {
    // Rows of W stored in params; build the column-major matrix.
    return transpose(mat3x3<f32>(params.rot_row0.xyz, params.rot_row1.xyz, params.rot_row2.xyz));
}

fn sigmoid(x: f32) -> f32 {
    return 1.0 / (1.0 + exp(-x));
}

struct ProjectedForward {
    visible: bool,
    mean2d: vec2<f32>,
    conic: vec3<f32>,
    opacity: f32,
    z: f32,
    radius: f32,
}

fn project_gaussian(g: Gaussian) -> ProjectedForward {
    var res: ProjectedForward;
    res.visible = false;
    let w = world_to_cam_rotation();
    let t = w * g.mean + vec3<f32>(params.rot_row0.w, params.rot_row1.w, params.rot_row2.w);
    if !(t.z >= NEAR_PLANE) || !is_finite_f32(t.z) {
        return res;
    }
    let fx = params.intrinsics.x;
    let fy = params.intrinsics.y;
    let rz = 1.0 / t.z;
    let u = clamp(t.x * rz, -params.jacobian_limits.x, params.jacobian_limits.x);
    let v = clamp(t.y * rz, -params.jacobian_limits.y, params.jacobian_limits.y);
    // J is 2x3; stored as a 3x3 with a zero last row to keep the products square.
    let j = mat3x3<f32>(
        vec3<f32>(fx * rz, 0.0, 0.0),
        vec3<f32>(0.0, fy * rz, 0.0),
        vec3<f32>(-fx * u * rz, -fy * v * rz, 0.0),
    );
    let r = quat_to_mat(normalized_quat(g.quat));
    let s = exp(clamp(g.log_scale, vec3<f32>(MIN_LOG_SCALE), vec3<f32>(MAX_LOG_SCALE)));
    let m = r * mat3x3<f32>(vec3<f32>(s.x, 0.0, 0.0), vec3<f32>(0.0, s.y, 0.0),
                            vec3<f32>(0.0, 0.0, s.z));
    let tm = j * w * m;
    let cov = tm * transpose(tm);
    let a0 = cov[0][0];
    let b0 = cov[1][0];
    let c0 = cov[1][1];
    let det0 = a0 * c0 - b0 * b0;
    let filter_px2 = screen_filter(params.antialiased);
    let a1 = a0 + filter_px2;
    let c1 = c0 + filter_px2;
    let det1 = a1 * c1 - b0 * b0;
    if !(det1 > 0.0) || !is_finite_f32(det1) {
        return res;
    }
    var opacity = sigmoid(g.opacity_logit);
    if params.antialiased != 0u {
        opacity *= sqrt(max(det0, 0.0) / det1);
    }
    if !(opacity >= ALPHA_MIN) {
        return res;
    }
    let mid = 0.5 * (a1 + c1);
    let lambda = mid + sqrt(max(0.1, mid * mid - det1));
    res.radius = ceil(3.0 * sqrt(lambda));
    res.conic = vec3<f32>(c1 / det1, -b0 / det1, a1 / det1);
    res.mean2d = vec2<f32>(fx * t.x * rz + params.intrinsics.z, fy * t.y * rz + params.intrinsics.w);
    res.opacity = opacity;
    res.z = t.z;
    res.visible = is_finite_f32(res.radius) && is_finite_f32(res.mean2d.x)
        && is_finite_f32(res.mean2d.y);
    return res;
}

const SH_C0: f32 = 0.28209479177387814;
const SH_C1: f32 = 0.4886025119029199;
const SH_C2: array<f32, 5> = array<f32, 5>(1.0925484305920792, -1.0925484305920792,
    0.31539156525252005, -1.0925484305920792, 0.5462742152960396);
const SH_C3: array<f32, 7> = array<f32, 7>(-0.5900435899266435, 2.890611442640554,
    -0.4570457994644658, 0.3731763325901154, -0.4570457994644658, 1.445305721320277,
    -0.5900435899266435);

// The real SH basis of 3DGS for a unit direction, 16 values (unused degrees are ignored).
fn sh_basis(d: vec3<f32>) -> array<f32, 16> {
    let x = d.x;
    let y = d.y;
    let z = d.z;
    let xx = x * x;
    let yy = y * y;
    let zz = z * z;
    return array<f32, 16>(
        SH_C0,
        -SH_C1 * y, SH_C1 * z, -SH_C1 * x,
        SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2.0 * zz - xx - yy), SH_C2[3] * x * z,
        SH_C2[4] * (xx - yy),
        SH_C3[0] * y * (3.0 * xx - yy), SH_C3[1] * x * y * z, SH_C3[2] * y * (4.0 * zz - xx - yy),
        SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy), SH_C3[4] * x * (4.0 * zz - xx - yy),
        SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3.0 * yy),
    );
}

// Gradient of each basis function with respect to the (unit) direction.
fn sh_basis_grad(d: vec3<f32>) -> array<vec3<f32>, 16> {
    let x = d.x;
    let y = d.y;
    let z = d.z;
    let xx = x * x;
    let yy = y * y;
    let zz = z * z;
    return array<vec3<f32>, 16>(
        vec3<f32>(0.0),
        vec3<f32>(0.0, -SH_C1, 0.0), vec3<f32>(0.0, 0.0, SH_C1), vec3<f32>(-SH_C1, 0.0, 0.0),
        SH_C2[0] * vec3<f32>(y, x, 0.0),
        SH_C2[1] * vec3<f32>(0.0, z, y),
        SH_C2[2] * vec3<f32>(-2.0 * x, -2.0 * y, 4.0 * z),
        SH_C2[3] * vec3<f32>(z, 0.0, x),
        SH_C2[4] * vec3<f32>(2.0 * x, -2.0 * y, 0.0),
        SH_C3[0] * vec3<f32>(6.0 * x * y, 3.0 * xx - 3.0 * yy, 0.0),
        SH_C3[1] * vec3<f32>(y * z, x * z, x * y),
        SH_C3[2] * vec3<f32>(-2.0 * x * y, 4.0 * zz - xx - 3.0 * yy, 8.0 * y * z),
        SH_C3[3] * vec3<f32>(-6.0 * x * z, -6.0 * y * z, 6.0 * zz - 3.0 * xx - 3.0 * yy),
        SH_C3[4] * vec3<f32>(4.0 * zz - 3.0 * xx - yy, -2.0 * x * y, 8.0 * x * z),
        SH_C3[5] * vec3<f32>(2.0 * x * z, -2.0 * y * z, xx - yy),
        SH_C3[6] * vec3<f32>(3.0 * xx - 3.0 * yy, -6.0 * x * y, 0.0),
    );
}

// rgb before the clamp at 0: SH · basis + 0.5.
fn sh_to_rgb(i: u32, o: GaussianOffsets, dir: vec3<f32>) -> vec3<f32> {
    var basis = sh_basis(dir);
    var rgb = vec3<f32>(0.5);
    let k_count = params.sh_coeffs;
    for (var k = 0u; k < k_count; k++) {
        let base = o.sh + (i * k_count + k) * 3u;
        rgb += basis[k] * vec3<f32>(gaussians[base], gaussians[base + 1u], gaussians[base + 2u]);
    }
    return rgb;
}
