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

/// Scan and sort pipelines.
pub(crate) struct SortKernels {
    scan_blocks: wgpu::ComputePipeline,
    scan_block_sums: wgpu::ComputePipeline,
    add_block_sums: wgpu::ComputePipeline,
    count_digits: wgpu::ComputePipeline,
    scatter: wgpu::ComputePipeline,
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
        Self {
            scan_blocks,
            scan_block_sums,
            add_block_sums,
            count_digits,
            scatter,
        }
    }

    /// Exclusive prefix sum of the first `len` u32 of `data`, in place.
    pub(crate) fn encode_scan(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        data: &wgpu::Buffer,
        block_sums: &wgpu::Buffer,
        len: u32,
    ) {
        if len == 0 {
            return;
        }
        let num_blocks = div_ceil(len, BLOCK);
        let params = uniform(device, &[len, num_blocks, 0, 0]);
        let mut pass = encoder.begin_compute_pass(&Default::default());
        let all = [(0, &params), (1, data), (2, block_sums)];
        let sums_only = [(0, &params), (2, block_sums)];
        for (pipeline, bindings, groups) in [
            (&self.scan_blocks, &all[..], num_blocks),
            (&self.scan_block_sums, &sums_only[..], 1),
            (&self.add_block_sums, &all[..], num_blocks),
        ] {
            run_linear(&mut pass, device, pipeline, bindings, groups);
        }
    }

    /// Stable sort of `num_keys` (key, value) pairs by the low `bits` bits of the key.
    /// Ping-pongs between `keys[0]/vals[0]` (input) and `keys[1]/vals[1]`; returns the
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
        num_keys: u32,
        bits: u32,
    ) -> usize {
        if num_keys <= 1 {
            return 0;
        }
        let num_blocks = div_ceil(num_keys, BLOCK);
        let passes = div_ceil(bits, BITS_PER_PASS);
        let mut src = 0;
        for p in 0..passes {
            let dst = 1 - src;
            let params = uniform(device, &[num_keys, p * BITS_PER_PASS, num_blocks, 0]);
            let count_bindings = [(0, &params), (1, keys[src]), (3, counts)];
            let scatter_bindings = [
                (0, &params),
                (1, keys[src]),
                (2, vals[src]),
                (3, counts),
                (4, keys[dst]),
                (5, vals[dst]),
            ];
            run_linear(
                &mut encoder.begin_compute_pass(&Default::default()),
                device,
                &self.count_digits,
                &count_bindings,
                num_blocks,
            );
            self.encode_scan(device, encoder, counts, block_sums, DIGITS * num_blocks);
            run_linear(
                &mut encoder.begin_compute_pass(&Default::default()),
                device,
                &self.scatter,
                &scatter_bindings,
                num_blocks,
            );
            src = dst;
        }
        src
    }
}
