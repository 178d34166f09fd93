//! What the region editor costs on a real panorama (`../shared/data/pano_lake.jpg`,
//! 4096×2048, the three regions of docs/editor_lake.yaml plus a painted mask): opening
//! through Python, the per-frame work of drawing (region labels, the composed view in
//! both views, a brush dab), saving through Python, and the flow preview. Prints a table
//! and writes JSON.
//!
//! `cargo run --release -p pano4d-viewer --bin editor-bench -- [--json PATH] [--size WxH]
//!  [--repeats N]`
//!
//! The pano4d Python package comes from `$PANO4D_PYTHON` or the `python` beside this
//! program, else `python3` (see `Python::locate`).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use eframe::egui::{Pos2, Rect, Vec2};
use glam::DVec3;
use pano4d_viewer::edit::bridge::{regions_json, Python};
use pano4d_viewer::edit::document::{Region, Shape};
use pano4d_viewer::edit::preview::PREVIEW_WIDTH;
use pano4d_viewer::edit::views::{compose, PanoramaView, PerspectiveView, Pyramid, Tint, View};
use serde::Serialize;

const SCENE: &str = "\
panorama: PANORAMA
regions:
  - name: clouds
    box: [1900, 0, 3950, 720]
    motion: {direction_deg: 0.0, speed: 0.2}
  - name: water
    box: [1950, 1050, 4000, 1350]
    motion: {direction_deg: 0.0, speed: 0.3}
  - name: leaves
    click: [620, 400]
    size: 500
animate: {frames: 14}
";

#[derive(Serialize)]
struct Step {
    what: String,
    /// Median over the repeats (one run for the Python steps).
    ms: f64,
}

#[derive(Serialize)]
struct Report {
    panorama: String,
    view_width: u32,
    view_height: u32,
    steps: Vec<Step>,
}

fn median_ms(repeats: usize, mut f: impl FnMut()) -> f64 {
    let mut times: Vec<f64> = (0..repeats)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[times.len() / 2]
}

fn once_ms<T>(f: impl FnOnce() -> Result<T, String>) -> Result<(T, f64), String> {
    let start = Instant::now();
    let value = f()?;
    Ok((value, start.elapsed().as_secs_f64() * 1e3))
}

fn run() -> Result<(), String> {
    let mut json = PathBuf::from("bench/out/editor.json");
    let (mut width, mut height, mut repeats) = (1280u32, 720u32, 5usize);
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().ok_or(format!("{arg} needs a value"));
        match arg.as_str() {
            "--json" => json = value()?.into(),
            "--size" => {
                let text = value()?;
                let (w, h) = text.split_once('x').ok_or("--size is WxH")?;
                width = w.parse().map_err(|_| "--size is WxH")?;
                height = h.parse().map_err(|_| "--size is WxH")?;
            }
            "--repeats" => repeats = value()?.parse().map_err(|_| "--repeats is a count")?,
            other => return Err(format!("unknown option {other}")),
        }
    }
    let panorama = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/pano_lake.jpg");
    let panorama = panorama
        .canonicalize()
        .map_err(|e| format!("{}: {e}", panorama.display()))?;
    let dir = std::env::temp_dir().join(format!("pano4d-editor-bench-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("work")).map_err(|e| e.to_string())?;
    let scene = dir.join("scene.yaml");
    std::fs::write(
        &scene,
        SCENE.replace("PANORAMA", &panorama.to_string_lossy()),
    )
    .map_err(|e| e.to_string())?;
    let python = Python::locate();
    let mut steps = Vec::new();
    let mut record = |what: &str, ms: f64| {
        println!("{what:<58} {ms:>10.2} ms");
        steps.push(Step {
            what: what.into(),
            ms,
        });
    };

    let (opened, ms) = once_ms(|| python.show(&scene, &dir.join("work")))?;
    record("open: pano4d regions show (display PNG, masks)", ms);
    let mut doc = opened.document()?;
    let (pyramid, ms) = once_ms(|| {
        let image = image::open(&opened.display).map_err(|e| e.to_string())?;
        Ok(Pyramid::new(image.into_rgb8()))
    })?;
    record("open: read the display PNG, build the pyramid", ms);

    // A painted mask region, as after a few strokes.
    let mut mask = doc.new_mask();
    for k in 0..20 {
        let azimuth = k as f64 * 0.05;
        mask.paint_cap(DVec3::new(azimuth.cos(), azimuth.sin(), -0.3), 0.05, true);
    }
    doc.regions.push(Region {
        name: Some("rocks".into()),
        shape: Shape::Mask {
            mask: Arc::new(mask),
            file: None,
        },
        motion: None,
    });
    let radius = 32.0 * std::f64::consts::TAU / doc.width as f64;
    let ms = median_ms(repeats, || {
        let Shape::Mask { mask, .. } = &mut doc.regions[3].shape else {
            unreachable!()
        };
        Arc::make_mut(mask).paint_cap(DVec3::new(0.3, -1.0, 0.2), radius, true);
    });
    record("brush dab, 64 px (a cap on the 2048×1024 mask)", ms);
    let mut labels = Vec::new();
    let ms = median_ms(repeats, || labels = doc.labels());
    record("region labels for the tint (4 regions, 2048×1024)", ms);

    let rect = Rect::from_min_size(Pos2::ZERO, Vec2::new(width as f32, height as f32));
    let tint = Tint {
        labels: &labels,
        width: doc.mask_width,
        height: doc.mask_height,
        selected: Some(0),
    };
    let mut perspective = PerspectiveView::default();
    perspective.camera.look_along(DVec3::new(0.3, -1.0, 0.4));
    let views = [
        (
            "compose the panorama view (whole panorama)",
            View::Panorama(PanoramaView::fit(rect, doc.width, doc.height)),
        ),
        (
            "compose the perspective view (80° FOV)",
            View::Perspective(perspective),
        ),
    ];
    for (what, view) in views {
        let ms = median_ms(repeats, || {
            compose(
                &view,
                rect,
                1.0,
                &pyramid,
                Some(&tint),
                doc.width,
                doc.height,
            );
        });
        record(&format!("{what}, {width}×{height}"), ms);
    }

    let json_regions = regions_json(&doc, &dir.join("work"))?;
    let (_, ms) = once_ms(|| python.save(&scene, &json_regions))?;
    record("save: pano4d regions save (splice, mask PNG, validate)", ms);
    let (frames, ms) =
        once_ms(|| python.preview(&scene, &json_regions, &dir.join("preview"), PREVIEW_WIDTH))?;
    record(
        &format!(
            "preview: {} frames at {}×{} (whole command)",
            frames.frames.len(),
            frames.width,
            frames.height
        ),
        ms,
    );
    record(
        "preview: of which the animator (Python's own count)",
        frames.seconds * 1e3,
    );
    let _ = std::fs::remove_dir_all(&dir);

    let report = Report {
        panorama: panorama.to_string_lossy().into_owned(),
        view_width: width,
        view_height: height,
        steps,
    };
    if let Some(parent) = json.parent() {
        std::fs::create_dir_all(parent).map_err(|e| e.to_string())?;
    }
    let text = serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?;
    std::fs::write(&json, text + "\n").map_err(|e| format!("{}: {e}", json.display()))?;
    println!("wrote {}", json.display());
    Ok(())
}

fn main() -> std::process::ExitCode {
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("editor-bench: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
