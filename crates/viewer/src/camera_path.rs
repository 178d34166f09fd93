//! Camera paths made in the viewer: keyframes taken from the view, interpolated as
//! nerfstudio's viewer interpolates them ([`crate::spline`]) and saved as nerfstudio's
//! `camera_path.json`, which `pano4d render scene.ply4d --path camera_path.json --out v.mp4`
//! renders (python/pano4d/nerfstudio_path.py reads it, as ns-render does).
//!
//! The file holds what nerfstudio's viewer writes (render_panel.py, `_write_json`):
//! - `camera_type` "perspective", `render_width`, `render_height`, `fps`, `seconds`;
//! - `keyframes`, enough to load them again (nerfstudio's viewer does): each `matrix`
//!   (camera-to-world, 16 numbers, row-major, OpenGL camera axes), `fov` (vertical, degrees),
//!   `aspect` (width / height of the view it was taken in) and, for a dynamic scene,
//!   `render_time` with `override_time_enabled: true` (so that nerfstudio's viewer keeps each
//!   keyframe's time); `default_transition_sec` (seconds between keyframes), `is_cycle`
//!   (false: the path does not loop) and `smoothness_value` (the spline tension) beside them;
//! - `camera_path`, the video: round(seconds × fps) frames, each `camera_to_world`, `fov`,
//!   `aspect` (the render size's) and, for a dynamic scene, `render_time`.
//!
//! Poses are in the scene's own coordinates. A keyframe's `render_time` is the shown time
//! over the loop, frame / timestamps: 0 its start, 1 its end (which is the start again);
//! `render_time` × timestamps is the scene time a reader shows. Interpolated times are
//! clamped to [0, 1], which the format requires and a spline may overshoot.
//!
//! One difference from nerfstudio's viewer: frame i of N lies i / (N − 1) of the way along
//! the path, not i / N, so that the video starts on the first keyframe and ends on the last
//! (nerfstudio's ends one frame short of its last keyframe unless the path loops).

use std::io::Write;
use std::path::Path;

use glam::{DMat3, DMat4, DQuat, DVec3};
use serde::Serialize;

use crate::camera::ViewCamera;
use crate::spline::{RotationSpline, Spline, TENSION};

/// What the file is called when the viewer proposes where to save it.
pub const FILE_NAME: &str = "camera_path.json";

/// One camera of a path: a keyframe's or a video frame's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathCamera {
    /// Camera-to-world with OpenGL camera axes (x right, y up, looking along −z).
    pub camera_to_world: DMat4,
    /// Vertical field of view in degrees.
    pub fov_deg: f64,
    /// The scene time over its loop, in [0, 1]; `None` for a static scene.
    pub render_time: Option<f64>,
}

/// A keyframe: a camera, and the shape of the view it was taken in.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Keyframe {
    pub camera: PathCamera,
    /// Width / height of the view.
    pub aspect: f64,
}

impl Keyframe {
    /// What `camera` shows in a `width`×`height` view at `render_time`.
    pub fn of_view(camera: &ViewCamera, width: u32, height: u32, render_time: Option<f64>) -> Self {
        Self {
            camera: PathCamera {
                camera_to_world: camera.camera_to_world_gl(),
                fov_deg: camera.vertical_fov_deg(width, height),
                render_time,
            },
            aspect: width as f64 / height as f64,
        }
    }
}

/// The video a path makes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Video {
    pub width: u32,
    pub height: u32,
    pub fps: f64,
    pub seconds: f64,
}

impl Default for Video {
    /// `pano4d render`'s size; 4 s at 30 fps.
    fn default() -> Self {
        Self {
            width: 1280,
            height: 720,
            fps: 30.0,
            seconds: 4.0,
        }
    }
}

impl Video {
    /// Frames in the video: round(seconds × fps); 0 where that is no number of frames.
    pub fn frame_count(&self) -> usize {
        let frames = (self.seconds * self.fps).round();
        if frames.is_finite() && frames >= 0.0 {
            frames as usize
        } else {
            0
        }
    }

    /// The frame count, or why these settings make no video.
    fn checked_frame_count(&self) -> Result<usize, String> {
        if !(self.fps.is_finite() && self.fps > 0.0) {
            return Err(format!("fps must be a frame rate > 0, got {}", self.fps));
        }
        if !(self.seconds.is_finite() && self.seconds > 0.0) {
            return Err(format!(
                "seconds must be a duration > 0, got {}",
                self.seconds
            ));
        }
        if self.width == 0 || self.height == 0 {
            return Err(format!(
                "the render size must be at least 1×1 pixels, got {}×{}",
                self.width, self.height
            ));
        }
        match self.frame_count() {
            0 => Err(format!(
                "{} s at {} fps makes no frame (round(seconds × fps) = 0)",
                self.seconds, self.fps
            )),
            frames => Ok(frames),
        }
    }
}

/// The curve through two or more keyframes: position, orientation, field of view and (when
/// every keyframe has one) scene time, each a spline over the keyframes' index.
pub struct Interpolation {
    /// The last keyframe's index: the path's parameter runs over [0, last].
    last: f64,
    position: [Spline; 3],
    rotation: RotationSpline,
    fov: Spline,
    time: Option<Spline>,
}

impl Interpolation {
    /// The curve through `keyframes`, at least two.
    pub fn new(keyframes: &[PathCamera]) -> Result<Self, String> {
        if keyframes.len() < 2 {
            return Err(format!(
                "a camera path needs at least two keyframes, it has {}",
                keyframes.len()
            ));
        }
        let spline =
            |value: &dyn Fn(&PathCamera) -> f64| Spline::new(keyframes.iter().map(value).collect());
        let rotations: Vec<DQuat> = keyframes
            .iter()
            .map(|k| DQuat::from_mat3(&DMat3::from_mat4(k.camera_to_world)))
            .collect();
        let times: Option<Vec<f64>> = keyframes.iter().map(|k| k.render_time).collect();
        Ok(Self {
            last: (keyframes.len() - 1) as f64,
            position: [0, 1, 2].map(|axis| spline(&|k| k.camera_to_world.w_axis[axis])),
            rotation: RotationSpline::new(&rotations),
            fov: spline(&|k| k.fov_deg),
            time: times.map(Spline::new),
        })
    }

    /// The camera at `s` keyframes along the path, in [0, keyframes − 1].
    pub fn at(&self, s: f64) -> PathCamera {
        let position = DVec3::from_array(self.position.each_ref().map(|p| p.at(s)));
        PathCamera {
            camera_to_world: DMat4::from_rotation_translation(self.rotation.at(s), position),
            fov_deg: self.fov.at(s),
            render_time: self.time.as_ref().map(|t| t.at(s).clamp(0.0, 1.0)),
        }
    }

    /// `count` cameras evenly along the path, from the first keyframe to the last: each
    /// transition between keyframes takes the same time.
    pub fn frames(&self, count: usize) -> Vec<PathCamera> {
        (0..count)
            .map(|i| match count {
                1 => self.at(0.0),
                _ => self.at(i as f64 * self.last / (count - 1) as f64),
            })
            .collect()
    }
}

/// The 16 numbers of `m`, row by row.
fn row_major(m: &DMat4) -> [f64; 16] {
    m.transpose().to_cols_array()
}

#[derive(Serialize)]
struct FileJson {
    camera_type: &'static str,
    render_width: u32,
    render_height: u32,
    fps: f64,
    seconds: f64,
    is_cycle: bool,
    smoothness_value: f64,
    default_transition_sec: f64,
    keyframes: Vec<KeyframeJson>,
    camera_path: Vec<FrameJson>,
}

#[derive(Serialize)]
struct KeyframeJson {
    matrix: [f64; 16],
    fov: f64,
    aspect: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    render_time: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    override_time_enabled: Option<bool>,
}

#[derive(Serialize)]
struct FrameJson {
    camera_to_world: [f64; 16],
    fov: f64,
    aspect: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    render_time: Option<f64>,
}

/// The `camera_path.json` of `keyframes` (at least two) making `video`, one line of JSON.
pub fn to_json(keyframes: &[Keyframe], video: &Video) -> Result<String, String> {
    let count = video.checked_frame_count()?;
    let cameras: Vec<PathCamera> = keyframes.iter().map(|k| k.camera).collect();
    let path = Interpolation::new(&cameras)?;
    let aspect = video.width as f64 / video.height as f64;
    let file = FileJson {
        camera_type: "perspective",
        render_width: video.width,
        render_height: video.height,
        fps: video.fps,
        seconds: video.seconds,
        is_cycle: false,
        smoothness_value: TENSION,
        default_transition_sec: video.seconds / (keyframes.len() - 1) as f64,
        keyframes: keyframes
            .iter()
            .map(|k| KeyframeJson {
                matrix: row_major(&k.camera.camera_to_world),
                fov: k.camera.fov_deg,
                aspect: k.aspect,
                render_time: k.camera.render_time,
                override_time_enabled: k.camera.render_time.map(|_| true),
            })
            .collect(),
        camera_path: path
            .frames(count)
            .iter()
            .map(|frame| FrameJson {
                camera_to_world: row_major(&frame.camera_to_world),
                fov: frame.fov_deg,
                aspect,
                render_time: frame.render_time,
            })
            .collect(),
    };
    serde_json::to_string(&file).map_err(|e| format!("cannot write the camera path: {e}"))
}

/// Writes the `camera_path.json` of `keyframes` making `video` to `path` atomically (a
/// temporary file beside it, renamed over it); returns the number of video frames.
pub fn save(path: &Path, keyframes: &[Keyframe], video: &Video) -> Result<usize, String> {
    let json = to_json(keyframes, video)?;
    splat_core::ply::write_atomic(path, |file| writeln!(file, "{json}"))
        .map_err(|e| e.to_string())?;
    Ok(video.frame_count())
}

/// The camera path being made in the viewer: its keyframes, the video and where it goes.
#[derive(Clone, Debug, PartialEq)]
pub struct PathDraft {
    pub keyframes: Vec<Keyframe>,
    pub video: Video,
    /// The file to save to, as typed.
    pub file: String,
}

impl Default for PathDraft {
    /// No keyframes, saved in the working directory (where screenshots go).
    fn default() -> Self {
        Self {
            keyframes: Vec::new(),
            video: Video::default(),
            file: FILE_NAME.into(),
        }
    }
}

impl PathDraft {
    /// An empty path for the scene at `scene_path`, to be saved beside it.
    pub fn for_scene(scene_path: &Path) -> Self {
        let file = match scene_path.parent() {
            Some(folder) => folder.join(FILE_NAME).display().to_string(),
            None => FILE_NAME.into(),
        };
        Self {
            file,
            ..Self::default()
        }
    }

    /// Appends `keyframe`, taken in a view of `view_size` pixels. The first keyframe sets the
    /// render size to the view's, so that the video frames what the view showed.
    pub fn add(&mut self, keyframe: Keyframe, view_size: [u32; 2]) {
        if self.keyframes.is_empty() {
            [self.video.width, self.video.height] = view_size;
        }
        self.keyframes.push(keyframe);
    }

    /// Saves the path to [`Self::file`]; the line to show the user.
    pub fn save(&self) -> Result<String, String> {
        let file = self.file.trim();
        if file.is_empty() {
            return Err("Give a file to save the camera path to".into());
        }
        let frames = save(Path::new(file), &self.keyframes, &self.video)?;
        Ok(format!(
            "Saved {file} ({} keyframes, {frames} frames)",
            self.keyframes.len()
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::SceneExtent;
    use serde_json::Value;

    fn view(position: [f64; 3], yaw: f64, pitch: f64, fov_deg: f64) -> ViewCamera {
        let mut camera = ViewCamera::panorama_viewpoint(&SceneExtent {
            median_distance: 5.0,
        });
        camera.position = DVec3::from_array(position);
        camera.yaw = yaw;
        camera.pitch = pitch;
        camera.fov_deg = fov_deg;
        camera
    }

    fn keyframes(times: Option<[f64; 4]>) -> Vec<Keyframe> {
        let views = [
            view([0.0, 0.0, 0.0], 0.0, 0.0, 80.0),
            view([1.0, 0.5, 0.2], 0.8, 0.2, 60.0),
            view([1.5, -1.0, 0.0], 2.5, -0.3, 95.0),
            view([0.2, -2.0, -0.4], 4.0, 0.1, 70.0),
        ];
        views
            .iter()
            .enumerate()
            .map(|(i, v)| Keyframe::of_view(v, 1600, 900, times.map(|t| t[i])))
            .collect()
    }

    fn cameras(keyframes: &[Keyframe]) -> Vec<PathCamera> {
        keyframes.iter().map(|k| k.camera).collect()
    }

    #[track_caller]
    fn assert_same_camera(got: &PathCamera, want: &PathCamera) {
        assert!(
            got.camera_to_world.abs_diff_eq(want.camera_to_world, 1e-12),
            "{got:?} != {want:?}"
        );
        assert!(
            (got.fov_deg - want.fov_deg).abs() < 1e-12,
            "{got:?} != {want:?}"
        );
        assert_eq!(got.render_time, want.render_time);
    }

    #[test]
    fn passes_through_every_keyframe() {
        let keys = keyframes(Some([0.0, 0.25, 0.6, 0.8]));
        let path = Interpolation::new(&cameras(&keys)).unwrap();
        for (k, key) in keys.iter().enumerate() {
            assert_same_camera(&path.at(k as f64), &key.camera);
        }
        // 10 frames between keyframes: frames 0, 10, 20 and 30 are the keyframes.
        let frames = path.frames(31);
        for (k, key) in keys.iter().enumerate() {
            assert_same_camera(&frames[10 * k], &key.camera);
        }
    }

    #[test]
    fn two_keyframes_make_a_straight_line_at_constant_speed() {
        let a = view([0.0, 0.0, 0.0], 0.0, 0.0, 80.0);
        let b = view([3.0, -6.0, 1.5], 1.0, 0.3, 40.0);
        let keys = [a, b].map(|v| Keyframe::of_view(&v, 800, 600, None).camera);
        let frames = Interpolation::new(&keys).unwrap().frames(7);
        let step = DVec3::new(3.0, -6.0, 1.5) / 6.0;
        for (i, frame) in frames.iter().enumerate() {
            let position = frame.camera_to_world.w_axis.truncate();
            assert!(
                position.abs_diff_eq(step * i as f64, 1e-12),
                "{i}: {position}"
            );
            assert_eq!(frame.render_time, None);
        }
        let fov = |f: &PathCamera| f.fov_deg;
        let (first, last) = (fov(&frames[0]), fov(&frames[6]));
        for (i, frame) in frames.iter().enumerate() {
            let want = first + (last - first) * i as f64 / 6.0;
            assert!((fov(frame) - want).abs() < 1e-12);
        }
    }

    #[test]
    fn frame_count_is_seconds_times_fps_rounded() {
        let video = |seconds, fps| Video {
            seconds,
            fps,
            ..Video::default()
        };
        assert_eq!(video(4.0, 30.0).frame_count(), 120);
        assert_eq!(video(4.0, 29.97).frame_count(), 120); // 119.88
        assert_eq!(video(1.01, 30.0).frame_count(), 30); // 30.3
        assert_eq!(video(0.01, 30.0).frame_count(), 0);
        let keys = keyframes(None);
        for (seconds, fps) in [(4.0, 30.0), (2.5, 24.0), (1.0 / 30.0, 30.0)] {
            let json: Value =
                serde_json::from_str(&to_json(&keys, &video(seconds, fps)).unwrap()).unwrap();
            let frames = json["camera_path"].as_array().unwrap().len();
            assert_eq!(frames, video(seconds, fps).frame_count());
        }
    }

    #[test]
    fn interpolated_times_stay_in_the_loop() {
        // A spline through 0, 1, 1, 0 rises past 1 between the middle keyframes; through
        // 1, 0, 0, 1 it dips below 0.
        for (times, bound) in [([0.0, 1.0, 1.0, 0.0], 1.0), ([1.0, 0.0, 0.0, 1.0], 0.0)] {
            let keys = keyframes(Some(times));
            let frames = Interpolation::new(&cameras(&keys)).unwrap().frames(61);
            let times: Vec<f64> = frames.iter().map(|f| f.render_time.unwrap()).collect();
            assert!(times.iter().all(|t| (0.0..=1.0).contains(t)), "{times:?}");
            // Held at the bound all the way between the middle keyframes.
            assert!(times[20..=40].iter().all(|&t| t == bound), "{times:?}");
        }
    }

    #[test]
    fn the_file_is_nerfstudios_camera_path() {
        let keys = keyframes(Some([0.0, 0.25, 0.5, 0.75]));
        let video = Video {
            width: 640,
            height: 360,
            fps: 24.0,
            seconds: 3.0,
        };
        let json: Value = serde_json::from_str(&to_json(&keys, &video).unwrap()).unwrap();
        assert_eq!(json["camera_type"], "perspective");
        assert_eq!(json["render_width"], 640);
        assert_eq!(json["render_height"], 360);
        assert_eq!(json["fps"], 24.0);
        assert_eq!(json["seconds"], 3.0);
        assert_eq!(json["is_cycle"], false);
        assert_eq!(json["default_transition_sec"], 1.0);
        let stored = json["keyframes"].as_array().unwrap();
        assert_eq!(stored.len(), 4);
        for (entry, key) in stored.iter().zip(&keys) {
            let matrix: Vec<f64> = serde_json::from_value(entry["matrix"].clone()).unwrap();
            assert_eq!(matrix, row_major(&key.camera.camera_to_world));
            assert_eq!(entry["fov"], key.camera.fov_deg);
            assert_eq!(entry["aspect"], 16.0 / 9.0);
            assert_eq!(entry["render_time"], key.camera.render_time.unwrap());
            assert_eq!(entry["override_time_enabled"], true);
        }
        let frames = json["camera_path"].as_array().unwrap();
        assert_eq!(frames.len(), 72);
        for frame in frames {
            let m: Vec<f64> = serde_json::from_value(frame["camera_to_world"].clone()).unwrap();
            // Row-major: the translation is the last column, the last row [0, 0, 0, 1].
            assert_eq!(m[12..], [0.0, 0.0, 0.0, 1.0]);
            let rotation =
                DMat3::from_cols_array(&[m[0], m[4], m[8], m[1], m[5], m[9], m[2], m[6], m[10]]);
            // pano4d's reader accepts rotations orthonormal to 1e-4.
            let error = (rotation.transpose() * rotation - DMat3::IDENTITY)
                .to_cols_array()
                .iter()
                .fold(0.0_f64, |worst, v| worst.max(v.abs()));
            assert!(error < 1e-12, "{error}");
            assert!(rotation.determinant() > 0.0);
            assert_eq!(frame["aspect"], 640.0 / 360.0);
            let time = frame["render_time"].as_f64().unwrap();
            assert!((0.0..=1.0).contains(&time));
            let fov = frame["fov"].as_f64().unwrap();
            assert!(fov > 0.0 && fov < 180.0);
        }
        let last: Vec<f64> = serde_json::from_value(frames[71]["camera_to_world"].clone()).unwrap();
        assert_eq!(last[3], keys[3].camera.camera_to_world.w_axis.x);
        assert_eq!(frames[71]["render_time"], 0.75);

        // A static scene's path has no times at all.
        let json: Value =
            serde_json::from_str(&to_json(&keyframes(None), &video).unwrap()).unwrap();
        assert!(json["keyframes"][0].get("render_time").is_none());
        assert!(json["keyframes"][0].get("override_time_enabled").is_none());
        assert!(json["camera_path"][0].get("render_time").is_none());
    }

    #[test]
    fn what_makes_no_path_is_said() {
        let keys = keyframes(None);
        let video = Video::default();
        let cases = [
            (&keys[..1], video, "at least two keyframes"),
            (&keys[..], Video { fps: 0.0, ..video }, "fps"),
            (
                &keys[..],
                Video {
                    seconds: f64::NAN,
                    ..video
                },
                "seconds",
            ),
            (&keys[..], Video { width: 0, ..video }, "render size"),
            (
                &keys[..],
                Video {
                    seconds: 0.001,
                    ..video
                },
                "no frame",
            ),
        ];
        for (keys, video, reason) in cases {
            let err = to_json(keys, &video).unwrap_err();
            assert!(err.contains(reason), "{reason}: {err}");
        }
    }

    #[test]
    fn a_draft_saves_beside_the_scene_atomically() {
        let dir = std::env::temp_dir().join(format!("pano4d-camera-path-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut draft = PathDraft::for_scene(&dir.join("scene.ply4d"));
        assert_eq!(Path::new(&draft.file), dir.join(FILE_NAME));
        let keys = keyframes(None);
        draft.add(keys[0], [1600, 900]);
        assert_eq!([draft.video.width, draft.video.height], [1600, 900]);
        assert!(draft.save().unwrap_err().contains("two keyframes"));
        draft.add(keys[1], [800, 800]);
        assert_eq!(
            [draft.video.width, draft.video.height],
            [1600, 900],
            "only the first keyframe sets the size"
        );
        let said = draft.save().unwrap();
        assert!(said.contains("2 keyframes, 120 frames"), "{said}");
        let json: Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join(FILE_NAME)).unwrap()).unwrap();
        assert_eq!(json["camera_path"].as_array().unwrap().len(), 120);
        // Saving again replaces the file; no temporary file is left beside it.
        draft.video.seconds = 1.0;
        draft.save().unwrap();
        let names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, [FILE_NAME]);
        draft.file = dir.join("missing").join(FILE_NAME).display().to_string();
        assert!(draft.save().unwrap_err().contains("cannot write"));
        draft.file = "  ".into();
        assert!(draft.save().unwrap_err().contains("Give a file"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
