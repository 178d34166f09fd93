// One 4-bit pass of a stable LSD radix sort of (key, value) pairs, in two dispatches
// around a prefix sum (scan.wgsl) of the digit counts:
// `count_digits`: per block of 1024 keys, a histogram of the 16 digits, stored
//   digit-major (counts[digit * num_blocks + block]) so that its exclusive scan is each
//   (digit, block)'s first output slot;
// `scatter`: each block writes its keys in input order. Ranks within a block come from a
//   workgroup scan of per-invocation digit counts packed as sixteen 16-bit counters, so
//   the pass is stable without subgroup operations or any assumption about subgroup size.
// The number of keys comes from a buffer (written by the host, or on the GPU for the tile
// sort) and both dispatches are indirect from it; only the digit's shift is per pass.
// After common.wgsl (`linear_workgroup`) and plan.wgsl (`DispatchPlan`).

// Rust: sort/mod.rs's `SortPass` (the one declaration; the wgsl tests check this one
// against it).
struct SortPass {
    shift: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> sort_pass: SortPass;
@group(0) @binding(1) var<storage, read> keys_in: array<u32>;
@group(0) @binding(2) var<storage, read> vals_in: array<u32>;
@group(0) @binding(3) var<storage, read_write> counts: array<u32>;
@group(0) @binding(4) var<storage, read_write> keys_out: array<u32>;
@group(0) @binding(5) var<storage, read_write> vals_out: array<u32>;
@group(0) @binding(6) var<storage, read> sort_plan: DispatchPlan;

const SORT_THREADS: u32 = 256u;
const SORT_ROUNDS: u32 = 4u;
const SORT_BLOCK: u32 = 1024u;
const DIGITS: u32 = 16u;

var<workgroup> histogram: array<atomic<u32>, 16>;
var<workgroup> flags_lo: array<vec4<u32>, 256>;
var<workgroup> flags_hi: array<vec4<u32>, 256>;
var<workgroup> digit_base: array<u32, 16>;

fn digit_of(key: u32) -> u32 {
    return (key >> sort_pass.shift) & 0xfu;
}

@compute @workgroup_size(256)
fn count_digits(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) lid: u32) {
    let block = linear_workgroup(wid, nwg);
    if lid < DIGITS {
        atomicStore(&histogram[lid], 0u);
    }
    workgroupBarrier();
    if block < sort_plan.num_blocks {
        for (var r = 0u; r < SORT_ROUNDS; r++) {
            let idx = block * SORT_BLOCK + r * SORT_THREADS + lid;
            if idx < sort_plan.len {
                atomicAdd(&histogram[digit_of(keys_in[idx])], 1u);
            }
        }
    }
    workgroupBarrier();
    if lid < DIGITS && block < sort_plan.num_blocks {
        counts[lid * sort_plan.num_blocks + block] = atomicLoad(&histogram[lid]);
    }
}

// Sixteen 16-bit counters in eight u32 words: digit d lives in word d / 2, half d % 2.
fn one_hot(digit: u32) -> array<vec4<u32>, 2> {
    var packed = array<vec4<u32>, 2>(vec4<u32>(0u), vec4<u32>(0u));
    let word = digit >> 1u;
    let bit = 1u << ((digit & 1u) * 16u);
    if word < 4u {
        packed[0][word] = bit;
    } else {
        packed[1][word - 4u] = bit;
    }
    return packed;
}

fn counter(packed_in: array<vec4<u32>, 2>, digit: u32) -> u32 {
    var packed = packed_in;
    let word = digit >> 1u;
    var w: u32;
    if word < 4u {
        w = packed[0][word];
    } else {
        w = packed[1][word - 4u];
    }
    return (w >> ((digit & 1u) * 16u)) & 0xffffu;
}

@compute @workgroup_size(256)
fn scatter(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let block = linear_workgroup(wid, nwg);
    // Uniform per workgroup, so the early return keeps barriers in uniform control flow.
    if block >= sort_plan.num_blocks {
        return;
    }
    if lid < DIGITS {
        digit_base[lid] = counts[lid * sort_plan.num_blocks + block];
    }
    // Each invocation owns SORT_ROUNDS consecutive keys, so block order is
    // (invocation, element) order and one workgroup scan ranks the whole block.
    let first = block * SORT_BLOCK + lid * SORT_ROUNDS;
    var keys: array<u32, 4>;
    var local_counts = array<vec4<u32>, 2>(vec4<u32>(0u), vec4<u32>(0u));
    for (var e = 0u; e < SORT_ROUNDS; e++) {
        if first + e < sort_plan.len {
            keys[e] = keys_in[first + e];
            let hot = one_hot(digit_of(keys[e]));
            local_counts[0] += hot[0];
            local_counts[1] += hot[1];
        }
    }
    flags_lo[lid] = local_counts[0];
    flags_hi[lid] = local_counts[1];
    workgroupBarrier();
    for (var offset = 1u; offset < SORT_THREADS; offset <<= 1u) {
        var add_lo = vec4<u32>(0u);
        var add_hi = vec4<u32>(0u);
        if lid >= offset {
            add_lo = flags_lo[lid - offset];
            add_hi = flags_hi[lid - offset];
        }
        workgroupBarrier();
        flags_lo[lid] += add_lo;
        flags_hi[lid] += add_hi;
        workgroupBarrier();
    }
    // Exclusive prefix per digit = inclusive - own counts; then rank within the thread.
    var seen = array<vec4<u32>, 2>(flags_lo[lid] - local_counts[0], flags_hi[lid] - local_counts[1]);
    for (var e = 0u; e < SORT_ROUNDS; e++) {
        if first + e < sort_plan.len {
            let digit = digit_of(keys[e]);
            let dst = digit_base[digit] + counter(seen, digit);
            keys_out[dst] = keys[e];
            vals_out[dst] = vals_in[first + e];
            let hot = one_hot(digit);
            seen[0] += hot[0];
            seen[1] += hot[1];
        }
    }
}
