// [start, end) of every tile in the tile-sorted intersection list (cleared to 0 first).
// Dispatched indirectly with the size `plan_intersections` (tiles.wgsl) wrote.
// After common.wgsl (`linear_workgroup`).

@group(0) @binding(0) var<storage, read> tile_plan: array<u32, 8>;
@group(0) @binding(1) var<storage, read> sorted_keys: array<u32>;
@group(0) @binding(2) var<storage, read_write> ranges: array<vec2<u32>>;

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let j = linear_workgroup(wid, nwg) * 256u + lid;
    // The intersections drawn this frame (0 when it overflowed).
    let m = tile_plan[0];
    if j >= m {
        return;
    }
    let key = sorted_keys[j];
    if j == 0u || sorted_keys[j - 1u] != key {
        ranges[key].x = j;
    }
    if j + 1u == m || sorted_keys[j + 1u] != key {
        ranges[key].y = j + 1u;
    }
}
