//! The region editor (`pano4d-view --edit`) driven through its window in egui_kittest's
//! wgpu harness (lavapipe in CI), saving through the project's Python package
//! (`.venv/bin/python`, from `make setup`): what is drawn is what scene.yaml says
//! afterwards, read back by pano4d's own loader.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use eframe::egui::accesskit::Role;
use eframe::egui::{self, Pos2};
use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;
use glam::{DVec2, DVec3};
use image::{Rgb, RgbImage};
use pano4d_viewer::edit::app::EditorApp;
use pano4d_viewer::edit::bridge::{Python, RegionJson};
use pano4d_viewer::edit::document::{Mask, Shape};

mod common;
use common::TempDir;

const W: u32 = 512;
const H: u32 = 256;

fn python() -> Python {
    let program = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    assert!(
        program.is_file(),
        "{} is missing: run `make setup` (the editor saves through the pano4d package)",
        program.display()
    );
    Python { program }
}

/// Everything outside the regions list of [`SCENE`] (see the markers in it).
const SCENE: &str = "\
# lake at dusk — my notes
panorama: pano.png   # 512×256 test image

# the moving parts
regions:
  # first item below
  - name: water
    mask: water.png
# after the regions: keep me
animate:
  frames: 4   # a short loop
  border_px: 4
seed: 3        # fixed
";

/// A textured panorama (so the preview has something to move) and [`SCENE`] with a
/// mask region `water` covering the bottom quarter.
fn write_scene(dir: &Path) -> PathBuf {
    let pano = RgbImage::from_fn(W, H, |x, y| {
        let stripe = if (x / 8 + y / 8) % 2 == 0 { 60 } else { 0 };
        Rgb([(x / 4) as u8 + stripe, (y / 2) as u8 + stripe, 120 + stripe])
    });
    pano.save(dir.join("pano.png")).unwrap();
    let mut water = Mask::empty(W, H);
    for y in 3 * H / 4..H {
        for x in 0..W {
            water.pixels[(y * W + x) as usize] = 1;
        }
    }
    water.save_png(&dir.join("water.png")).unwrap();
    let scene = dir.join("scene.yaml");
    std::fs::write(&scene, SCENE).unwrap();
    scene
}

/// The editor on `scene`, after its first frames.
fn open_editor(scene: &Path) -> Harness<'static, EditorApp> {
    let scene = scene.to_path_buf();
    let mut harness = Harness::builder()
        .with_size(egui::vec2(1100.0, 640.0))
        .wgpu()
        .build_eframe(move |_| EditorApp::new(&scene, python()));
    settle(&mut harness);
    harness
}

/// Steps the window until Python's open or save has finished (it runs on a worker thread).
fn settle(harness: &mut Harness<'static, EditorApp>) {
    let started = Instant::now();
    while harness.state().working() {
        assert!(
            started.elapsed() < Duration::from_secs(120),
            "{}",
            harness.state().status()
        );
        std::thread::sleep(Duration::from_millis(50));
        harness.step();
    }
    harness.run();
}

/// A fresh folder with [`SCENE`] and the editor open on it.
fn editor(tag: &str) -> (TempDir, PathBuf, Harness<'static, EditorApp>) {
    let dir = TempDir::new(tag);
    let scene = write_scene(&dir.0);
    let harness = open_editor(&scene);
    assert_eq!(harness.state().error(), None);
    (dir, scene, harness)
}

fn choose(harness: &mut Harness<'static, EditorApp>, label: &str) {
    harness.get_by_label(label).click();
    harness.run();
}

/// A primary-button drag through a few intermediate points.
fn drag(harness: &mut Harness<'static, EditorApp>, from: Pos2, to: Pos2) {
    harness.hover_at(from);
    harness.run();
    harness.drag_at(from);
    harness.run();
    for k in 1..=4 {
        harness.hover_at(from + (to - from) * (k as f32 / 4.0));
        harness.run();
    }
    harness.drop_at(to);
    harness.run();
}

fn click_at(harness: &mut Harness<'static, EditorApp>, at: Pos2) {
    harness.hover_at(at);
    harness.run();
    harness.drag_at(at);
    harness.run();
    harness.drop_at(at);
    harness.run();
}

/// A drag between two panorama pixels, as they show in the current view.
fn drag_px(harness: &mut Harness<'static, EditorApp>, from: [f64; 2], to: [f64; 2]) {
    let (a, b) = (
        screen(harness, from[0], from[1]),
        screen(harness, to[0], to[1]),
    );
    drag(harness, a, b);
}

fn screen(harness: &Harness<'static, EditorApp>, u: f64, v: f64) -> Pos2 {
    harness
        .state()
        .screen_of(DVec2::new(u, v))
        .expect("the point is in view")
}

fn save(harness: &mut Harness<'static, EditorApp>) {
    choose(harness, "Save *");
    settle(harness);
    let status = harness.state().status();
    assert!(status.starts_with("Saved"), "{status}");
}

/// scene.yaml as pano4d's loader reads it.
fn read_back(scene: &Path) -> Vec<RegionJson> {
    let work = scene.with_file_name("readback");
    python()
        .show(scene, &work)
        .expect("the saved scene loads")
        .regions
}

/// The text before the regions' first item and after their last (see [`SCENE`]).
fn outside_regions(text: &str) -> (&str, &str) {
    let start = text.find("  - name").expect("a first item");
    let end = text.find("# after the regions").expect("the comment after");
    (&text[..start], &text[end..])
}

fn pano4d_check(scene: &Path) {
    let out = Command::new(python().program)
        .args(["-m", "pano4d.cli", "check"])
        .arg(scene)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "pano4d check refuses what the editor wrote: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_drawn_box_and_arrow_are_what_scene_yaml_says_after_saving() {
    let (_dir, scene, mut harness) = editor("box");
    choose(&mut harness, "Box");
    let (from, to) = (
        screen(&harness, 100.0, 60.0),
        screen(&harness, 180.0, 120.0),
    );
    drag(&mut harness, from, to);
    assert_eq!(
        harness.state().selected(),
        Some(1),
        "the new box is selected"
    );
    choose(&mut harness, "Arrow");
    // 30° above +u, from the box's centre.
    let centre = DVec2::new(140.0, 90.0);
    let end = centre + DVec2::new(40.0, -40.0 * 30f64.to_radians().tan());
    drag_px(&mut harness, [centre.x, centre.y], [end.x, end.y]);
    save(&mut harness);

    let regions = read_back(&scene);
    assert_eq!(regions.len(), 2);
    assert_eq!(regions[0].name.as_deref(), Some("water"));
    assert_eq!(
        regions[0].mask.as_deref(),
        Some("water.png"),
        "an unpainted mask keeps its file"
    );
    assert_eq!(regions[1].bbox, Some([100.0, 60.0, 180.0, 120.0]));
    let motion = regions[1].motion.expect("the arrow gave a motion hint");
    assert!((motion.direction_deg - 30.0).abs() < 1.0, "{motion:?}");
    assert_eq!(motion.speed, 0.5);
    pano4d_check(&scene);
    let text = std::fs::read_to_string(&scene).unwrap();
    assert_eq!(outside_regions(&text), outside_regions(SCENE), "{text}");
}

#[test]
fn a_box_dragged_across_the_seam_is_one_wrapping_region_in_both_views() {
    let (dir, scene, mut harness) = editor("seam");
    // Pan so that the seam (u = 0 = 512) is in the middle of the view.
    choose(&mut harness, "Navigate");
    let middle = harness.state().view_rect().center();
    let half_turn = screen(&harness, 256.0, 128.0).x - screen(&harness, 0.0, 128.0).x;
    drag(&mut harness, middle, middle + egui::vec2(half_turn, 0.0));
    choose(&mut harness, "Box");
    let (from, to) = (
        screen(&harness, 492.0, 100.0),
        screen(&harness, 20.0, 140.0),
    );
    assert!(
        from.x < middle.x && middle.x < to.x,
        "the seam lies between the corners"
    );
    drag(&mut harness, from, to);

    // The perspective view looking at the seam (−x): the same across it.
    choose(&mut harness, "Perspective");
    harness
        .state_mut()
        .perspective_mut()
        .camera
        .look_along(DVec3::NEG_X);
    harness.run();
    let (from, to) = (
        screen(&harness, 490.0, 110.0),
        screen(&harness, 25.0, 135.0),
    );
    assert!(from.x < to.x);
    drag(&mut harness, from, to);
    save(&mut harness);

    let regions = read_back(&scene);
    assert_eq!(regions.len(), 3, "{regions:?}");
    assert_eq!(regions[1].bbox, Some([492.0, 100.0, 20.0, 140.0]));
    assert_eq!(regions[2].bbox, Some([490.0, 110.0, 25.0, 135.0]));
    pano4d_check(&scene);

    // Drawn on both sides of the seam: the tint shows left and right of it.
    let image = harness.render().unwrap();
    let pano = image::open(dir.0.join("pano.png")).unwrap().into_rgb8();
    let tinted = |u: f64, v: f64| {
        let p = screen(&harness, u, v);
        let shown = image.get_pixel(p.x as u32, p.y as u32).0;
        let original = pano.get_pixel(u as u32, v as u32).0;
        (0..3).any(|c| shown[c].abs_diff(original[c]) > 20)
    };
    for u in [500.5, 510.5, 4.5, 15.5] {
        assert!(tinted(u, 125.5), "u = {u} is inside the seam regions");
    }
    assert!(
        !tinted(40.5, 125.5) && !tinted(470.5, 125.5),
        "outside them"
    );
}

/// Region `index`'s mask and the file scene.yaml names for it (None once painted).
fn mask_of(harness: &Harness<'static, EditorApp>, index: usize) -> (Mask, Option<String>) {
    match &harness.state().document().unwrap().regions[index].shape {
        Shape::Mask { mask, file } => ((**mask).clone(), file.clone()),
        other => panic!("region {index} is not a mask: {other:?}"),
    }
}

#[test]
fn painting_then_undo_leaves_the_mask_unchanged() {
    let (dir, scene, mut harness) = editor("paint");
    let (original, _) = mask_of(&harness, 0);
    choose(&mut harness, "water (mask)");
    choose(&mut harness, "Paint");
    drag_px(&mut harness, [100.0, 100.0], [300.0, 150.0]);
    let (painted, file) = mask_of(&harness, 0);
    assert_eq!(file, None, "a painted mask is saved anew");
    assert!(
        painted.count() > original.count() + 500,
        "the stroke painted"
    );
    choose(&mut harness, "Undo");
    let (undone, file) = mask_of(&harness, 0);
    assert_eq!(undone, original, "undo restores every pixel");
    assert_eq!(file.as_deref(), Some("water.png"));
    choose(&mut harness, "Redo");
    assert_eq!(mask_of(&harness, 0).0, painted, "redo paints it again");
    // Saved: the painted mask goes beside scene.yaml under the region's name.
    save(&mut harness);
    let regions = read_back(&scene);
    assert_eq!(regions[0].mask.as_deref(), Some("scene.water.mask.png"));
    let written = Mask::from_png(&dir.0.join("scene.water.mask.png")).unwrap();
    assert_eq!(written, painted);
}

#[test]
fn a_brush_at_the_pole_in_the_perspective_view_paints_a_cap() {
    let (_dir, _scene, mut harness) = editor("pole");
    choose(&mut harness, "Perspective");
    harness
        .state_mut()
        .perspective_mut()
        .camera
        .look_along(DVec3::new(1.0, 0.0, 50.0));
    harness.state_mut().brush_px = 40.0;
    harness.run();
    choose(&mut harness, "Paint");
    let pole = harness
        .state()
        .screen_of(DVec2::new(0.0, 0.0))
        .expect("the zenith is in view");
    click_at(&mut harness, pole);
    assert_eq!(
        harness.state().document().unwrap().regions.len(),
        2,
        "painting with nothing selected starts a mask region"
    );
    let (mask, _) = mask_of(&harness, 1);
    // A cap of 20 px radius round the pole: every column of the top rows.
    for y in 0..15 {
        assert!(
            (0..W).all(|x| mask.get(x, y)),
            "row {y} is covered all round"
        );
    }
    assert!(
        (0..W).all(|x| !mask.get(x, 25)),
        "row 25 is outside the cap"
    );
}

#[test]
fn rename_delete_and_comments_survive_a_save() {
    let (_dir, scene, mut harness) = editor("rename");
    choose(&mut harness, "Click");
    let at = screen(&harness, 200.0, 40.0);
    click_at(&mut harness, at);
    choose(&mut harness, "Box");
    drag_px(&mut harness, [10.0, 10.0], [60.0, 40.0]);
    // Rename the click region, delete the box.
    choose(&mut harness, "region 2 (click)");
    let field = harness.get_by_role_and_label(Role::TextInput, "Name");
    field.focus();
    field.type_text("birds");
    harness.run();
    choose(&mut harness, "region 3 (box)");
    choose(&mut harness, "Delete region");
    save(&mut harness);
    let regions = read_back(&scene);
    assert_eq!(regions.len(), 2, "{regions:?}");
    assert_eq!(regions[1].name.as_deref(), Some("birds"));
    assert_eq!(regions[1].click, Some([200.0, 40.0]));
    assert_eq!(regions[1].size, Some(128));
    let text = std::fs::read_to_string(&scene).unwrap();
    assert_eq!(outside_regions(&text), outside_regions(SCENE), "{text}");
    pano4d_check(&scene);
}

#[test]
fn animate_preview_plays_the_unsaved_regions_in_place() {
    let (_dir, scene, mut harness) = editor("preview");
    choose(&mut harness, "Box");
    drag_px(&mut harness, [100.0, 40.0], [300.0, 120.0]);
    choose(&mut harness, "Animate preview");
    let started = Instant::now();
    while harness.state().preview_state().1.is_none() {
        assert!(
            started.elapsed() < Duration::from_secs(180),
            "{}",
            harness.state().status()
        );
        std::thread::sleep(Duration::from_millis(200));
        harness.step();
    }
    assert!(
        harness.state().status().starts_with("Preview: 4 frames"),
        "{}",
        harness.state().status()
    );
    let before = std::fs::read_to_string(&scene).unwrap();
    assert_eq!(before, SCENE, "previewing writes nothing beside scene.yaml");
    // The loop plays: the view changes inside the box, not outside.
    // Frames are compared by what was drawn, not by the clock: on a loaded machine a
    // whole loop can pass between two renders.
    harness.step();
    let first = harness.render().unwrap();
    let frame = harness.state().shown_preview_frame();
    assert!(frame.is_some(), "the preview is drawn");
    let mut later = first.clone();
    while harness.state().shown_preview_frame() == frame {
        std::thread::sleep(Duration::from_millis(50));
        harness.step();
        later = harness.render().unwrap();
    }
    let moved = |u: f64, v: f64| {
        let p = screen(&harness, u, v);
        first.get_pixel(p.x as u32, p.y as u32) != later.get_pixel(p.x as u32, p.y as u32)
    };
    let inside = [(130.0, 60.0), (150.0, 100.0), (260.0, 100.0), (280.0, 60.0)];
    assert!(inside.iter().any(|&(u, v)| moved(u, v)), "the box moves");
    assert!(!moved(400.0, 60.0) && !moved(40.0, 150.0), "the rest stays");
}

#[test]
fn an_invalid_scene_shows_its_error_in_the_window() {
    let dir = TempDir::new("invalid");
    let scene = write_scene(&dir.0);
    std::fs::write(
        &scene,
        "panorama: pano.png\nregions: [{box: [1, 9, 3, 4]}]\n",
    )
    .unwrap();
    let harness = open_editor(&scene);
    harness.get_by_label("Cannot edit the regions");
    let error = harness.state().error().unwrap();
    assert!(
        error.contains("regions[0].box: expected v0 < v1"),
        "{error}"
    );
    assert!(
        !error.contains('\n') || error.lines().count() < 3,
        "{error}"
    );
}

#[test]
fn edit_needs_a_scene_yaml_and_no_headless() {
    let cases: [&[&str]; 2] = [&["--edit"], &["--edit", "scene.yaml", "--headless"]];
    for args in cases {
        let out = Command::new(env!("CARGO_BIN_EXE_pano4d-view"))
            .args(args)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains("--edit needs a scene.yaml"), "{stderr}");
    }
}

#[test]
fn closing_with_unsaved_changes_is_refused_once() {
    let (_dir, _scene, mut harness) = editor("close");
    let close = |harness: &mut Harness<'static, EditorApp>| {
        let root = egui::ViewportId::ROOT;
        let info = harness.input_mut().viewports.entry(root).or_default();
        info.events.push(egui::ViewportEvent::Close);
        harness.step();
        harness.output().viewport_output[&root]
            .commands
            .contains(&egui::ViewportCommand::CancelClose)
    };
    assert!(!close(&mut harness), "nothing to lose: it closes");
    choose(&mut harness, "Box");
    drag_px(&mut harness, [10.0, 10.0], [60.0, 40.0]);
    assert!(close(&mut harness), "a drawn box is not lost silently");
    assert!(harness.state().status().starts_with("Unsaved changes"));
    assert!(!close(&mut harness), "the second close discards");
}

#[test]
fn the_window_draws_while_python_opens_and_saves() {
    let dir = TempDir::new("live");
    let scene = write_scene(&dir.0);
    let path = scene.clone();
    let mut harness = Harness::builder()
        .with_size(egui::vec2(1100.0, 640.0))
        .wgpu()
        .build_eframe(move |_| EditorApp::new(&path, python()));
    // The first frames come before Python has answered: the window shows that it opens.
    assert!(harness.state().working(), "opening runs on a worker thread");
    assert!(
        harness.state().status().starts_with("Opening"),
        "{}",
        harness.state().status()
    );
    settle(&mut harness);
    assert_eq!(harness.state().error(), None);
    choose(&mut harness, "Box");
    drag_px(&mut harness, [10.0, 10.0], [60.0, 40.0]);
    choose(&mut harness, "Save *");
    assert!(harness.state().working(), "saving runs on a worker thread");
    // A box dragged while the save runs is not taken: what is saved is what was drawn.
    drag_px(&mut harness, [300.0, 100.0], [360.0, 140.0]);
    settle(&mut harness);
    assert!(harness.state().status().starts_with("Saved"));
    assert_eq!(harness.state().document().unwrap().regions.len(), 2);
    assert_eq!(read_back(&scene).len(), 2);
    assert!(!harness.state().unsaved());
}

/// A shortcut as `xdotool key ctrl+s` (or fast typing) delivers it: ctrl down, the key
/// down and up, ctrl up, all in one frame, so ctrl is no longer held when the frame runs.
fn shortcut_in_one_frame(harness: &mut Harness<'static, EditorApp>, key: egui::Key) {
    // What egui-winit sends for ctrl on Linux.
    let ctrl = egui::Modifiers::CTRL.plus(egui::Modifiers::COMMAND);
    let event = |pressed, modifiers| egui::Event::Key {
        key,
        pressed,
        modifiers,
        repeat: false,
        physical_key: None,
    };
    harness.input_mut().events.extend([
        egui::Event::ModifiersChanged(ctrl),
        event(true, ctrl),
        event(false, ctrl),
        egui::Event::ModifiersChanged(egui::Modifiers::NONE),
    ]);
    harness.step();
    harness.run();
}

#[test]
fn ctrl_s_and_ctrl_z_work_when_ctrl_is_released_within_the_frame() {
    let (_dir, scene, mut harness) = editor("shortcuts");
    choose(&mut harness, "Box");
    drag_px(&mut harness, [10.0, 10.0], [60.0, 40.0]);
    shortcut_in_one_frame(&mut harness, egui::Key::S);
    assert!(harness.state().working(), "ctrl+S started a save");
    settle(&mut harness);
    let status = harness.state().status();
    assert!(status.starts_with("Saved"), "{status}");
    assert_eq!(read_back(&scene).len(), 2);
    drag_px(&mut harness, [100.0, 100.0], [160.0, 140.0]);
    assert_eq!(harness.state().document().unwrap().regions.len(), 3);
    shortcut_in_one_frame(&mut harness, egui::Key::Z);
    assert_eq!(
        harness.state().document().unwrap().regions.len(),
        2,
        "ctrl+Z undid the box"
    );
}
