//! The viewer's window rendered headless with egui_kittest on wgpu (lavapipe in CI): the
//! app draws the scene with splat-core's forward on the harness's device, and the tests
//! read the composed window back as an image.

use std::path::{Path, PathBuf};

use eframe::egui::accesskit::Role;
use eframe::{egui, egui_wgpu};
use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;
use glam::DVec3;
use image::RgbaImage;
use pano4d_viewer::app::ViewerApp;
use pano4d_viewer::camera::{CameraPose, ViewCamera};
use pano4d_viewer::synthetic::{self, ball_centre, BALL_RADIUS};
use splat_core::ply4d;

mod common;
use common::TempDir;

const TIMES: usize = 4;
/// A pixel with every channel at or below this is background showing through (the shell's
/// and the ball's colours are all brighter in some channel).
const DARK: u8 = 10;

fn write_scene(dir: &Path) -> PathBuf {
    let path = dir.join("scene.ply4d");
    ply4d::write(&path, &synthetic::scene(20_000, 2_000, TIMES, 1, 11)).unwrap();
    path
}

fn open_viewer(path: &Path) -> Harness<'static, ViewerApp> {
    let egui_wgpu::WgpuSetup::CreateNew(setup) = egui_kittest::wgpu::default_wgpu_setup() else {
        panic!("egui_kittest's default set-up creates its own device");
    };
    let path = path.to_path_buf();
    Harness::builder()
        .with_size(egui::vec2(960.0, 600.0))
        .wgpu_setup(pano4d_viewer::full_limits(setup).into())
        .build_eframe(move |cc| ViewerApp::new(cc, Some(&path)))
}

/// The part of the window image where the scene is drawn.
fn view_pixels(harness: &mut Harness<'static, ViewerApp>) -> RgbaImage {
    let window = harness.render().expect("the window renders on wgpu");
    let rect = harness.state().view_rect();
    assert!(
        rect.width() > 100.0 && rect.height() > 100.0,
        "view rect {rect:?}"
    );
    image::imageops::crop_imm(
        &window,
        rect.min.x as u32,
        rect.min.y as u32,
        rect.width() as u32,
        rect.height() as u32,
    )
    .to_image()
}

fn lit_fraction(image: &RgbaImage) -> f64 {
    let lit = image
        .pixels()
        .filter(|p| p.0[..3].iter().any(|&c| c > DARK))
        .count();
    lit as f64 / (image.width() * image.height()) as f64
}

/// Pixel box (with `margin`) of the moving ball at timestamp `t`, as `camera` sees it.
fn ball_box(camera: &ViewCamera, width: u32, height: u32, t: usize, margin: f64) -> [f64; 4] {
    let cam = camera.to_camera(width, height);
    let centre = ball_centre(t, TIMES);
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    // Splats reach a few standard deviations past the means: pad the radius.
    let reach = 1.6 * BALL_RADIUS;
    for dx in [-1.0, 1.0] {
        for dy in [-1.0, 1.0] {
            for dz in [-1.0, 1.0] {
                let (uv, z) = cam.project(centre + DVec3::new(dx, dy, dz) * reach);
                assert!(z > 0.0);
                b = [
                    b[0].min(uv.x),
                    b[1].min(uv.y),
                    b[2].max(uv.x),
                    b[3].max(uv.y),
                ];
            }
        }
    }
    [b[0] - margin, b[1] - margin, b[2] + margin, b[3] + margin]
}

fn inside(b: &[f64; 4], x: u32, y: u32) -> bool {
    let (x, y) = (x as f64 + 0.5, y as f64 + 0.5);
    x >= b[0] && x <= b[2] && y >= b[1] && y <= b[3]
}

#[test]
fn scene_is_visible_and_time_controls_are_there() {
    let dir = TempDir::new("visible");
    let mut harness = open_viewer(&write_scene(&dir.0));
    harness.run();
    assert_eq!(harness.state().error(), None);
    let view = view_pixels(&mut harness);
    let lit = lit_fraction(&view);
    assert!(
        lit > 0.9,
        "the shell surrounds the viewpoint, so nearly every pixel is lit: {lit}"
    );
    // The ball is orange-red in front of the shell: some strongly red pixels.
    let red = view
        .pixels()
        .filter(|p| p.0[0] > 200 && p.0[2] < 60)
        .count();
    assert!(red > 100, "the moving ball is visible: {red} red pixels");
    harness.get_by_role_and_label(Role::Slider, "time");
    harness.get_by_label("Play");
    harness.get_by_label("Loop");
    harness.get_by_label("Screenshot (PNG)");
    harness.get_by_label("20000");
    harness.get_by_label("2000");
    harness.get_by_label("classic");

    // The side panel names the mode the file records.
    let mut antialiased = synthetic::scene(2_000, 200, TIMES, 1, 11);
    antialiased.meta.antialiased = true;
    let path = dir.0.join("antialiased.ply4d");
    ply4d::write(&path, &antialiased).unwrap();
    harness.state_mut().open(&path);
    harness.run();
    assert_eq!(harness.state().error(), None);
    harness.get_by_label("antialiased (2D filter)");
}

#[test]
fn moving_the_time_slider_changes_only_the_moving_region() {
    let dir = TempDir::new("slider");
    let mut harness = open_viewer(&write_scene(&dir.0));
    harness.run();
    let before = view_pixels(&mut harness);
    harness
        .get_by_role_and_label(Role::Slider, "time")
        .set_value_accesskit((TIMES - 1) as f64);
    harness.run();
    assert_eq!(harness.state().time_index(), Some(TIMES - 1));
    let after = view_pixels(&mut harness);
    assert_eq!(before.dimensions(), after.dimensions());

    let (w, h) = before.dimensions();
    let camera = *harness.state().camera();
    let first = ball_box(&camera, w, h, 0, 3.0);
    let last = ball_box(&camera, w, h, TIMES - 1, 3.0);
    let mut changed_inside = 0;
    let mut changed_outside = Vec::new();
    for (x, y, p) in after.enumerate_pixels() {
        let q = before.get_pixel(x, y);
        let differs = p.0.iter().zip(q.0).any(|(a, b)| a.abs_diff(b) > 2);
        if !differs {
            continue;
        }
        if inside(&first, x, y) || inside(&last, x, y) {
            changed_inside += 1;
        } else {
            changed_outside.push((x, y));
        }
    }
    assert!(
        changed_inside > 200,
        "the ball moved: {changed_inside} pixels changed"
    );
    assert!(
        changed_outside.is_empty(),
        "{} pixels changed outside the ball's boxes {first:?} / {last:?}, e.g. {:?}",
        changed_outside.len(),
        &changed_outside[..changed_outside.len().min(5)]
    );
}

#[test]
fn keys_move_and_reset_the_camera() {
    let dir = TempDir::new("keys");
    let mut harness = open_viewer(&write_scene(&dir.0));
    harness.run();
    let start = view_pixels(&mut harness);
    harness.key_down(egui::Key::W);
    harness.run_steps(3);
    harness.key_up(egui::Key::W);
    harness.run();
    let position = harness.state().camera().position;
    assert!(
        position.x > 0.0 && position.y.abs() < 1e-9,
        "W moves along +x: {position:?}"
    );
    assert_ne!(view_pixels(&mut harness), start);
    harness.key_press(egui::Key::R);
    harness.run();
    assert_eq!(harness.state().camera().position, DVec3::ZERO);
    assert_eq!(
        view_pixels(&mut harness),
        start,
        "R restores the panorama's view"
    );
}

#[test]
fn corrupt_files_show_an_error_in_the_window() {
    let dir = TempDir::new("corrupt");
    let good = write_scene(&dir.0);
    let bytes = std::fs::read(&good).unwrap();

    let truncated = dir.0.join("truncated.ply4d");
    std::fs::write(&truncated, &bytes[..bytes.len() / 3]).unwrap();
    let mut harness = open_viewer(&truncated);
    harness.run();
    harness.get_by_label("Cannot show the scene");
    assert!(harness.state().error().unwrap().contains("truncated"));
    harness.render().expect("the error screen renders");

    let jpeg = dir.0.join("photo.ply");
    std::fs::write(&jpeg, b"\xff\xd8\xff\xe0\x00\x10JFIF\x00").unwrap();
    let mut harness = open_viewer(&jpeg);
    harness.run();
    assert!(harness
        .state()
        .error()
        .unwrap()
        .contains("neither a .ply4d scene nor a 3DGS .ply"));

    // A damaged dynamic set: the scene opens, the error appears at that timestamp, and
    // going back to a good one recovers.
    let damaged = dir.0.join("damaged.ply4d");
    let mut flipped = bytes.clone();
    let last = flipped.len() - 100;
    flipped[last] ^= 0x5a;
    std::fs::write(&damaged, &flipped).unwrap();
    let mut harness = open_viewer(&damaged);
    harness.run();
    assert_eq!(harness.state().error(), None);
    harness
        .get_by_role_and_label(Role::Slider, "time")
        .set_value_accesskit((TIMES - 1) as f64);
    harness.run();
    assert!(harness.state().error().unwrap().contains("checksum"));
    harness.get_by_label("Cannot show the scene");
    harness
        .get_by_role_and_label(Role::Slider, "time")
        .set_value_accesskit(0.0);
    harness.run();
    assert_eq!(harness.state().error(), None);
}

#[test]
fn pasted_pose_moves_the_camera_to_a_real_scene() {
    let guitar = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/gs_guitar.ply");
    let mut harness = open_viewer(&guitar);
    harness.run();
    assert_eq!(harness.state().error(), None);
    harness.get_by_label("90854");
    // The guitar stands along -y around the origin of its capture frame; look at it from +x.
    let pose = CameraPose {
        position: [3.0, -2.1, 0.2],
        forward: [-1.0, 0.0, 0.0],
        fov_deg: 70.0,
    };
    let field =
        harness.get_by_role_and_label(Role::TextInput, "Pose (for pano4d render --camera):");
    field.focus();
    field.type_text(&pose.to_line());
    harness.run();
    harness.get_by_label("Paste pose").click();
    harness.run();
    let camera = harness.state().camera();
    assert!((camera.position - DVec3::new(3.0, -2.1, 0.2)).length() < 1e-9);
    let lit = lit_fraction(&view_pixels(&mut harness));
    assert!(
        lit > 0.02 && lit < 0.9,
        "the guitar covers part of the view: {lit}"
    );
}
