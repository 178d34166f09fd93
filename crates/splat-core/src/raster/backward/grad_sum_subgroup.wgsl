// rasterize_backward.wgsl's tile sum with subgroup operations: the subgroup sums its
// pixels' values first and one invocation adds them, so a tile's 256 pixels contend
// 256 / subgroup-size times per value instead of 256. (Naga takes subgroup builtins when
// the device has Features::SUBGROUP; it does not accept WGSL's `enable subgroups;` yet.)

fn sum_grads(base: u32, contributes: bool, grads: array<f32, 10>) {
    if subgroupAny(contributes) {
        // The first active invocation adds the subgroup's totals (naga has no
        // subgroupElect yet).
        let first = subgroupExclusiveAdd(1u) == 0u;
        for (var c = 0u; c < GRAD_STRIDE; c++) {
            let total = subgroupAdd(grads[c]);
            if first {
                add_tile_grad(base + c, total);
            }
        }
    }
}
