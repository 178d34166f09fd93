// The forward's pixels (r, g, b, alpha, depth per pixel, background blended in) as an
// RGBA8 texture the viewer shows directly: the image never leaves the GPU.
// After common.wgsl (RenderParams).

@group(0) @binding(0) var<uniform> params: RenderParams;
@group(0) @binding(1) var<storage, read> pixels: array<f32>;
@group(0) @binding(2) var frame: texture_storage_2d<rgba8unorm, write>;

@compute @workgroup_size(16, 16)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.width || gid.y >= params.height {
        return;
    }
    let i = 5u * (gid.y * params.width + gid.x);
    let rgb = clamp(vec3<f32>(pixels[i], pixels[i + 1u], pixels[i + 2u]), vec3<f32>(0.0),
                    vec3<f32>(1.0));
    textureStore(frame, vec2<i32>(gid.xy), vec4<f32>(rgb, 1.0));
}
