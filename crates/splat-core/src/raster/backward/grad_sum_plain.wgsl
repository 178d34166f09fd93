// rasterize_backward.wgsl's tile sum without subgroup operations: every contributing
// invocation adds its ten values to the Gaussian's workgroup sums.

fn sum_grads(base: u32, contributes: bool, grads: array<f32, 10>) {
    if contributes {
        for (var c = 0u; c < GRAD_STRIDE; c++) {
            add_tile_grad(base + c, grads[c]);
        }
    }
}
