//! Binning the projected Gaussians into tiles, around the two sorts (docs/rasterizer.md,
//! stages 3–6; `tiles.wgsl`, `ranges.wgsl`): the tile counts gathered in depth order for
//! their scan, the plan that sizes the rest of the frame on the GPU from the scan's total,
//! the (tile, Gaussian) intersections, and after the tile sort each tile's range.

use super::gpu::{compile, div_ceil, run_indirect, run_linear};
use super::COMMON_WGSL;
use crate::wgsl::{KernelModule, WgslPart};

const TILES_WGSL: WgslPart = WgslPart {
    file: "tiles.wgsl",
    source: include_str!("tiles.wgsl"),
    needs: &[COMMON_WGSL.file],
    reads: &[],
};
const RANGES_WGSL: WgslPart = WgslPart {
    file: "ranges.wgsl",
    source: include_str!("ranges.wgsl"),
    needs: &[COMMON_WGSL.file],
    reads: &[],
};

pub(crate) fn tiles_module() -> KernelModule {
    KernelModule {
        label: "tiles",
        parts: vec![&COMMON_WGSL, &TILES_WGSL],
    }
}

pub(crate) fn ranges_module() -> KernelModule {
    KernelModule {
        label: "ranges",
        parts: vec![&COMMON_WGSL, &RANGES_WGSL],
    }
}

/// Byte offset of the ranges' workgroups in the tile plan (tiles.wgsl, `tile_plan`).
const RANGES_GROUPS_OFFSET: u64 = 20;

/// What `gather_counts` reads and writes (tiles.wgsl's bindings 0, 2, 3, 4).
pub(crate) struct GatherBuffers<'a> {
    pub params: &'a wgpu::Buffer,
    pub tile_counts: &'a wgpu::Buffer,
    pub depth_order: &'a wgpu::Buffer,
    pub offsets: &'a wgpu::Buffer,
}

/// What the intersections are made from and written to (tiles.wgsl's bindings).
pub(crate) struct IntersectionBuffers<'a> {
    pub params: &'a wgpu::Buffer,
    pub projected: &'a wgpu::Buffer,
    pub tile_counts: &'a wgpu::Buffer,
    pub depth_order: &'a wgpu::Buffer,
    /// Each Gaussian's first intersection slot (the scanned counts), the total at n.
    pub offsets: &'a wgpu::Buffer,
    pub keys: &'a wgpu::Buffer,
    pub gaussians: &'a wgpu::Buffer,
    /// The tile sort's plan and its scan's, written by `plan_intersections`.
    pub tile_plan: &'a wgpu::Buffer,
    pub tile_scan_plan: &'a wgpu::Buffer,
    pub status: &'a wgpu::Buffer,
}

pub(crate) struct TileKernels {
    gather_counts: wgpu::ComputePipeline,
    plan_intersections: wgpu::ComputePipeline,
    emit: wgpu::ComputePipeline,
    ranges: wgpu::ComputePipeline,
}

impl TileKernels {
    pub(crate) fn new(device: &wgpu::Device) -> Self {
        let entries = ["gather_counts", "plan_intersections", "emit_intersections"];
        let [gather_counts, plan_intersections, emit]: [wgpu::ComputePipeline; 3] =
            compile(device, &tiles_module(), &entries)
                .try_into()
                .expect("three tiles entry points");
        Self {
            gather_counts,
            plan_intersections,
            emit,
            ranges: compile(device, &ranges_module(), &["main"]).remove(0),
        }
    }

    /// The tile counts of `n` Gaussians in depth order, and a trailing 0, into
    /// `b.offsets` (to be scanned); reads `b.params`, `b.tile_counts`, `b.depth_order`.
    pub(crate) fn encode_gather(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        device: &wgpu::Device,
        b: &GatherBuffers<'_>,
        n: u32,
    ) {
        run_linear(
            pass,
            device,
            &self.gather_counts,
            &[
                (0, b.params),
                (2, b.tile_counts),
                (3, b.depth_order),
                (4, b.offsets),
            ],
            div_ceil(n + 1, 256),
        );
    }

    /// The plan of the rest of the frame (one invocation), then, for `n` Gaussians, the
    /// intersections it has room for.
    pub(crate) fn encode_intersections(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        device: &wgpu::Device,
        b: &IntersectionBuffers<'_>,
        n: u32,
    ) {
        run_linear(
            pass,
            device,
            &self.plan_intersections,
            &[
                (0, b.params),
                (4, b.offsets),
                (7, b.tile_plan),
                (8, b.tile_scan_plan),
                (9, b.status),
            ],
            1,
        );
        if n > 0 {
            run_linear(
                pass,
                device,
                &self.emit,
                &[
                    (0, b.params),
                    (1, b.projected),
                    (2, b.tile_counts),
                    (3, b.depth_order),
                    (4, b.offsets),
                    (5, b.keys),
                    (6, b.gaussians),
                    (7, b.tile_plan),
                ],
                div_ceil(n, 256),
            );
        }
    }

    /// Each tile's [start, end) in the tile-sorted `sorted_keys`, into `ranges` (cleared
    /// by the caller), dispatched with the size in `tile_plan`.
    pub(crate) fn encode_ranges(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        device: &wgpu::Device,
        tile_plan: &wgpu::Buffer,
        sorted_keys: &wgpu::Buffer,
        ranges: &wgpu::Buffer,
    ) {
        run_indirect(
            pass,
            device,
            &self.ranges,
            &[(0, tile_plan), (1, sorted_keys), (2, ranges)],
            tile_plan,
            RANGES_GROUPS_OFFSET,
        );
    }
}
