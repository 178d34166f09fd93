//! Rendering without a window: one view of a scene at one time, through the same
//! [`FrameRenderer`] the window uses. `pano4d-view --headless`, the tests and the
//! benchmark call it.

use std::path::Path;

use image::RgbaImage;

use crate::camera::{CameraPose, ViewCamera};
use crate::render::{FrameOptions, FrameRenderer};
use crate::scene::Scene;
use crate::time::TimeControl;

/// Which time to draw.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TimeSelection {
    /// Seconds on the timestamps' clock, round the loop, as the window plays them
    /// ([`TimeControl::set_seconds`]): a version-2 scene at that real time, any other at the
    /// timestamp holding it (the last at or before it).
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
    let frame = match request.time {
        TimeSelection::Seconds(s) if s.is_finite() => {
            let mut time = TimeControl::new(&scene.timestamps, scene.timeline());
            time.set_seconds(s);
            time.frame()
        }
        TimeSelection::Seconds(s) => return Err(format!("time must be finite, got {s}")),
        TimeSelection::Index(i) if i < scene.num_times() => i as f64,
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
    renderer.show_time(scene, frame)?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic;
    use splat_core::ply4d;

    /// Draws `time` of `scene`; the time drawn and the image.
    fn draw(
        renderer: &mut FrameRenderer,
        scene: &Scene,
        time: TimeSelection,
    ) -> (Option<f64>, RgbaImage) {
        let request = ViewRequest {
            time,
            width: 96,
            height: 64,
            ..Default::default()
        };
        let image = render_view(renderer, scene, &request).unwrap();
        (renderer.shown_time(), image)
    }

    #[test]
    fn seconds_are_a_real_time_in_version_2_and_held_otherwise() {
        let dir = std::env::temp_dir().join(format!("pano4d-headless-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // Four timestamps at synthetic::FPS (10): 0.1 s apart.
        let v2 = dir.join("v2.ply4d");
        ply4d::write_spacetime(&v2, &synthetic::spacetime_scene(2_000, 400, 4, 0, 2)).unwrap();
        let v1 = dir.join("v1.ply4d");
        ply4d::write(&v1, &synthetic::scene(2_000, 400, 4, 0, 2)).unwrap();
        let [v2, v1] = [v2, v1].map(|path| Scene::open(&path).unwrap());
        std::fs::remove_dir_all(&dir).unwrap();

        let mut renderer = FrameRenderer::headless().unwrap();
        renderer.load_scene(&v2);
        let (shown, between) = draw(&mut renderer, &v2, TimeSelection::Seconds(0.15));
        assert_eq!(shown, Some(1.5));
        for t in [1, 2] {
            assert_ne!(draw(&mut renderer, &v2, TimeSelection::Index(t)).1, between);
        }
        let (shown, _) = draw(&mut renderer, &v2, TimeSelection::Seconds(0.45));
        assert!(
            (shown.unwrap() - 0.5).abs() < 1e-9,
            "round the loop: {shown:?}"
        );

        renderer.load_scene(&v1);
        let (shown, held) = draw(&mut renderer, &v1, TimeSelection::Seconds(0.19));
        assert_eq!(
            shown,
            Some(1.0),
            "the timestamp holding 0.19 s, not the nearest"
        );
        assert_eq!(draw(&mut renderer, &v1, TimeSelection::Index(1)).1, held);
    }
}
