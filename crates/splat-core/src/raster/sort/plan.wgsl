// The size of a scan or sort (Rust: sort/mod.rs's `DispatchPlan`, the one declaration;
// the wgsl tests check this one against it): its length, its number of blocks and the
// workgroups of its block-wise dispatches (an indirect dispatch: x, y, 1). tiles.wgsl
// writes the tile sort's as words, in this order.

struct DispatchPlan {
    len: u32,
    num_blocks: u32,
    groups_x: u32,
    groups_y: u32,
    groups_z: u32,
}
