// rasterize_backward.wgsl's gradient sum without subgroup operations: every contributing
// invocation adds its ten values to the Gaussian's workgroup slots.

fn sum_grads(base: u32, contributes: bool, grads: array<f32, 10>) {
    if contributes {
        for (var c = 0u; c < GRAD_STRIDE; c++) {
            add_grad(base + c, grads[c]);
        }
    }
}
