//! Rendering without a window: one view of a scene at one timestamp, through the same
//! [`FrameRenderer`] the window uses. `pano4d-view --headless`, the tests and the
//! benchmark call it.

use std::path::Path;

use image::RgbaImage;

use crate::camera::{CameraPose, ViewCamera};
use crate::render::{FrameOptions, FrameRenderer};
use crate::scene::Scene;

/// Which timestamp to draw.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TimeSelection {
    /// The timestamp nearest to this many seconds.
    Seconds(f64),
    /// A timestamp index.
    Index(usize),
}

/// One headless view.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewRequest {
    /// `None`: the panorama's viewpoint (origin, looking along +x).
    pub pose: Option<CameraPose>,
    pub time: TimeSelection,
    pub width: u32,
    pub height: u32,
    pub options: FrameOptions,
}

impl Default for ViewRequest {
    fn default() -> Self {
        Self {
            pose: None,
            time: TimeSelection::Index(0),
            width: 1280,
            height: 720,
            options: FrameOptions::default(),
        }
    }
}

/// Draws `request` of an opened `scene` with `renderer` (which must have loaded it).
pub fn render_view(
    renderer: &mut FrameRenderer,
    scene: &Scene,
    request: &ViewRequest,
) -> Result<RgbaImage, String> {
    let index = match request.time {
        TimeSelection::Seconds(s) if s.is_finite() => scene.index_at(s),
        TimeSelection::Seconds(s) => return Err(format!("time must be finite, got {s}")),
        TimeSelection::Index(i) if i < scene.num_times() => i,
        TimeSelection::Index(i) => {
            return Err(format!(
                "frame {i} out of range: the scene has {} timestamps",
                scene.num_times()
            ))
        }
    };
    let mut camera = ViewCamera::panorama_viewpoint(&scene.extent);
    if let Some(pose) = &request.pose {
        camera.set_pose(pose);
        // set_pose clamps to the viewer's zoom range; a headless view takes the FOV as given.
        camera.fov_deg = pose.fov_deg;
    }
    renderer.show_time(scene, index as f64)?;
    renderer.render(
        &camera.to_camera(request.width, request.height),
        &request.options,
    )
}

/// Opens `path` on a device of its own and draws `request`.
pub fn render_file(path: &Path, request: &ViewRequest) -> Result<RgbaImage, String> {
    let scene = Scene::open(path)?;
    let mut renderer = FrameRenderer::headless()?;
    renderer.load_scene(&scene);
    render_view(&mut renderer, &scene, request)
}
