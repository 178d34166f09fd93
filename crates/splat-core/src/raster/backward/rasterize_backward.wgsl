// Backward of rasterize.wgsl: per tile, every pixel walks its contributors back to front
// (T recovered by dividing out 1 - alpha, colour/depth behind accumulated as in 3DGS) and
// produces gradients w.r.t. each Gaussian's 2D mean, conic, colour, opacity and depth.
// They are summed over the tile's pixels in workgroup memory, and each batch ends with one
// invocation per Gaussian adding the tile's totals into that Gaussian's ten sums in
// `gaussian_grads` (zeroed by the host), which project_backward.wgsl carries to the 3D
// parameters. Nothing is kept per intersection.
// The frozen static set (the first `params.n_static` Gaussians: a dynamic step's static
// set) gets no sums, and the walk stops at the tile's front-most trained Gaussian: what is
// in front of it is frozen and nothing behind depends on it. So the static set costs the
// backward its blending arithmetic between the back and that Gaussian, not its sums.
// After common.wgsl and two parts the host chooses by what the device has
// (backward/mod.rs, `rasterize_backward_module`):
// `sum_grads` (the tile sum): a compare-exchange loop on workgroup memory per pixel
//   (grad_sum_plain.wgsl), or a subgroup sum first so that one invocation per subgroup adds
//   (grad_sum_subgroup.wgsl);
// `add_gaussian_grad` and the `gaussian_grads` binding (6): native f32 atomic adds
//   (grad_add_float.wgsl) or a compare-exchange loop on the u32 bits (grad_add_cas.wgsl).

@group(0) @binding(0) var<uniform> params: RenderParams;
@group(0) @binding(1) var<storage, read> projected: array<Projected>;
// Gaussian ids of the intersections, sorted by tile (depth order within a tile).
@group(0) @binding(2) var<storage, read> sorted_gaussians: array<u32>;
@group(0) @binding(3) var<storage, read> ranges: array<vec2<u32>>;
@group(0) @binding(4) var<storage, read> pixel_state: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read> v_pixels: array<f32>;

const BATCH: u32 = 128u;
// mean2d (2), conic (3), rgb (3), opacity, depth
const GRAD_STRIDE: u32 = 10u;

var<workgroup> batch_xy_opacity_z: array<vec4<f32>, 128>;
var<workgroup> batch_conic: array<vec4<f32>, 128>;
var<workgroup> batch_rgb: array<vec4<f32>, 128>;
var<workgroup> batch_gaussian: array<u32, 128>;
var<workgroup> batch_grads: array<atomic<u32>, 1280>;
var<workgroup> max_end: atomic<u32>;
var<workgroup> max_end_snapshot: u32;
var<workgroup> walk_start: atomic<u32>;
var<workgroup> walk_start_snapshot: u32;

// Float add on workgroup memory by compare-exchange on the u32 bits (WGSL has no portable
// float atomics, and wgpu's f32 atomics are for storage buffers only).
fn add_tile_grad(idx: u32, value: f32) {
    var old = atomicLoad(&batch_grads[idx]);
    loop {
        let new_bits = bitcast<u32>(bitcast<f32>(old) + value);
        let result = atomicCompareExchangeWeak(&batch_grads[idx], old, new_bits);
        if result.exchanged {
            break;
        }
        old = result.old_value;
    }
}

@compute @workgroup_size(16, 16)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lxy: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let pixel = tile_pixel(params, wid, lxy);
    let inside = pixel.inside;
    let centre = pixel.centre;
    let range = ranges[pixel.tile];

    var t_final = 1.0;
    var contrib_end = range.x;
    var v_rgb = vec3<f32>(0.0);
    var v_alpha_out = 0.0;
    var v_depth = 0.0;
    if inside {
        let pix = pixel.index;
        let state = pixel_state[pix];
        t_final = bitcast<f32>(state.x);
        contrib_end = state.y;
        v_rgb = vec3<f32>(v_pixels[pix * 5u], v_pixels[pix * 5u + 1u], v_pixels[pix * 5u + 2u]);
        v_alpha_out = v_pixels[pix * 5u + 3u];
        v_depth = v_pixels[pix * 5u + 4u];
    }
    // d rgb_out / d T_final = background and d alpha_out / d T_final = -1.
    let v_t_final = dot(v_rgb, params.background.rgb) - v_alpha_out;

    if lid == 0u {
        atomicStore(&max_end, range.x);
    }
    workgroupBarrier();
    atomicMax(&max_end, contrib_end);
    workgroupBarrier();
    if lid == 0u {
        max_end_snapshot = atomicLoad(&max_end);
    }
    let end = workgroupUniformLoad(&max_end_snapshot);

    // The walk's front: the first intersection (in depth order) of a trained Gaussian.
    var start = range.x;
    if params.n_static > 0u {
        if lid == 0u {
            atomicStore(&walk_start, end);
        }
        workgroupBarrier();
        for (var i = range.x + lid; i < end; i += 256u) {
            if sorted_gaussians[i] >= params.n_static {
                atomicMin(&walk_start, i);
                break;
            }
        }
        workgroupBarrier();
        if lid == 0u {
            walk_start_snapshot = atomicLoad(&walk_start);
        }
        start = workgroupUniformLoad(&walk_start_snapshot);
    }

    var t = t_final;
    var behind_rgb = vec3<f32>(0.0);
    var behind_depth = 0.0;
    var last_alpha = 0.0;
    var last_rgb = vec3<f32>(0.0);
    var last_depth = 0.0;

    var batch_end = end;
    while batch_end > start {
        let batch_start = max(start, select(0u, batch_end - BATCH, batch_end >= BATCH));
        let count = batch_end - batch_start;
        if lid < count {
            let gid = sorted_gaussians[batch_start + lid];
            let p = projected[gid];
            batch_xy_opacity_z[lid] = p.xy_opacity_z;
            batch_conic[lid] = p.conic_radius;
            batch_rgb[lid] = p.rgb;
            batch_gaussian[lid] = gid;
        }
        for (var k = lid; k < BATCH * GRAD_STRIDE; k += 256u) {
            atomicStore(&batch_grads[k], 0u);
        }
        workgroupBarrier();
        // k is the same for the whole workgroup: every invocation reaches `sum_grads`
        // (those the Gaussian does not touch with zeros), as subgroup sums require.
        for (var kk = 0u; kk < count; kk++) {
            let k = count - 1u - kk;
            let xyoz = batch_xy_opacity_z[k];
            let conic = batch_conic[k].xyz;
            let d = xyoz.xy - centre;
            let power = -0.5 * (conic.x * d.x * d.x + conic.z * d.y * d.y) - conic.y * d.x * d.y;
            let g = exp(min(power, 0.0));
            let raw_alpha = xyoz.z * g;
            let alpha = min(ALPHA_MAX, raw_alpha);
            let contributes = batch_start + k < contrib_end && power <= 0.0
                && power >= POWER_MIN && alpha >= ALPHA_MIN;
            var grads: array<f32, 10>;
            if contributes {
                t = t / (1.0 - alpha);
                behind_rgb = last_alpha * last_rgb + (1.0 - last_alpha) * behind_rgb;
                behind_depth = last_alpha * last_depth + (1.0 - last_alpha) * behind_depth;
                let rgb = batch_rgb[k].rgb;
                let weight = alpha * t;
                let v_alpha = t * (dot(rgb - behind_rgb, v_rgb) + (xyoz.w - behind_depth) * v_depth)
                    - t_final / (1.0 - alpha) * v_t_final;
                // The min() at 0.999 passes no gradient when it clamps.
                var v_g = 0.0;
                var v_opacity = 0.0;
                if raw_alpha <= ALPHA_MAX {
                    v_g = xyoz.z * v_alpha;
                    v_opacity = g * v_alpha;
                }
                let v_power = g * v_g;
                grads = array<f32, 10>(
                    -v_power * (conic.x * d.x + conic.y * d.y),
                    -v_power * (conic.y * d.x + conic.z * d.y),
                    -0.5 * v_power * d.x * d.x,
                    -v_power * d.x * d.y,
                    -0.5 * v_power * d.y * d.y,
                    weight * v_rgb.r,
                    weight * v_rgb.g,
                    weight * v_rgb.b,
                    v_opacity,
                    weight * v_depth,
                );
                last_alpha = alpha;
                last_rgb = rgb;
                last_depth = xyoz.w;
            }
            // The same Gaussian for the whole workgroup, so every invocation or none sums.
            if batch_gaussian[k] >= params.n_static {
                sum_grads(k * GRAD_STRIDE, contributes, grads);
            }
        }
        workgroupBarrier();
        // The tile's totals, one global add per Gaussian and value (none for zeros: a
        // Gaussian whose box touches the tile may reach none of its pixels, and a static
        // one has none).
        if lid < count {
            let dst = batch_gaussian[lid] * GRAD_STRIDE;
            for (var c = 0u; c < GRAD_STRIDE; c++) {
                let total = bitcast<f32>(atomicLoad(&batch_grads[lid * GRAD_STRIDE + c]));
                if total != 0.0 {
                    add_gaussian_grad(dst + c, total);
                }
            }
        }
        workgroupBarrier();
        batch_end = batch_start;
    }
}
