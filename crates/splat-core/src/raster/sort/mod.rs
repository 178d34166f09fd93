//! The exclusive prefix sum (`scan.wgsl`) and the stable 4-bit LSD radix sort around it
//! (`sort.wgsl`): the depth sort and the tile sort of every frame, and the scan of the
//! tile counts. Their lengths come from a [`DispatchPlan`] buffer (written by the host, or
//! by tiles.wgsl's `plan_intersections` for the tile sort) and their block-wise
//! dispatches are indirect from it.

use super::gpu::{compile, div_ceil, grid, run_indirect, run_linear};
use crate::wgsl::{gpu_struct, KernelModule, WgslPart};
use wgpu::util::DeviceExt;

/// The plan struct both kernels read (and tiles.wgsl writes as words).
pub(crate) const PLAN_WGSL: WgslPart = WgslPart {
    file: "plan.wgsl",
    source: include_str!("plan.wgsl"),
    needs: &[],
    reads: &[],
};
const SCAN_WGSL: WgslPart = WgslPart {
    file: "scan.wgsl",
    source: include_str!("scan.wgsl"),
    needs: &[super::COMMON_WGSL.file, PLAN_WGSL.file],
    reads: &[],
};
const SORT_WGSL: WgslPart = WgslPart {
    file: "sort.wgsl",
    source: include_str!("sort.wgsl"),
    needs: &[super::COMMON_WGSL.file, PLAN_WGSL.file],
    reads: &[],
};

pub(crate) fn scan_module() -> KernelModule {
    KernelModule {
        label: "scan",
        parts: vec![&super::COMMON_WGSL, &PLAN_WGSL, &SCAN_WGSL],
    }
}

pub(crate) fn sort_module() -> KernelModule {
    KernelModule {
        label: "sort",
        parts: vec![&super::COMMON_WGSL, &PLAN_WGSL, &SORT_WGSL],
    }
}

/// Values per scan block and keys per sort block (256 invocations × 4).
pub(crate) const BLOCK: u32 = 1024;
const DIGITS: u32 = 16;
const BITS_PER_PASS: u32 = 4;

gpu_struct! {
    /// The size of a scan or sort: its length, its number of blocks, and the (x, y, z)
    /// workgroups of its block-wise dispatches (an indirect dispatch's arguments).
    pub(crate) struct DispatchPlan {
        pub len: u32,
        pub num_blocks: u32,
        pub groups_x: u32,
        pub groups_y: u32,
        pub groups_z: u32,
    }
}

gpu_struct! {
    /// The uniform of one sort pass: the shift of its digit.
    pub(crate) struct SortPass {
        shift: u32,
        pad0: u32,
        pad1: u32,
        pad2: u32,
    }
}

/// Byte offset of the (x, y, z) workgroups in a plan.
const PLAN_GROUPS_OFFSET: u64 = std::mem::offset_of!(DispatchPlan, groups_x) as u64;
/// Bytes of a plan buffer: room for the tile plan, which appends the ranges' dispatch.
const PLAN_BYTES: u64 = 32;

fn plan(len: u32, block: u32) -> DispatchPlan {
    let num_blocks = div_ceil(len, block);
    let [groups_x, groups_y, groups_z] = grid(num_blocks);
    DispatchPlan {
        len,
        num_blocks,
        groups_x,
        groups_y,
        groups_z,
    }
}

/// The sort plan of `num_keys` keys and the plan of the digit-count scan inside each of
/// its passes (tiles.wgsl's `plan_intersections` writes the same for the tile sort).
pub(crate) fn sort_plans(num_keys: u32) -> (DispatchPlan, DispatchPlan) {
    let sort = plan(num_keys, BLOCK);
    (sort, plan(DIGITS * sort.num_blocks, BLOCK))
}

/// The plan of a scan of `len` values.
pub(crate) fn scan_plan(len: u32) -> DispatchPlan {
    plan(len, BLOCK)
}

/// A buffer for a scan or sort plan: written by the host (`queue.write_buffer`) or by a
/// kernel, read by the kernels and as their indirect dispatch sizes.
pub(crate) fn plan_buffer(device: &wgpu::Device, label: &str) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: PLAN_BYTES,
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::INDIRECT
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    })
}

/// The two plans of one sort: its own and that of the scan inside each pass.
pub(crate) struct SortPlan {
    pub(crate) sort: wgpu::Buffer,
    pub(crate) scan: wgpu::Buffer,
}

impl SortPlan {
    pub(crate) fn new(device: &wgpu::Device, label: &str) -> Self {
        Self {
            sort: plan_buffer(device, label),
            scan: plan_buffer(device, label),
        }
    }

    /// Sizes the sort for `num_keys` keys from the host (before the next submit).
    pub(crate) fn write(&self, queue: &wgpu::Queue, num_keys: u32) {
        let (sort, scan) = sort_plans(num_keys);
        queue.write_buffer(&self.sort, 0, bytemuck::bytes_of(&sort));
        queue.write_buffer(&self.scan, 0, bytemuck::bytes_of(&scan));
    }
}

/// Scratch space a sort or scan of `len` values needs, in u32 elements:
/// (digit counts, block sums).
pub(crate) fn scratch_len(len: u32) -> (u32, u32) {
    let counts = DIGITS * div_ceil(len.max(1), BLOCK);
    let sums = div_ceil(counts.max(len + 1), BLOCK);
    (counts, sums)
}

/// Scan and sort pipelines.
pub(crate) struct SortKernels {
    scan_blocks: wgpu::ComputePipeline,
    scan_block_sums: wgpu::ComputePipeline,
    add_block_sums: wgpu::ComputePipeline,
    count_digits: wgpu::ComputePipeline,
    scatter: wgpu::ComputePipeline,
    /// The uniform of each pass, fixed, so made once.
    passes: Vec<wgpu::Buffer>,
}

impl SortKernels {
    pub(crate) fn new(device: &wgpu::Device) -> Self {
        let scan_entries = ["scan_blocks", "scan_block_sums", "add_block_sums"];
        let [scan_blocks, scan_block_sums, add_block_sums]: [wgpu::ComputePipeline; 3] =
            compile(device, &scan_module(), &scan_entries)
                .try_into()
                .expect("three scan entry points");
        let [count_digits, scatter]: [wgpu::ComputePipeline; 2] =
            compile(device, &sort_module(), &["count_digits", "scatter"])
                .try_into()
                .expect("two sort entry points");
        let passes = (0..u32::BITS / BITS_PER_PASS)
            .map(|p| {
                let pass = SortPass {
                    shift: p * BITS_PER_PASS,
                    pad0: 0,
                    pad1: 0,
                    pad2: 0,
                };
                device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("sort pass"),
                    contents: bytemuck::bytes_of(&pass),
                    usage: wgpu::BufferUsages::UNIFORM,
                })
            })
            .collect();
        Self {
            scan_blocks,
            scan_block_sums,
            add_block_sums,
            count_digits,
            scatter,
            passes,
        }
    }

    /// Exclusive prefix sum, in place, of the first `plan.len` u32 of `data`.
    pub(crate) fn encode_scan(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        data: &wgpu::Buffer,
        block_sums: &wgpu::Buffer,
        plan: &wgpu::Buffer,
    ) {
        let mut pass = encoder.begin_compute_pass(&Default::default());
        let all = [(0, plan), (1, data), (2, block_sums)];
        let at = PLAN_GROUPS_OFFSET;
        run_indirect(&mut pass, device, &self.scan_blocks, &all, plan, at);
        run_linear(
            &mut pass,
            device,
            &self.scan_block_sums,
            &[(0, plan), (2, block_sums)],
            1,
        );
        run_indirect(&mut pass, device, &self.add_block_sums, &all, plan, at);
    }

    /// Stable sort of the (key, value) pairs `plan` counts by the low `bits` bits of the
    /// key. Ping-pongs between `keys[0]/vals[0]` (input) and `keys[1]/vals[1]`; returns the
    /// index of the pair that holds the result.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn encode_sort(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        keys: [&wgpu::Buffer; 2],
        vals: [&wgpu::Buffer; 2],
        counts: &wgpu::Buffer,
        block_sums: &wgpu::Buffer,
        plan: &SortPlan,
        bits: u32,
    ) -> usize {
        let passes = div_ceil(bits, BITS_PER_PASS);
        let mut src = 0;
        for sort_pass in &self.passes[..passes as usize] {
            let dst = 1 - src;
            let count_bindings = [(0, sort_pass), (1, keys[src]), (3, counts), (6, &plan.sort)];
            let scatter_bindings = [
                (0, sort_pass),
                (1, keys[src]),
                (2, vals[src]),
                (3, counts),
                (4, keys[dst]),
                (5, vals[dst]),
                (6, &plan.sort),
            ];
            run_indirect(
                &mut encoder.begin_compute_pass(&Default::default()),
                device,
                &self.count_digits,
                &count_bindings,
                &plan.sort,
                PLAN_GROUPS_OFFSET,
            );
            self.encode_scan(device, encoder, counts, block_sums, &plan.scan);
            run_indirect(
                &mut encoder.begin_compute_pass(&Default::default()),
                device,
                &self.scatter,
                &scatter_bindings,
                &plan.sort,
                PLAN_GROUPS_OFFSET,
            );
            src = dst;
        }
        src
    }
}
