//! One frame's results on the GPU and what the renderer's status buffer says about
//! frames: the types [`super::Renderer::encode_frame`] and
//! [`super::Renderer::check_intersections`] return.

use super::gpu_scene::SceneBuffer;
use super::params::RenderParams;

/// Words of the renderer's status buffer (tiles.wgsl, `plan_intersections`): frames that
/// overflowed and the most intersections of any frame (both counting only the frames of
/// `encode_frame`, and only growing), then the last frame's intersections and whether it
/// was drawn (1) or overflowed (0).
pub(crate) const STATUS_WORDS: usize = 4;
/// Index of the status word that says whether the last frame was drawn (1) or overflowed
/// its intersection buffers and drew only the background (0).
pub const STATUS_DRAWN: usize = 3;

/// What [`super::Renderer::check_intersections`] found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IntersectionCheck {
    /// Frames of `encode_frame` since the last check that had more tile intersections than
    /// room: each drew only the background and gave zero gradients.
    pub overflowed: u32,
    /// The most tile intersections of any frame of `encode_frame` so far.
    pub max_intersections: u32,
    /// Room per frame from now on: at least a quarter more than `max_intersections`
    /// (unless that is past the device's binding limit).
    pub capacity: u32,
}

/// One frame's results on the GPU, from [`super::Renderer::encode_frame`] (the forward's
/// output is at [`super::Renderer::frame_pixels`], its status at
/// [`super::Renderer::frame_status`]): what its backward needs. The buffers are the
/// renderer's own: the next `encode_frame` on the same renderer overwrites them.
pub struct Frame {
    pub(super) scene: SceneBuffer,
    pub(super) params: RenderParams,
    pub(super) projected: wgpu::Buffer,
    pub(super) tile_counts: wgpu::Buffer,
    /// Gaussian ids of the intersections, sorted by tile (depth order within a tile).
    pub(super) sorted_gaussians: wgpu::Buffer,
    pub(super) ranges: wgpu::Buffer,
    pub(super) pixel_state: wgpu::Buffer,
    pub(super) pixels: wgpu::Buffer,
}

impl Frame {
    /// (width, height) in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.params.width, self.params.height)
    }

    pub fn num_gaussians(&self) -> u32 {
        self.params.num_gaussians
    }
}
