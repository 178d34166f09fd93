//! Compute pipelines and the small encoders shared by the forward and backward passes:
//! the exclusive prefix sum and the stable 4-bit LSD radix sort (shaders/scan.wgsl,
//! shaders/sort.wgsl).

use wgpu::util::DeviceExt;

pub(crate) const COMMON_WGSL: &str = include_str!("../../../../shaders/common.wgsl");
pub(crate) const GAUSSIAN_WGSL: &str = include_str!("../../../../shaders/gaussian.wgsl");
const SCAN_WGSL: &str = include_str!("../../../../shaders/scan.wgsl");
const SORT_WGSL: &str = include_str!("../../../../shaders/sort.wgsl");

/// Values per scan block and keys per sort block (256 invocations × 4).
pub(crate) const BLOCK: u32 = 1024;
const DIGITS: u32 = 16;
const BITS_PER_PASS: u32 = 4;
/// Largest workgroup count of one dispatch dimension.
const MAX_GROUPS_X: u32 = 65535;

pub(crate) fn div_ceil(a: u32, b: u32) -> u32 {
    a.div_ceil(b)
}

/// Dispatches `groups` workgroups as an (x, y) grid; shaders linearise and bound-check.
pub(crate) fn dispatch_linear(pass: &mut wgpu::ComputePass<'_>, groups: u32) {
    if groups == 0 {
        return;
    }
    let x = groups.min(MAX_GROUPS_X);
    pass.dispatch_workgroups(x, div_ceil(groups, x), 1);
}

pub(crate) fn compile(
    device: &wgpu::Device,
    label: &str,
    sources: &[&str],
    entry_points: &[&str],
) -> Vec<wgpu::ComputePipeline> {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(sources.concat().into()),
    });
    entry_points
        .iter()
        .map(|entry| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: None,
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        })
        .collect()
}

/// A bind group for group 0 of `pipeline`'s derived layout, which holds only the
/// bindings that entry point uses: pass exactly those, as (binding, buffer).
pub(crate) fn bind_group(
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[(u32, &wgpu::Buffer)],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .map(|(binding, b)| wgpu::BindGroupEntry {
            binding: *binding,
            resource: b.as_entire_binding(),
        })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    })
}

/// Binds `buffers` to `pipeline` and dispatches `groups` workgroups on `pass` (as
/// [`dispatch_linear`]): one stage of the rasteriser.
pub(crate) fn run_linear(
    pass: &mut wgpu::ComputePass<'_>,
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[(u32, &wgpu::Buffer)],
    groups: u32,
) {
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, &bind_group(device, pipeline, buffers), &[]);
    dispatch_linear(pass, groups);
}

pub(crate) fn uniform(device: &wgpu::Device, data: &[u32]) -> wgpu::Buffer {
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: None,
        contents: bytemuck::cast_slice(data),
        usage: wgpu::BufferUsages::UNIFORM,
    })
}

/// Words of a scan plan (scan.wgsl's `ScanPlan`) or sort plan (sort.wgsl's `SortPlan`):
/// a length, its number of blocks, and the (x, y, z) workgroups of the block-wise
/// dispatches, which are indirect from the plan.
pub(crate) const PLAN_WORDS: usize = 5;
/// Byte offset of the (x, y, z) workgroups in a plan.
const PLAN_GROUPS_OFFSET: u64 = 8;
/// Bytes of a plan buffer: room for the tile plan, which appends the ranges' dispatch.
const PLAN_BYTES: u64 = 32;

/// The (x, y, 1) grid [`dispatch_linear`] uses for `groups` workgroups (common.wgsl's
/// `dispatch_grid` computes the same on the GPU).
pub(crate) fn grid(groups: u32) -> [u32; 3] {
    if groups == 0 {
        return [0, 1, 1];
    }
    let x = groups.min(MAX_GROUPS_X);
    [x, div_ceil(groups, x), 1]
}

fn plan(len: u32, block: u32) -> [u32; PLAN_WORDS] {
    let blocks = div_ceil(len, block);
    let [x, y, z] = grid(blocks);
    [len, blocks, x, y, z]
}

/// The sort plan of `num_keys` keys and the plan of the digit-count scan inside each of
/// its passes (tiles.wgsl's `plan_intersections` writes the same for the tile sort).
pub(crate) fn sort_plans(num_keys: u32) -> ([u32; PLAN_WORDS], [u32; PLAN_WORDS]) {
    let sort = plan(num_keys, BLOCK);
    (sort, plan(DIGITS * sort[1], BLOCK))
}

/// The plan of a scan of `len` values.
pub(crate) fn scan_plan(len: u32) -> [u32; PLAN_WORDS] {
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
        queue.write_buffer(&self.sort, 0, bytemuck::cast_slice(&sort));
        queue.write_buffer(&self.scan, 0, bytemuck::cast_slice(&scan));
    }
}

/// Binds `buffers` to `pipeline` and dispatches it with the workgroups of `plan`.
fn run_planned(
    pass: &mut wgpu::ComputePass<'_>,
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[(u32, &wgpu::Buffer)],
    plan: &wgpu::Buffer,
) {
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, &bind_group(device, pipeline, buffers), &[]);
    pass.dispatch_workgroups_indirect(plan, PLAN_GROUPS_OFFSET);
}

/// Scan and sort pipelines.
pub(crate) struct SortKernels {
    scan_blocks: wgpu::ComputePipeline,
    scan_block_sums: wgpu::ComputePipeline,
    add_block_sums: wgpu::ComputePipeline,
    count_digits: wgpu::ComputePipeline,
    scatter: wgpu::ComputePipeline,
    /// The digit shift of each pass (sort.wgsl's `SortPass`), fixed, so made once.
    shifts: Vec<wgpu::Buffer>,
}

/// Scratch space a sort or scan of `len` values needs, in u32 elements:
/// (digit counts, block sums).
pub(crate) fn scratch_len(len: u32) -> (u32, u32) {
    let counts = DIGITS * div_ceil(len.max(1), BLOCK);
    let sums = div_ceil(counts.max(len + 1), BLOCK);
    (counts, sums)
}

impl SortKernels {
    pub(crate) fn new(device: &wgpu::Device) -> Self {
        let scan_entries = ["scan_blocks", "scan_block_sums", "add_block_sums"];
        let scan = compile(device, "scan", &[COMMON_WGSL, SCAN_WGSL], &scan_entries);
        let sort = compile(
            device,
            "sort",
            &[COMMON_WGSL, SORT_WGSL],
            &["count_digits", "scatter"],
        );
        let [scan_blocks, scan_block_sums, add_block_sums]: [wgpu::ComputePipeline; 3] =
            scan.try_into().expect("three scan entry points");
        let [count_digits, scatter]: [wgpu::ComputePipeline; 2] =
            sort.try_into().expect("two sort entry points");
        let shifts = (0..u32::BITS / BITS_PER_PASS)
            .map(|p| uniform(device, &[p * BITS_PER_PASS, 0, 0, 0]))
            .collect();
        Self {
            scan_blocks,
            scan_block_sums,
            add_block_sums,
            count_digits,
            scatter,
            shifts,
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
        run_planned(&mut pass, device, &self.scan_blocks, &all, plan);
        run_linear(
            &mut pass,
            device,
            &self.scan_block_sums,
            &[(0, plan), (2, block_sums)],
            1,
        );
        run_planned(&mut pass, device, &self.add_block_sums, &all, plan);
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
        for shift in &self.shifts[..passes as usize] {
            let dst = 1 - src;
            let count_bindings = [(0, shift), (1, keys[src]), (3, counts), (6, &plan.sort)];
            let scatter_bindings = [
                (0, shift),
                (1, keys[src]),
                (2, vals[src]),
                (3, counts),
                (4, keys[dst]),
                (5, vals[dst]),
                (6, &plan.sort),
            ];
            run_planned(
                &mut encoder.begin_compute_pass(&Default::default()),
                device,
                &self.count_digits,
                &count_bindings,
                &plan.sort,
            );
            self.encode_scan(device, encoder, counts, block_sums, &plan.scan);
            run_planned(
                &mut encoder.begin_compute_pass(&Default::default()),
                device,
                &self.scatter,
                &scatter_bindings,
                &plan.sort,
            );
            src = dst;
        }
        src
    }
}
