//! The viewer's 6-DoF camera: fly and orbit controls, the panorama viewpoint, the pose
//! string shared with `pano4d render --camera`, and the "outside the supported region" hint.
//!
//! Pure maths, no UI: the app feeds it key states and mouse deltas. Conventions are
//! docs/design.md's: world +z up, the panorama's camera at the origin looking along +x, and the
//! render camera in the OpenCV convention built by [`splat_core::camera::Camera::from_fov`].

use glam::{DMat4, DVec3, DVec4};
use serde::{Deserialize, Serialize};
use splat_core::camera::Camera;

/// Pitch stays this far from ±90° so that "no roll about +z" is always defined.
const MAX_PITCH_DEG: f64 = 89.0;
/// Horizontal field of view at start and after a reset.
pub const DEFAULT_FOV_DEG: f64 = 80.0;
pub const MIN_FOV_DEG: f64 = 10.0;
pub const MAX_FOV_DEG: f64 = 150.0;
/// The speed multiplier while shift is held.
pub const FAST_FACTOR: f64 = 4.0;
/// Walking speed as a fraction of the median Gaussian distance, per second.
const SPEED_PER_MEDIAN_DISTANCE: f64 = 0.2;
/// A panorama sees every surface from the origin only; beyond this fraction of the median
/// Gaussian distance, disocclusions (holes, stretched splats) become obvious.
pub const SUPPORTED_FRACTION: f64 = 0.3;
/// Radians of look rotation per pixel of mouse drag.
pub const LOOK_RADIANS_PER_PIXEL: f64 = 0.004;
/// OpenCV camera axes (x right, y down, z forward) to OpenGL ones (x right, y up, z back),
/// the axes of nerfstudio's `camera_to_world` (Python's `pano4d.camera.CV_TO_GL`).
const CV_TO_GL: DMat4 = DMat4::from_diagonal(DVec4::new(1.0, -1.0, -1.0, 1.0));

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraMode {
    /// WASD moves the eye, dragging turns the head.
    Fly,
    /// Dragging circles around a target point; WASD moves the target.
    Orbit,
}

/// How far the scene reaches, for speeds and the support hint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneExtent {
    /// Median distance of the Gaussians' means from the origin (the panorama's camera).
    pub median_distance: f64,
}

impl SceneExtent {
    /// The extent of the means (non-finite ones ignored); a unit extent for an empty set.
    /// Looks at most `max_samples` means, evenly strided, so that 10⁷ Gaussians stay cheap.
    pub fn of_means<'a>(
        means: impl ExactSizeIterator<Item = &'a [f32; 3]>,
        max_samples: usize,
    ) -> Self {
        let stride = means.len().div_ceil(max_samples.max(1)).max(1);
        let mut distances: Vec<f64> = means
            .step_by(stride)
            .map(|m| DVec3::new(m[0] as f64, m[1] as f64, m[2] as f64).length())
            .filter(|d| d.is_finite())
            .collect();
        if distances.is_empty() {
            return Self {
                median_distance: 1.0,
            };
        }
        let mid = distances.len() / 2;
        let (_, median, _) = distances.select_nth_unstable_by(mid, f64::total_cmp);
        Self {
            median_distance: median.max(1e-6),
        }
    }

    /// Movement speed (world units per second) that crosses the scene in a few seconds.
    pub fn walking_speed(&self) -> f64 {
        SPEED_PER_MEDIAN_DISTANCE * self.median_distance
    }
}

/// Key states for one frame of fly/orbit movement, each -1, 0 or +1.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MoveInput {
    /// W (+1) / S (-1): along the view direction.
    pub forward: f64,
    /// D (+1) / A (-1): along the view's right.
    pub right: f64,
    /// E (+1) / Q (-1): along world +z.
    pub up: f64,
    /// Shift: move [`FAST_FACTOR`] times faster.
    pub fast: bool,
}

impl MoveInput {
    pub fn is_idle(&self) -> bool {
        self.forward == 0.0 && self.right == 0.0 && self.up == 0.0
    }
}

/// A camera pose as one line of JSON, the format `pano4d render --camera` accepts:
/// `{"position":[x,y,z],"forward":[x,y,z],"fov_deg":f}` (horizontal FOV, +z up, no roll).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraPose {
    pub position: [f64; 3],
    pub forward: [f64; 3],
    pub fov_deg: f64,
}

impl CameraPose {
    /// Parses and checks a pose line: finite numbers, a non-zero forward, a FOV in (0, 180).
    pub fn parse(text: &str) -> Result<Self, String> {
        let pose: CameraPose = serde_json::from_str(text.trim()).map_err(|e| {
            format!(
                "invalid camera pose ({e}); expected {{\"position\":[x,y,z],\"forward\":[x,y,z],\
                 \"fov_deg\":f}}"
            )
        })?;
        let finite = pose
            .position
            .iter()
            .chain(&pose.forward)
            .all(|v| v.is_finite());
        if !finite || !pose.fov_deg.is_finite() {
            return Err("invalid camera pose: every number must be finite".into());
        }
        if DVec3::from_array(pose.forward).length() < 1e-9 {
            return Err("invalid camera pose: forward must not be the zero vector".into());
        }
        if !(pose.fov_deg > 0.0 && pose.fov_deg < 180.0) {
            return Err(format!(
                "invalid camera pose: fov_deg must lie in (0, 180), got {}",
                pose.fov_deg
            ));
        }
        Ok(pose)
    }

    /// The pose as one line of JSON.
    pub fn to_line(&self) -> String {
        serde_json::to_string(self).expect("a pose of finite numbers serialises")
    }
}

/// The viewer's camera state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewCamera {
    pub mode: CameraMode,
    /// Eye position in world coordinates.
    pub position: DVec3,
    /// Heading in radians about +z, 0 looking along +x, positive turning toward +y (left).
    pub yaw: f64,
    /// Elevation in radians, positive looking up.
    pub pitch: f64,
    /// Horizontal field of view in degrees.
    pub fov_deg: f64,
    /// World units per second in fly mode (before [`FAST_FACTOR`]).
    pub speed: f64,
    /// Orbit mode: the point the eye circles, and its distance from it.
    pub orbit_target: DVec3,
    pub orbit_distance: f64,
}

impl ViewCamera {
    /// The panorama's viewpoint: at the origin looking along +x, +z up, with a walking
    /// speed suited to `extent`.
    pub fn panorama_viewpoint(extent: &SceneExtent) -> Self {
        let distance = extent.median_distance;
        Self {
            mode: CameraMode::Fly,
            position: DVec3::ZERO,
            yaw: 0.0,
            pitch: 0.0,
            fov_deg: DEFAULT_FOV_DEG,
            speed: extent.walking_speed(),
            orbit_target: DVec3::X * distance,
            orbit_distance: distance,
        }
    }

    /// Unit view direction.
    pub fn forward(&self) -> DVec3 {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        DVec3::new(cp * cy, cp * sy, sp)
    }

    /// Unit right vector of the image (horizontal, OpenCV x axis in world coordinates).
    pub fn right(&self) -> DVec3 {
        let (sy, cy) = self.yaw.sin_cos();
        DVec3::new(sy, -cy, 0.0)
    }

    /// Points the camera along `direction` (need not be unit length, must be non-zero).
    pub fn look_along(&mut self, direction: DVec3) {
        let d = direction.normalize();
        self.yaw = d.y.atan2(d.x);
        let limit = MAX_PITCH_DEG.to_radians();
        self.pitch = d.z.clamp(-1.0, 1.0).asin().clamp(-limit, limit);
    }

    /// Switches between fly and orbit. Entering orbit keeps the eye where it is and
    /// circles the point `orbit_distance` ahead; leaving it keeps the current view.
    pub fn set_mode(&mut self, mode: CameraMode) {
        if mode == CameraMode::Orbit && self.mode != CameraMode::Orbit {
            self.orbit_target = self.position + self.forward() * self.orbit_distance;
        }
        self.mode = mode;
    }

    /// Turns the view by a mouse drag of (`dx`, `dy`) pixels: right drags look right, down
    /// drags look down. In orbit mode the eye moves around the target instead.
    pub fn drag(&mut self, dx: f64, dy: f64) {
        let limit = MAX_PITCH_DEG.to_radians();
        self.yaw -= dx * LOOK_RADIANS_PER_PIXEL;
        self.yaw = self.yaw.rem_euclid(std::f64::consts::TAU);
        self.pitch = (self.pitch - dy * LOOK_RADIANS_PER_PIXEL).clamp(-limit, limit);
        if self.mode == CameraMode::Orbit {
            self.position = self.orbit_target - self.forward() * self.orbit_distance;
        }
    }

    /// Moves for `dt` seconds with the given keys held. Fly: the eye moves along the view
    /// direction, the image's right and world up. Orbit: the target and eye move together.
    pub fn step(&mut self, input: &MoveInput, dt: f64) {
        let factor = if input.fast { FAST_FACTOR } else { 1.0 };
        let delta =
            (self.forward() * input.forward + self.right() * input.right + DVec3::Z * input.up)
                * (self.speed * factor * dt);
        self.position += delta;
        self.orbit_target += delta;
    }

    /// Scroll wheel: in fly mode scales the speed, in orbit mode the distance to the target.
    /// `ticks` > 0 speeds up / moves closer.
    pub fn scroll(&mut self, ticks: f64) {
        let factor = 1.1_f64.powf(ticks);
        match self.mode {
            CameraMode::Fly => self.speed = (self.speed * factor).clamp(1e-6, 1e6),
            CameraMode::Orbit => {
                self.orbit_distance = (self.orbit_distance / factor).clamp(1e-4, 1e6);
                self.position = self.orbit_target - self.forward() * self.orbit_distance;
            }
        }
    }

    /// Ctrl + scroll: narrows (ticks > 0) or widens the field of view.
    pub fn zoom(&mut self, ticks: f64) {
        self.fov_deg = (self.fov_deg * 1.05_f64.powf(-ticks)).clamp(MIN_FOV_DEG, MAX_FOV_DEG);
    }

    /// The OpenCV pinhole camera for a `width`×`height` image.
    pub fn to_camera(&self, width: u32, height: u32) -> Camera {
        Camera::from_fov(
            self.fov_deg,
            width,
            height,
            self.position,
            self.forward(),
            DVec3::Z,
        )
    }

    /// The vertical field of view in degrees of a `width`×`height` view ([`Self::fov_deg`]
    /// is the horizontal one).
    pub fn vertical_fov_deg(&self, width: u32, height: u32) -> f64 {
        2.0 * self
            .to_camera(width, height)
            .half_fov_tan
            .y
            .atan()
            .to_degrees()
    }

    /// Camera-to-world with OpenGL camera axes (x right, y up, looking along −z), nerfstudio's
    /// `camera_to_world`: the render camera's, as Python's `Camera.camera_to_world_gl`.
    pub fn camera_to_world_gl(&self) -> DMat4 {
        // The rotation does not depend on the image size.
        let camera = self.to_camera(1, 1);
        let to_world = camera.rotation.transpose();
        let camera_to_world = DMat4::from_cols(
            to_world.x_axis.extend(0.0),
            to_world.y_axis.extend(0.0),
            to_world.z_axis.extend(0.0),
            self.position.extend(1.0),
        );
        camera_to_world * CV_TO_GL
    }

    pub fn pose(&self) -> CameraPose {
        CameraPose {
            position: self.position.to_array(),
            forward: self.forward().to_array(),
            fov_deg: self.fov_deg,
        }
    }

    /// Takes position, direction and FOV from `pose` (mode, speed and orbit distance stay).
    pub fn set_pose(&mut self, pose: &CameraPose) {
        self.position = DVec3::from_array(pose.position);
        self.look_along(DVec3::from_array(pose.forward));
        self.fov_deg = pose.fov_deg.clamp(MIN_FOV_DEG, MAX_FOV_DEG);
        self.orbit_target = self.position + self.forward() * self.orbit_distance;
    }

    /// A warning when the eye has left the region a single panorama can show well.
    pub fn support_hint(&self, extent: &SceneExtent) -> Option<String> {
        let limit = SUPPORTED_FRACTION * extent.median_distance;
        let distance = self.position.length();
        (distance > limit).then(|| {
            format!(
                "{distance:.2} from the panorama's viewpoint (supported: about {limit:.2}); \
                 expect holes and stretched splats. Press R to go back."
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat3;

    /// Equality up to rounding, for scalars, vectors and matrices.
    trait Near: Copy + std::fmt::Debug {
        fn near(self, other: Self) -> bool;
    }

    impl Near for f64 {
        fn near(self, other: Self) -> bool {
            (self - other).abs() <= 1e-9 * (1.0 + other.abs())
        }
    }

    impl Near for DVec3 {
        fn near(self, other: Self) -> bool {
            self.abs_diff_eq(other, 1e-9)
        }
    }

    impl Near for DMat3 {
        fn near(self, other: Self) -> bool {
            self.abs_diff_eq(other, 1e-9)
        }
    }

    #[track_caller]
    fn assert_near<T: Near>(a: T, b: T) {
        assert!(a.near(b), "{a:?} != {b:?}");
    }

    fn extent() -> SceneExtent {
        SceneExtent {
            median_distance: 10.0,
        }
    }

    /// A camera away from the panorama's viewpoint, turned and tilted.
    fn moved_camera() -> ViewCamera {
        let mut cam = ViewCamera::panorama_viewpoint(&extent());
        cam.position = DVec3::new(0.5, -1.25, 2.0);
        cam.yaw = 2.0;
        cam.pitch = -0.3;
        cam
    }

    #[test]
    fn panorama_viewpoint_looks_along_x_from_origin() {
        let cam = ViewCamera::panorama_viewpoint(&extent());
        assert_eq!(cam.position, DVec3::ZERO);
        assert_near(cam.forward(), DVec3::X);
        // OpenCV: the image's right is world -y, its down is world -z.
        let c = cam.to_camera(64, 32);
        assert_near(c.rotation.row(0), DVec3::NEG_Y);
        assert_near(c.rotation.row(1), DVec3::NEG_Z);
        assert_near(c.rotation.row(2), DVec3::X);
        // A point straight ahead lands on the principal point.
        let (uv, z) = c.project(DVec3::new(5.0, 0.0, 0.0));
        assert_near(uv.x, 32.0);
        assert_near(uv.y, 16.0);
        assert_near(z, 5.0);
        assert_near(cam.speed, 2.0);
    }

    #[test]
    fn right_matches_the_render_camera_for_any_heading() {
        for i in 0..16 {
            let mut cam = ViewCamera::panorama_viewpoint(&extent());
            cam.yaw = i as f64 * 0.4;
            cam.pitch = (i as f64 * 0.3).sin();
            let c = cam.to_camera(100, 100);
            assert_near(c.rotation.row(0), cam.right());
            assert_near(c.rotation.row(2), cam.forward());
        }
    }

    #[test]
    fn fly_moves_along_view_right_and_up() {
        let mut cam = ViewCamera::panorama_viewpoint(&extent());
        let forward = MoveInput {
            forward: 1.0,
            ..Default::default()
        };
        cam.step(&forward, 0.5);
        assert_near(cam.position, DVec3::new(1.0, 0.0, 0.0));
        let right_fast = MoveInput {
            right: 1.0,
            fast: true,
            ..Default::default()
        };
        cam.step(&right_fast, 0.5);
        assert_near(cam.position, DVec3::new(1.0, -4.0, 0.0));
        let down = MoveInput {
            up: -1.0,
            ..Default::default()
        };
        cam.step(&down, 1.0);
        assert_near(cam.position, DVec3::new(1.0, -4.0, -2.0));
    }

    #[test]
    fn dragging_right_turns_right_and_pitch_is_clamped() {
        let mut cam = ViewCamera::panorama_viewpoint(&extent());
        cam.drag(100.0, 0.0);
        // Turning right from +x heads toward -y.
        assert!(cam.forward().y < -0.1, "{:?}", cam.forward());
        cam.drag(0.0, -1e6);
        assert_near(cam.pitch, MAX_PITCH_DEG.to_radians());
        cam.drag(0.0, 1e6);
        assert_near(cam.pitch, -MAX_PITCH_DEG.to_radians());
        // Still a valid rotation at the clamp.
        let c = cam.to_camera(10, 10);
        assert_near(c.rotation.determinant(), 1.0);
    }

    #[test]
    fn orbit_keeps_distance_to_target() {
        let mut cam = ViewCamera::panorama_viewpoint(&extent());
        cam.position = DVec3::new(1.0, 2.0, 0.5);
        cam.set_mode(CameraMode::Orbit);
        let target = cam.orbit_target;
        for (dx, dy) in [(50.0, 10.0), (-300.0, 40.0), (10.0, -90.0)] {
            cam.drag(dx, dy);
            assert_near(cam.position.distance(target), cam.orbit_distance);
            assert_near((target - cam.position).normalize(), cam.forward());
        }
        let before = cam.orbit_distance;
        cam.scroll(3.0);
        assert!(cam.orbit_distance < before);
        assert_near(cam.position.distance(target), cam.orbit_distance);
    }

    #[test]
    fn scroll_scales_speed_and_zoom_clamps_fov() {
        let mut cam = ViewCamera::panorama_viewpoint(&extent());
        cam.scroll(1.0);
        assert_near(cam.speed, 2.2);
        cam.scroll(-1.0);
        assert_near(cam.speed, 2.0);
        cam.zoom(1.0);
        assert!(cam.fov_deg < DEFAULT_FOV_DEG);
        cam.zoom(1e4);
        assert_eq!(cam.fov_deg, MIN_FOV_DEG);
        cam.zoom(-1e4);
        assert_eq!(cam.fov_deg, MAX_FOV_DEG);
    }

    #[test]
    fn pose_round_trips_through_its_line() {
        let mut cam = moved_camera();
        cam.fov_deg = 65.0;
        let line = cam.pose().to_line();
        assert!(!line.contains('\n'));
        let pose = CameraPose::parse(&line).unwrap();
        let mut back = ViewCamera::panorama_viewpoint(&extent());
        back.set_pose(&pose);
        assert_near(back.position, cam.position);
        assert_near(back.forward(), cam.forward());
        assert_eq!(back.fov_deg, 65.0);
        let a = back.to_camera(320, 200);
        let b = cam.to_camera(320, 200);
        assert_near(a.rotation, b.rotation);
    }

    #[test]
    fn opengl_camera_to_world_is_the_copied_pose() {
        let cam = moved_camera();
        let pose = CameraPose::parse(&cam.pose().to_line()).unwrap();
        let m = cam.camera_to_world_gl();
        // Row-major as the file holds it: the last row is exactly [0, 0, 0, 1].
        assert_eq!(m.row(3), DVec4::W);
        assert_eq!(m.w_axis.truncate(), DVec3::from_array(pose.position));
        // OpenGL: the camera looks along −z; x is the image's right, level (no roll); y is
        // the image's up, towards world +z.
        assert_near(-m.z_axis.truncate(), DVec3::from_array(pose.forward));
        assert_near(m.x_axis.truncate(), cam.right());
        assert_eq!(m.x_axis.z, 0.0);
        assert!(m.y_axis.z > 0.0);
        assert_near(m.y_axis.truncate(), cam.right().cross(cam.forward()));
        let rotation = DMat3::from_mat4(m);
        assert_near(rotation.transpose() * rotation, DMat3::IDENTITY);
        assert_near(rotation.determinant(), 1.0);
    }

    #[test]
    fn vertical_fov_of_a_view() {
        let cam = ViewCamera::panorama_viewpoint(&extent());
        assert_near(cam.vertical_fov_deg(100, 100), DEFAULT_FOV_DEG);
        let want = 2.0
            * (40.0_f64.to_radians().tan() * 9.0 / 16.0)
                .atan()
                .to_degrees();
        assert_near(cam.vertical_fov_deg(1600, 900), want);
    }

    #[test]
    fn bad_poses_are_rejected_with_a_reason() {
        let cases = [
            ("not json", "invalid camera pose"),
            (
                r#"{"position":[0,0,0],"forward":[0,0,0],"fov_deg":60}"#,
                "zero vector",
            ),
            (
                r#"{"position":[0,0,0],"forward":[1,0,0],"fov_deg":180}"#,
                "fov_deg",
            ),
            (
                r#"{"position":[0,0],"forward":[1,0,0],"fov_deg":60}"#,
                "invalid camera pose",
            ),
            (
                r#"{"position":[0,0,0],"forward":[1,0,0],"fov_deg":60,"x":1}"#,
                "unknown field",
            ),
        ];
        for (text, reason) in cases {
            let err = CameraPose::parse(text).unwrap_err();
            assert!(err.contains(reason), "{text}: {err}");
        }
    }

    #[test]
    fn support_hint_appears_beyond_the_supported_fraction() {
        let mut cam = ViewCamera::panorama_viewpoint(&extent());
        assert!(cam.support_hint(&extent()).is_none());
        cam.position = DVec3::new(0.0, 2.9, 0.0);
        assert!(cam.support_hint(&extent()).is_none());
        cam.position = DVec3::new(0.0, 3.1, 0.0);
        assert!(cam.support_hint(&extent()).unwrap().contains("Press R"));
    }

    #[test]
    fn extent_is_the_median_distance() {
        let means: Vec<[f32; 3]> = (1..=101).map(|i| [i as f32, 0.0, 0.0]).collect();
        let e = SceneExtent::of_means(means.iter(), 1000);
        assert_near(e.median_distance, 51.0);
        let with_nan = [[f32::NAN, 0.0, 0.0], [3.0, 4.0, 0.0]];
        assert_near(
            SceneExtent::of_means(with_nan.iter(), 10).median_distance,
            5.0,
        );
        assert_eq!(SceneExtent::of_means([].iter(), 10).median_distance, 1.0);
        // Sampling keeps the estimate close.
        let sampled = SceneExtent::of_means(means.iter(), 10).median_distance;
        assert!((sampled - 51.0).abs() <= 10.0, "{sampled}");
    }
}
