// Tile binning around the sorts:
// `gather_counts`: tile counts in depth order (plus a trailing 0), to be scanned into
//   each Gaussian's first intersection slot; the scan's last entry is the total.
// `emit_intersections`: for every Gaussian in depth order, one (tile id, slot) pair per
//   tile it touches; sorting these stably by tile keeps each tile depth-ordered.

@group(0) @binding(0) var<uniform> params: RenderParams;
@group(0) @binding(1) var<storage, read> projected: array<Projected>;
@group(0) @binding(2) var<storage, read> tile_counts: array<u32>;
@group(0) @binding(3) var<storage, read> depth_order: array<u32>;
@group(0) @binding(4) var<storage, read_write> offsets: array<u32>;
@group(0) @binding(5) var<storage, read_write> isect_keys: array<u32>;
@group(0) @binding(6) var<storage, read_write> isect_slots: array<u32>;
@group(0) @binding(7) var<storage, read_write> isect_gaussian: array<u32>;

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

@compute @workgroup_size(256)
fn emit_intersections(@builtin(workgroup_id) wid: vec3<u32>,
                      @builtin(num_workgroups) nwg: vec3<u32>,
                      @builtin(local_invocation_index) lid: u32) {
    let i = linear_workgroup(wid, nwg) * 256u + lid;
    if i >= params.num_gaussians {
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
            isect_slots[slot] = slot;
            isect_gaussian[slot] = gid;
            slot++;
        }
    }
}
