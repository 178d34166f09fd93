// Stage 1: project every Gaussian (EWA splatting), evaluate its SH colour, count the
// 16x16 tiles it touches and emit its depth sort key.
// Gaussian inputs are one f32 buffer in SoA sections (see `gaussian_offsets`), bound as
// the `params` and `gaussians` gaussian.wgsl reads.

@group(0) @binding(0) var<uniform> params: RenderParams;
@group(0) @binding(1) var<storage, read> gaussians: array<f32>;
@group(0) @binding(2) var<storage, read_write> projected: array<Projected>;
@group(0) @binding(3) var<storage, read_write> tile_counts: array<u32>;
@group(0) @binding(4) var<storage, read_write> depth_keys: array<u32>;
@group(0) @binding(5) var<storage, read_write> depth_vals: array<u32>;

fn cull(i: u32) {
    projected[i] = Projected(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    tile_counts[i] = 0u;
    depth_keys[i] = 0xffffffffu;
    depth_vals[i] = i;
}

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let i = linear_workgroup(wid, nwg) * 256u + lid;
    let n = params.num_gaussians;
    if i >= n {
        return;
    }
    let offs = gaussian_offsets(params.gaussian_stride);
    let g = load_gaussian(i, offs);
    let num_sh = params.sh_coeffs * 3u;
    var finite = gaussian_is_finite(g);
    for (var k = 0u; k < num_sh; k++) {
        finite = finite && is_finite_f32(gaussians[offs.sh + i * num_sh + k]);
    }
    if !finite {
        cull(i);
        return;
    }
    let fwd = project_gaussian(g);
    if !fwd.visible {
        cull(i);
        return;
    }
    let colour = sh_to_rgb(i, offs, normalize(g.mean - params.cam_pos.xyz));
    let rect = tile_rect(params, fwd.mean2d, fwd.radius);
    let count = (rect.z - rect.x) * (rect.w - rect.y);
    if count == 0u {
        cull(i);
        return;
    }
    projected[i] = Projected(
        vec4<f32>(fwd.mean2d, fwd.opacity, fwd.z),
        vec4<f32>(fwd.conic, fwd.radius),
        vec4<f32>(max(colour.rgb, vec3<f32>(0.0)), 0.0),
    );
    tile_counts[i] = count;
    depth_keys[i] = bitcast<u32>(fwd.z);
    depth_vals[i] = i;
}
