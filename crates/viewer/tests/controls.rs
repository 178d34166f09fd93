//! Play, Loop, Screenshot and the camera path's keyframes clicked in the real window
//! (egui_kittest on wgpu), and the frame the window presents compared with splat-core's
//! `Renderer::forward` through the sRGB transfer.
//!
//! A test binary of its own: the screenshot is written into the current directory, which
//! the screenshot test changes, and no other test may run beside it.

use std::path::{Path, PathBuf};

use eframe::egui::accesskit::Role;
use eframe::{egui, egui_wgpu};
use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;
use image::RgbaImage;
use pano4d_viewer::app::ViewerApp;
use pano4d_viewer::synthetic;
use splat_core::gaussians::SceneInput;
use splat_core::ply4d::{self, Scene4d};
use splat_core::raster::{GpuContext, RenderSettings, Renderer};

mod common;
use common::TempDir;

const TIMES: usize = 4; // at synthetic::FPS (10): one loop is 0.4 s
/// Seconds per harness step: half a frame, so that playing shows every timestamp.
const STEP_DT: f32 = 0.05;

fn scene() -> Scene4d {
    synthetic::scene(20_000, 2_000, TIMES, 1, 11)
}

fn open_viewer(dir: &Path) -> Harness<'static, ViewerApp> {
    let path = dir.join("scene.ply4d");
    ply4d::write(&path, &scene()).unwrap();
    open_path(path)
}

/// The viewer on a version-2 scene of TIMES timestamps, written into `dir`.
fn open_spacetime_viewer(dir: &Path) -> Harness<'static, ViewerApp> {
    let path = dir.join("scene.ply4d");
    let scene = synthetic::spacetime_scene(20_000, 2_000, TIMES as u32, 1, 11);
    ply4d::write_spacetime(&path, &scene).unwrap();
    open_path(path)
}

fn open_path(path: PathBuf) -> Harness<'static, ViewerApp> {
    let egui_wgpu::WgpuSetup::CreateNew(setup) = egui_kittest::wgpu::default_wgpu_setup() else {
        panic!("egui_kittest's default set-up creates its own device");
    };
    let mut harness = Harness::builder()
        .with_size(egui::vec2(640.0, 480.0))
        .with_step_dt(STEP_DT)
        .wgpu_setup(pano4d_viewer::full_limits(setup).into())
        .build_eframe(move |cc| ViewerApp::new(cc, Some(&path)));
    harness.run();
    assert_eq!(harness.state().error(), None);
    harness
}

/// Clicks the widget labelled `label` through accesskit, which reaches it also where the
/// side panel is taller than the window and it is scrolled out of sight; the second step
/// draws what the click changed.
fn click(harness: &mut Harness<'static, ViewerApp>, label: &str) {
    harness.get_by_label(label).click_accesskit();
    harness.step();
    harness.step();
}

/// The shown timestamp after each of `steps` steps.
fn play(harness: &mut Harness<'static, ViewerApp>, steps: usize) -> Vec<usize> {
    (0..steps)
        .map(|_| {
            harness.step();
            harness.state().time_index().unwrap()
        })
        .collect()
}

#[test]
fn play_pause_and_loop_move_time_as_their_labels_say() {
    let dir = TempDir::new("controls-play");
    let mut harness = open_viewer(&dir.0);
    assert_eq!(harness.state().time_index(), Some(0));

    // Play, looping (the default): every timestamp in turn, then back to the first.
    click(&mut harness, "Play");
    harness.get_by_label("Pause");
    let looped = play(&mut harness, 20); // 1 s: 2.5 loops
    for t in 0..TIMES {
        assert!(looped.contains(&t), "timestamp {t} never shown: {looped:?}");
    }
    assert!(
        looped.windows(2).any(|w| w == [TIMES - 1, 0]),
        "looping wraps from the last timestamp to the first: {looped:?}"
    );

    // Pause: time stands still.
    click(&mut harness, "Pause");
    let paused = harness.state().time_index().unwrap();
    assert_eq!(play(&mut harness, 6), vec![paused; 6]);

    // Loop off, Play: up to the last timestamp, where playback stops by itself.
    click(&mut harness, "Loop");
    click(&mut harness, "Play");
    let once = play(&mut harness, 20);
    assert_eq!(*once.last().unwrap(), TIMES - 1, "{once:?}");
    assert!(
        once.windows(2).all(|w| w[0] <= w[1]),
        "no wrap without Loop: {once:?}"
    );
    harness.get_by_label("Play"); // stopped: the button offers Play again
}

#[test]
fn a_version_2_scene_plays_between_its_timestamps_at_the_speed_set() {
    let dir = TempDir::new("controls-v2");
    let mut harness = open_spacetime_viewer(&dir.0);
    // The speed control is reachable by its label; at half speed a 0.05 s step of the
    // display moves a 10 fps scene by a quarter of a frame.
    harness.get_by_label("speed ×").set_value_accesskit(0.5);
    harness.step();
    assert_eq!(harness.state().time().unwrap().speed, 0.5);
    click(&mut harness, "Play");
    let mut shown = Vec::new();
    for _ in 0..20 {
        harness.step();
        let frame = harness.state().time().unwrap().frame();
        // Every display frame draws the time it shows: evaluated there, not held.
        assert_eq!(harness.state().drawn_frame(), Some(frame));
        shown.push(frame);
    }
    let quarter = 0.05 * 0.5 * synthetic::FPS;
    for pair in shown.windows(2) {
        let moved = (pair[1] - pair[0]).rem_euclid(TIMES as f64);
        assert!((moved - quarter).abs() < 1e-6, "{shown:?}");
    }
    assert!(
        shown.iter().any(|f| f.fract() != 0.0),
        "times between timestamps are shown: {shown:?}"
    );
    assert!(
        shown.windows(2).any(|w| w[1] < w[0]),
        "the time loops: {shown:?}"
    );

    // Paused between two timestamps, the view moves with the slider by a fraction of a
    // frame; a step lands on the next timestamp.
    click(&mut harness, "Pause");
    let view = |harness: &mut Harness<'static, ViewerApp>| {
        let window = harness.render().expect("the window renders on wgpu");
        let rect = harness.state().view_rect();
        image::imageops::crop_imm(
            &window,
            rect.min.x as u32,
            rect.min.y as u32,
            rect.width() as u32,
            rect.height() as u32,
        )
        .to_image()
    };
    let at = |frame: f64, harness: &mut Harness<'static, ViewerApp>| {
        harness
            .get_by_role_and_label(Role::Slider, "time")
            .set_value_accesskit(frame);
        harness.run();
        assert_eq!(harness.state().drawn_frame(), Some(frame));
        view(harness)
    };
    let whole = at(1.0, &mut harness);
    let between = at(1.5, &mut harness);
    assert_ne!(whole, between, "half a frame later the ball has moved");
    assert_eq!(harness.state().time_index(), Some(1));
    harness.key_press(egui::Key::Period);
    harness.run();
    assert_eq!(harness.state().time().unwrap().frame(), 2.0);
}

/// Moves the time slider to `frame` and lets the window draw it.
fn set_time(harness: &mut Harness<'static, ViewerApp>, frame: f64) {
    harness
        .get_by_role_and_label(Role::Slider, "time")
        .set_value_accesskit(frame);
    harness.run();
}

/// The 16 numbers of `m`, row by row, as a camera path stores a matrix.
fn row_major(m: glam::DMat4) -> Vec<f64> {
    m.transpose().to_cols_array().to_vec()
}

fn numbers(value: &serde_json::Value) -> Vec<f64> {
    serde_json::from_value(value.clone()).unwrap()
}

#[track_caller]
fn assert_close(got: &[f64], want: &[f64]) {
    assert_eq!(got.len(), want.len());
    for (g, w) in got.iter().zip(want) {
        assert!((g - w).abs() < 1e-12, "{got:?} != {want:?}");
    }
}

#[test]
fn keyframes_from_the_key_and_the_button_save_nerfstudios_camera_path() {
    let dir = TempDir::new("controls-path");
    let mut harness = open_spacetime_viewer(&dir.0);
    let file = dir.0.join("camera_path.json");
    assert_eq!(
        Path::new(&harness.state().camera_path().file),
        file,
        "saved beside the scene"
    );

    // Keyframe 1 by its key: the panorama's view, half way between timestamps 1 and 2.
    set_time(&mut harness, 1.5);
    let first = *harness.state().camera();
    harness.key_press(egui::Key::K);
    harness.run();
    // Keyframe 2 by the button, further on (W) and at timestamp 3.
    harness.key_down(egui::Key::W);
    harness.run_steps(3);
    harness.key_up(egui::Key::W);
    set_time(&mut harness, 3.0);
    let second = *harness.state().camera();
    assert_ne!(first.position, second.position);
    click(&mut harness, "Add keyframe (K)");
    // A third, taken back.
    click(&mut harness, "Add keyframe (K)");
    harness.get_by_label("3 keyframes");
    click(&mut harness, "Remove last");
    harness.get_by_label("2 keyframes");
    click(&mut harness, "Save camera path…");
    assert!(harness.query_by_label_contains("Saved").is_some());

    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    // The render size is the view's (one pixel a point here).
    let rect = harness.state().view_rect();
    let (width, height) = (rect.width().round() as u32, rect.height().round() as u32);
    assert_eq!(json["camera_type"], "perspective");
    assert_eq!(json["render_width"], width);
    assert_eq!(json["render_height"], height);
    let keyframes = json["keyframes"].as_array().unwrap();
    assert_eq!(keyframes.len(), 2);
    for (key, (camera, frame)) in keyframes.iter().zip([(first, 1.5), (second, 3.0)]) {
        assert_eq!(
            numbers(&key["matrix"]),
            row_major(camera.camera_to_world_gl())
        );
        assert_eq!(key["fov"], camera.vertical_fov_deg(width, height));
        assert_eq!(key["render_time"], frame / TIMES as f64);
    }
    // The video: 4 s at 30 fps, from the first keyframe to the second along a straight line.
    let frames = json["camera_path"].as_array().unwrap();
    assert_eq!(json["seconds"], 4.0);
    assert_eq!(json["fps"], 30.0);
    assert_eq!(frames.len(), 120);
    assert_close(
        &numbers(&frames[0]["camera_to_world"]),
        &row_major(first.camera_to_world_gl()),
    );
    assert_close(
        &numbers(&frames[119]["camera_to_world"]),
        &row_major(second.camera_to_world_gl()),
    );
    assert_eq!(frames[0]["render_time"], 1.5 / TIMES as f64);
    assert_eq!(frames[119]["render_time"], 3.0 / TIMES as f64);
    let x = |i: usize| numbers(&frames[i]["camera_to_world"])[3];
    let step = (second.position.x - first.position.x) / 119.0;
    for i in [1, 40, 77, 118] {
        assert!((x(i) - first.position.x - step * i as f64).abs() < 1e-9);
    }

    // The round trip: pano4d's reader takes the file as `pano4d render --path` does, and
    // its cameras at the two keyframes are the poses "Copy pose" gives `--camera`, at the
    // keyframes' times (the venv of `make setup`, as edit_ui.rs).
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    let poses = [first.pose().to_line(), second.pose().to_line()];
    let read = std::process::Command::new(&python)
        .args([
            "-c",
            ROUND_TRIP,
            file.to_str().unwrap(),
            &poses[0],
            &poses[1],
        ])
        .output()
        .unwrap_or_else(|e| panic!("{} (run `make setup`): {e}", python.display()));
    assert!(
        read.status.success(),
        "{}",
        String::from_utf8_lossy(&read.stderr)
    );
}

/// Reads a camera_path.json (argv 1) with pano4d and checks its first and last cameras
/// against two `--camera` poses (argv 2, 3) and its times against the keyframes' (1.5, 3).
const ROUND_TRIP: &str = "
import sys
from pathlib import Path
import torch
from pano4d import camera_paths, nerfstudio_path
path = nerfstudio_path.read(Path(sys.argv[1]))
cams = path.cameras()
for i, pose in ((0, sys.argv[2]), (len(cams) - 1, sys.argv[3])):
    want = camera_paths.parse_camera(pose, path.width, path.height)
    assert torch.allclose(cams[i].world_to_cam, want.world_to_cam, atol=1e-9), (i, cams[i], want)
    assert torch.allclose(cams[i].K, want.K, rtol=1e-9, atol=0), (i, cams[i].K, want.K)
times = path.scene_times(4, 10.0)
assert abs(times[0] - 1.5) < 1e-12 and abs(times[-1] - 3.0) < 1e-12, times
";

/// sRGB (0..1) of a display value: what egui decodes the view's texels to before
/// compositing, and encodes again for the window.
fn srgb_roundtrip(value: u8) -> f64 {
    let c = value as f64 / 255.0;
    let linear = if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    };
    let encoded = if linear <= 0.0031308 {
        12.92 * linear
    } else {
        1.055 * linear.powf(1.0 / 2.4) - 0.055
    };
    encoded * 255.0
}

fn find_screenshot(dir: &Path) -> PathBuf {
    let shots: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            name.starts_with("pano4d-view-") && name.ends_with(".png")
        })
        .collect();
    assert_eq!(
        shots.len(),
        1,
        "one screenshot in {}: {shots:?}",
        dir.display()
    );
    shots[0].clone()
}

#[test]
fn the_window_shows_forwards_image_and_the_screenshot_saves_it() {
    let dir = TempDir::new("controls-shot");
    std::env::set_current_dir(&dir.0).unwrap();
    let mut harness = open_viewer(&dir.0);
    let window = harness.render().expect("the window renders on wgpu");
    let rect = harness.state().view_rect();
    assert_eq!(
        (rect.min.x.fract(), rect.min.y.fract()),
        (0.0, 0.0),
        "the view sits on whole pixels: {rect:?}"
    );
    let (x0, y0) = (rect.min.x as u32, rect.min.y as u32);
    let (width, height) = (rect.width() as u32, rect.height() as u32);

    // The rasteriser's own image of the same camera, scene and settings.
    let camera = harness.state().camera().to_camera(width, height);
    let scene = scene();
    let mut whole = scene.static_set.clone();
    whole.extend_from(&scene.dynamic[0]);
    let mut renderer = Renderer::new(GpuContext::new().unwrap()).unwrap();
    let (pixels, _) = renderer
        .forward(
            &SceneInput::from(&whole),
            &camera,
            &RenderSettings::default(),
        )
        .unwrap();
    let expected = |x: u32, y: u32, c: usize| -> u8 {
        let value = pixels[(y * width + x) as usize * 5 + c];
        (value.clamp(0.0, 1.0) * 255.0).round() as u8
    };

    // Presented: within one 8-bit level of forward's value through the sRGB transfer.
    let mut worst = 0.0f64;
    for y in 0..height {
        for x in 0..width {
            let shown = window.get_pixel(x0 + x, y0 + y).0;
            for (c, &value) in shown[..3].iter().enumerate() {
                let want = srgb_roundtrip(expected(x, y, c));
                worst = worst.max((value as f64 - want).abs());
            }
        }
    }
    assert!(
        worst <= 1.0,
        "presented frame off forward's by {worst} levels"
    );

    // Screenshot: a PNG that decodes to forward's image, pixel for pixel.
    click(&mut harness, "Screenshot (PNG)");
    let shot: RgbaImage = image::open(find_screenshot(&dir.0)).unwrap().to_rgba8();
    assert_eq!(shot.dimensions(), (width, height));
    let mut off = 0usize;
    for (x, y, p) in shot.enumerate_pixels() {
        off += (0..3)
            .filter(|&c| p.0[c].abs_diff(expected(x, y, c)) > 1)
            .count();
    }
    assert_eq!(
        off, 0,
        "screenshot channels off forward's by more than one level"
    );
    assert!(harness
        .query_by_label_contains("Saved pano4d-view-")
        .is_some());
}
