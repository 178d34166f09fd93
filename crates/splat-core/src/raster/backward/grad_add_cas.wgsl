// rasterize_backward.wgsl's per-Gaussian sums where the device has no f32 atomics: a float
// add by compare-exchange on the u32 bits. project_backward.wgsl reads the buffer as f32.
// (The same loop as `add_tile_grad`, on a storage pointer: WGSL functions cannot take a
// pointer of either address space.)

@group(0) @binding(6) var<storage, read_write> gaussian_grads: array<atomic<u32>>;

fn add_gaussian_grad(idx: u32, value: f32) {
    var old = atomicLoad(&gaussian_grads[idx]);
    loop {
        let new_bits = bitcast<u32>(bitcast<f32>(old) + value);
        let result = atomicCompareExchangeWeak(&gaussian_grads[idx], old, new_bits);
        if result.exchanged {
            break;
        }
        old = result.old_value;
    }
}
