//! The viewer's last pass (`present.wgsl`): a frame's colours written into an RGBA8
//! texture ([`target_texture`]) that egui samples, without the image leaving the GPU.

use super::gpu::compile;
use super::COMMON_WGSL;
use crate::wgsl::{KernelModule, WgslPart};

const PRESENT_WGSL: WgslPart = WgslPart {
    file: "present.wgsl",
    source: include_str!("present.wgsl"),
    needs: &[COMMON_WGSL.file],
    reads: &[],
};

pub(crate) fn module() -> KernelModule {
    KernelModule {
        label: "present",
        parts: vec![&COMMON_WGSL, &PRESENT_WGSL],
    }
}

/// The texture format [`super::Renderer::draw`] writes: the forward's colours (display
/// values, clamped to 0..1) as 8-bit RGBA, sampled as they are (egui takes texture samples
/// as display values).
pub const TARGET_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// A texture [`super::Renderer::draw`] can write, egui can sample and
/// [`super::Renderer::read_rgba8`] can copy out.
pub fn target_texture(device: &wgpu::Device, width: u32, height: u32) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some("render target"),
        size: wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: TARGET_FORMAT,
        usage: wgpu::TextureUsages::STORAGE_BINDING
            | wgpu::TextureUsages::TEXTURE_BINDING
            | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    })
}

pub(crate) struct PresentKernel {
    pipeline: wgpu::ComputePipeline,
}

impl PresentKernel {
    pub(crate) fn new(device: &wgpu::Device) -> Self {
        Self {
            pipeline: compile(device, &module(), &["main"]).remove(0),
        }
    }

    /// Converts the forward's `pixels` (a frame of `params`, one 16×16 workgroup per tile)
    /// into `target`.
    pub(crate) fn encode(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        device: &wgpu::Device,
        params: &wgpu::Buffer,
        pixels: &wgpu::Buffer,
        target: &wgpu::TextureView,
        tiles: (u32, u32),
    ) {
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("present"),
            layout: &self.pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: params.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: pixels.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(target),
                },
            ],
        });
        let mut pass = encoder.begin_compute_pass(&Default::default());
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(tiles.0, tiles.1, 1);
    }
}
