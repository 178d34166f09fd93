// Per-tile front-to-back alpha blending, one 16x16 workgroup per tile (3DGS rules):
// alpha = min(0.999, o * exp(power)); skip alpha < 1/255 or power outside [-4.5, 0];
// stop before a Gaussian that would take T below 1e-4.
// Writes rgb + T * background, alpha = 1 - T and D = sum(z * alpha * T) per pixel, and
// for the backward pass the final T and one past the last contributing intersection.
// After common.wgsl (RenderParams, Projected, the blending constants, `tile_pixel`).

@group(0) @binding(0) var<uniform> params: RenderParams;
@group(0) @binding(1) var<storage, read> projected: array<Projected>;
// Gaussian ids of the intersections, sorted by tile (depth order within a tile).
@group(0) @binding(2) var<storage, read> sorted_gaussians: array<u32>;
@group(0) @binding(3) var<storage, read> ranges: array<vec2<u32>>;
@group(0) @binding(4) var<storage, read_write> out_pixels: array<f32>;
@group(0) @binding(5) var<storage, read_write> pixel_state: array<vec2<u32>>;
// The static set's own render of this camera (H·W·5, as `out_pixels`), where
// `params.static_render` is 1: a tile no trained Gaussian reaches is copied from it.
@group(0) @binding(6) var<storage, read> static_pixels: array<f32>;

const BATCH: u32 = 256u;

var<workgroup> batch_xy_opacity_z: array<vec4<f32>, 256>;
var<workgroup> batch_conic: array<vec4<f32>, 256>;
var<workgroup> batch_rgb: array<vec4<f32>, 256>;
var<workgroup> active_count: atomic<u32>;
var<workgroup> active_snapshot: u32;
var<workgroup> trained_count: atomic<u32>;
var<workgroup> trained_snapshot: u32;

@compute @workgroup_size(16, 16)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lxy: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let pixel = tile_pixel(params, wid, lxy);
    let inside = pixel.inside;
    let centre = pixel.centre;
    let range = ranges[pixel.tile];

    // A tile of the frozen static set alone blends exactly as the static set's own render did
    // (the same Gaussians in the same depth order): copy it instead. Its pixel state tells
    // the backward that nothing here contributed, so it walks nothing.
    if params.static_render != 0u {
        if lid == 0u {
            atomicStore(&trained_count, 0u);
        }
        workgroupBarrier();
        for (var i = range.x + lid; i < range.y; i += 256u) {
            if sorted_gaussians[i] >= params.n_static {
                atomicAdd(&trained_count, 1u);
                break;
            }
        }
        workgroupBarrier();
        if lid == 0u {
            trained_snapshot = atomicLoad(&trained_count);
        }
        if workgroupUniformLoad(&trained_snapshot) == 0u {
            if inside {
                let pix = pixel.index;
                for (var c = 0u; c < 5u; c++) {
                    out_pixels[pix * 5u + c] = static_pixels[pix * 5u + c];
                }
                pixel_state[pix] = vec2<u32>(bitcast<u32>(1.0 - static_pixels[pix * 5u + 3u]), range.x);
            }
            return;
        }
    }

    var t = 1.0;
    var colour = vec3<f32>(0.0);
    var depth = 0.0;
    var contrib_end = range.x;
    var done = !inside;

    for (var start = range.x; start < range.y; start += BATCH) {
        if lid == 0u {
            atomicStore(&active_count, 0u);
        }
        workgroupBarrier();
        if !done {
            atomicAdd(&active_count, 1u);
        }
        workgroupBarrier();
        if lid == 0u {
            active_snapshot = atomicLoad(&active_count);
        }
        if workgroupUniformLoad(&active_snapshot) == 0u {
            break;
        }
        let j_load = start + lid;
        if j_load < range.y {
            let p = projected[sorted_gaussians[j_load]];
            batch_xy_opacity_z[lid] = p.xy_opacity_z;
            batch_conic[lid] = p.conic_radius;
            batch_rgb[lid] = p.rgb;
        }
        workgroupBarrier();
        let count = min(BATCH, range.y - start);
        for (var k = 0u; k < count && !done; k++) {
            let xyoz = batch_xy_opacity_z[k];
            let conic = batch_conic[k].xyz;
            let d = xyoz.xy - centre;
            let power = -0.5 * (conic.x * d.x * d.x + conic.z * d.y * d.y) - conic.y * d.x * d.y;
            if power > 0.0 || power < POWER_MIN {
                continue;
            }
            let alpha = min(ALPHA_MAX, xyoz.z * exp(power));
            if alpha < ALPHA_MIN {
                continue;
            }
            let test_t = t * (1.0 - alpha);
            if test_t < T_MIN {
                done = true;
                break;
            }
            let weight = alpha * t;
            colour += batch_rgb[k].rgb * weight;
            depth += xyoz.w * weight;
            t = test_t;
            contrib_end = start + k + 1u;
        }
        workgroupBarrier();
    }

    if inside {
        let pix = pixel.index;
        let rgb = colour + t * params.background.rgb;
        out_pixels[pix * 5u] = rgb.r;
        out_pixels[pix * 5u + 1u] = rgb.g;
        out_pixels[pix * 5u + 2u] = rgb.b;
        out_pixels[pix * 5u + 3u] = 1.0 - t;
        out_pixels[pix * 5u + 4u] = depth;
        pixel_state[pix] = vec2<u32>(bitcast<u32>(t), contrib_end);
    }
}
