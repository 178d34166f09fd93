// Exclusive prefix sum over u32, in place, in three dispatches (reduce-then-scan):
// `scan_blocks` scans each block of 1024 values and records the block totals,
// `scan_block_sums` scans the totals in one workgroup (looping, so any length works),
// `add_block_sums` adds each block's prefix back. No inter-workgroup communication
// within a dispatch, so no forward-progress assumptions.
// The length comes from a buffer, written by the host or by an earlier kernel (the tile
// sort's, sized on the GPU), and the block-wise dispatches are indirect from it.
// After common.wgsl (`linear_workgroup`) and plan.wgsl (`DispatchPlan`).

@group(0) @binding(0) var<storage, read> scan_plan: DispatchPlan;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@group(0) @binding(2) var<storage, read_write> block_sums: array<u32>;

const SCAN_THREADS: u32 = 256u;
const SCAN_PER_THREAD: u32 = 4u;
const SCAN_BLOCK: u32 = 1024u;

var<workgroup> partial: array<u32, 256>;

// Exclusive scan of one value per invocation across the workgroup; returns (prefix, total).
fn workgroup_exclusive_scan(lid: u32, value: u32) -> vec2<u32> {
    partial[lid] = value;
    workgroupBarrier();
    for (var offset = 1u; offset < SCAN_THREADS; offset <<= 1u) {
        var add = 0u;
        if lid >= offset {
            add = partial[lid - offset];
        }
        workgroupBarrier();
        partial[lid] += add;
        workgroupBarrier();
    }
    let inclusive = partial[lid];
    let total = partial[SCAN_THREADS - 1u];
    workgroupBarrier();
    return vec2<u32>(inclusive - value, total);
}

@compute @workgroup_size(256)
fn scan_blocks(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) lid: u32) {
    let block = linear_workgroup(wid, nwg);
    if block >= scan_plan.num_blocks {
        return;
    }
    let base = block * SCAN_BLOCK + lid * SCAN_PER_THREAD;
    var values: array<u32, 4>;
    var sum = 0u;
    for (var k = 0u; k < SCAN_PER_THREAD; k++) {
        let idx = base + k;
        var v = 0u;
        if idx < scan_plan.len {
            v = data[idx];
        }
        values[k] = v;
        sum += v;
    }
    let scanned = workgroup_exclusive_scan(lid, sum);
    var running = scanned.x;
    for (var k = 0u; k < SCAN_PER_THREAD; k++) {
        let idx = base + k;
        if idx < scan_plan.len {
            data[idx] = running;
        }
        running += values[k];
    }
    if lid == 0u {
        block_sums[block] = scanned.y;
    }
}

@compute @workgroup_size(256)
fn scan_block_sums(@builtin(local_invocation_index) lid: u32) {
    var carry = 0u;
    let chunks = (scan_plan.num_blocks + SCAN_THREADS - 1u) / SCAN_THREADS;
    for (var c = 0u; c < chunks; c++) {
        let idx = c * SCAN_THREADS + lid;
        var v = 0u;
        if idx < scan_plan.num_blocks {
            v = block_sums[idx];
        }
        let scanned = workgroup_exclusive_scan(lid, v);
        if idx < scan_plan.num_blocks {
            block_sums[idx] = carry + scanned.x;
        }
        carry += scanned.y;
    }
}

@compute @workgroup_size(256)
fn add_block_sums(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                  @builtin(local_invocation_index) lid: u32) {
    let block = linear_workgroup(wid, nwg);
    if block >= scan_plan.num_blocks {
        return;
    }
    let prefix = block_sums[block];
    let base = block * SCAN_BLOCK + lid * SCAN_PER_THREAD;
    for (var k = 0u; k < SCAN_PER_THREAD; k++) {
        let idx = base + k;
        if idx < scan_plan.len {
            data[idx] += prefix;
        }
    }
}
