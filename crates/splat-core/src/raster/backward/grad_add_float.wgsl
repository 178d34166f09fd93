// rasterize_backward.wgsl's per-Gaussian sums with native f32 atomic adds (wgpu's
// Features::SHADER_FLOAT32_ATOMIC). project_backward.wgsl reads the buffer as f32.

@group(0) @binding(6) var<storage, read_write> gaussian_grads: array<atomic<f32>>;

fn add_gaussian_grad(idx: u32, value: f32) {
    atomicAdd(&gaussian_grads[idx], value);
}
