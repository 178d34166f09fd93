// Tile binning around the sorts:
// `gather_counts`: tile counts in depth order (plus a trailing 0), to be scanned into
//   each Gaussian's first intersection slot; the scan's last entry is the total M.
// `plan_intersections` (one invocation): sizes the rest of the frame on the GPU from M, so
//   the host never waits for it. If M fits the intersection buffers, it writes the tile
//   sort's and the ranges' dispatch sizes; if not, zero intersections (the frame draws
//   only the background) and an overflow in `status` for the host to see later.
// `emit_intersections`: for every Gaussian in depth order, one (tile id, Gaussian id) pair
//   per tile it touches; sorting these stably by tile keeps each tile depth-ordered.
// After common.wgsl (RenderParams, Projected, `tile_rect`, the dispatch helpers).

@group(0) @binding(0) var<uniform> params: RenderParams;
@group(0) @binding(1) var<storage, read> projected: array<Projected>;
@group(0) @binding(2) var<storage, read> tile_counts: array<u32>;
@group(0) @binding(3) var<storage, read> depth_order: array<u32>;
@group(0) @binding(4) var<storage, read_write> offsets: array<u32>;
@group(0) @binding(5) var<storage, read_write> isect_keys: array<u32>;
@group(0) @binding(6) var<storage, read_write> isect_gaussians: array<u32>;
// The tile sort's plan (sort/plan.wgsl's DispatchPlan, as words) followed by the ranges'
// dispatch size:
// num_keys, num_blocks, sort groups x y z, ranges groups x y z.
@group(0) @binding(7) var<storage, read_write> tile_plan: array<u32, 8>;
// The plan of the scan inside each pass of the tile sort (a DispatchPlan, as words).
@group(0) @binding(8) var<storage, read_write> tile_scan_plan: array<u32, 5>;
// overflowed frames and the largest M so far (both only grow, for frames recorded), then
// this frame's M and whether it was drawn (1) or overflowed (0).
@group(0) @binding(9) var<storage, read_write> status: array<u32, 4>;

// Keys per sort block, digit buckets per pass, values per scan block, intersections per
// ranges workgroup (sort/sort.wgsl, sort/scan.wgsl, ranges.wgsl).
const SORT_BLOCK: u32 = 1024u;
const SORT_DIGITS: u32 = 16u;
const SCAN_BLOCK: u32 = 1024u;
const RANGES_WORKGROUP: u32 = 256u;

@compute @workgroup_size(256)
fn gather_counts(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) lid: u32) {
    let i = linear_workgroup(wid, nwg) * 256u + lid;
    if i < params.num_gaussians {
        offsets[i] = tile_counts[depth_order[i]];
    } else if i == params.num_gaussians {
        offsets[i] = 0u;
    }
}

@compute @workgroup_size(1)
fn plan_intersections() {
    let total = offsets[params.num_gaussians];
    let fits = total <= params.intersection_capacity;
    let m = select(0u, total, fits);
    let blocks = (m + SORT_BLOCK - 1u) / SORT_BLOCK;
    let sort_groups = dispatch_grid(blocks);
    let range_groups = dispatch_grid((m + RANGES_WORKGROUP - 1u) / RANGES_WORKGROUP);
    tile_plan = array<u32, 8>(m, blocks, sort_groups.x, sort_groups.y, sort_groups.z,
                              range_groups.x, range_groups.y, range_groups.z);
    let scan_len = SORT_DIGITS * blocks;
    let scan_blocks = (scan_len + SCAN_BLOCK - 1u) / SCAN_BLOCK;
    let scan_groups = dispatch_grid(scan_blocks);
    tile_scan_plan = array<u32, 5>(scan_len, scan_blocks, scan_groups.x, scan_groups.y,
                                   scan_groups.z);
    if params.record_overflow != 0u {
        status[0] += select(1u, 0u, fits);
        status[1] = max(status[1], total);
    }
    status[2] = total;
    status[3] = select(0u, 1u, fits);
}

@compute @workgroup_size(256)
fn emit_intersections(@builtin(workgroup_id) wid: vec3<u32>,
                      @builtin(num_workgroups) nwg: vec3<u32>,
                      @builtin(local_invocation_index) lid: u32) {
    let i = linear_workgroup(wid, nwg) * 256u + lid;
    // Nothing to emit when the frame overflowed (the plan has no intersections).
    if i >= params.num_gaussians || tile_plan[0] == 0u {
        return;
    }
    let gid = depth_order[i];
    if tile_counts[gid] == 0u {
        return;
    }
    let p = projected[gid];
    let rect = tile_rect(params, p.xy_opacity_z.xy, p.conic_radius.w);
    var slot = offsets[i];
    for (var ty = rect.y; ty < rect.w; ty++) {
        for (var tx = rect.x; tx < rect.z; tx++) {
            isect_keys[slot] = ty * params.tiles_x + tx;
            isect_gaussians[slot] = gid;
            slot++;
        }
    }
}
