//! The small wgpu helpers every stage uses: compiling a kernel module, binding and
//! dispatching a pipeline, submitting with validation errors turned into
//! [`RasterError::Gpu`], reading a mapped buffer back.

use super::RasterError;
use crate::wgsl::KernelModule;

/// Largest workgroup count of one dispatch dimension.
const MAX_GROUPS_X: u32 = 65535;

pub(crate) fn div_ceil(a: u32, b: u32) -> u32 {
    a.div_ceil(b)
}

/// The (x, y, 1) grid [`dispatch_linear`] uses for `groups` workgroups (common.wgsl's
/// `dispatch_grid` computes the same on the GPU).
pub(crate) fn grid(groups: u32) -> [u32; 3] {
    if groups == 0 {
        return [0, 1, 1];
    }
    let x = groups.min(MAX_GROUPS_X);
    [x, div_ceil(groups, x), 1]
}

/// Dispatches `groups` workgroups as an (x, y) grid; shaders linearise and bound-check.
pub(crate) fn dispatch_linear(pass: &mut wgpu::ComputePass<'_>, groups: u32) {
    if groups == 0 {
        return;
    }
    let [x, y, z] = grid(groups);
    pass.dispatch_workgroups(x, y, z);
}

/// Compiles `module` and one compute pipeline per entry point, in the order given.
pub(crate) fn compile(
    device: &wgpu::Device,
    module: &KernelModule,
    entry_points: &[&str],
) -> Vec<wgpu::ComputePipeline> {
    let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(module.label),
        source: wgpu::ShaderSource::Wgsl(module.source().into()),
    });
    entry_points
        .iter()
        .map(|entry| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: None,
                module: &shader,
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

/// Binds `buffers` to `pipeline` and dispatches it with (x, y, z) workgroups read from
/// `indirect` at byte `offset` (written by the host or by an earlier kernel).
pub(crate) fn run_indirect(
    pass: &mut wgpu::ComputePass<'_>,
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[(u32, &wgpu::Buffer)],
    indirect: &wgpu::Buffer,
    offset: u64,
) {
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, &bind_group(device, pipeline, buffers), &[]);
    pass.dispatch_workgroups_indirect(indirect, offset);
}

/// Binds `buffers` to `pipeline` and dispatches one 16×16 workgroup per tile.
pub(crate) fn run_per_tile(
    pass: &mut wgpu::ComputePass<'_>,
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[(u32, &wgpu::Buffer)],
    tiles: (u32, u32),
) {
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, &bind_group(device, pipeline, buffers), &[]);
    pass.dispatch_workgroups(tiles.0, tiles.1, 1);
}

pub(crate) fn pop_error(scope: wgpu::ErrorScopeGuard) -> Result<(), RasterError> {
    match pollster::block_on(scope.pop()) {
        Some(e) => Err(RasterError::Gpu(e.to_string())),
        None => Ok(()),
    }
}

/// Submits `encoder`, turning validation errors into [`RasterError::Gpu`].
pub(crate) fn submit_checked(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    encoder: wgpu::CommandEncoder,
) -> Result<(), RasterError> {
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    queue.submit([encoder.finish()]);
    pop_error(scope)
}

/// Maps the first `bytes` of `staging` (a MAP_READ buffer whose copy has been submitted),
/// waits for the device and returns them.
pub(crate) fn read_mapped(
    device: &wgpu::Device,
    staging: &wgpu::Buffer,
    bytes: u64,
) -> Result<Vec<u8>, RasterError> {
    let slice = staging.slice(..bytes);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| RasterError::Gpu(e.to_string()))?;
    rx.recv()
        .map_err(|e| RasterError::Gpu(e.to_string()))?
        .map_err(|e| RasterError::Gpu(e.to_string()))?;
    let data = slice
        .get_mapped_range()
        .map_err(|e| RasterError::Gpu(e.to_string()))?
        .to_vec();
    staging.unmap();
    Ok(data)
}
