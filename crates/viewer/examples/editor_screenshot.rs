//! The region editor rendered without a window (egui_kittest on wgpu: lavapipe here),
//! for the README's screenshots:
//!
//! ```text
//! cargo run --release -p pano4d-viewer --example editor_screenshot -- \
//!     SCENE.yaml OUT.png [--select N] [--perspective YAW_DEG PITCH_DEG FOV_DEG]
//! ```
//!
//! The pano4d Python package comes from `$PANO4D_PYTHON` or the project's `.venv`.

use std::path::{Path, PathBuf};

use eframe::egui;
use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;
use glam::DVec3;
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use pano4d_viewer::edit::app::EditorApp;
use pano4d_viewer::edit::bridge::Python;

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [scene, out, options @ ..] = args.as_slice() else {
        return Err("usage: editor_screenshot SCENE.yaml OUT.png [--select N] \
                    [--perspective YAW PITCH FOV]"
            .into());
    };
    let python = match std::env::var_os("PANO4D_PYTHON") {
        Some(program) => Python {
            program: program.into(),
        },
        None => Python {
            program: Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python"),
        },
    };
    let scene = PathBuf::from(scene);
    let mut harness = Harness::builder()
        .with_size(egui::vec2(1120.0, 630.0))
        .wgpu()
        .build_eframe(move |_| EditorApp::new(&scene, python));
    harness.run();
    if let Some(error) = harness.state().error() {
        return Err(error.to_string());
    }
    let number = |text: &str| text.parse::<f64>().map_err(|e| format!("{text}: {e}"));
    let mut rest = options.iter();
    while let Some(option) = rest.next() {
        let mut next = || rest.next().ok_or(format!("{option} needs a value"));
        match option.as_str() {
            "--select" => {
                let index = number(next()?)? as usize;
                let label = {
                    let doc = harness.state().document().ok_or("no document")?;
                    let region = doc.regions.get(index).ok_or("no such region")?;
                    format!("{} ({})", region.label(index), region.kind())
                };
                harness.get_by_label(&label).click();
            }
            "--perspective" => {
                let (yaw, pitch, fov) = (number(next()?)?, number(next()?)?, number(next()?)?);
                harness.get_by_label("Perspective").click();
                let camera = &mut harness.state_mut().perspective_mut().camera;
                let (y, p) = (yaw.to_radians(), pitch.to_radians());
                camera.look_along(DVec3::new(p.cos() * y.cos(), p.cos() * y.sin(), p.sin()));
                camera.fov_deg = fov;
            }
            other => return Err(format!("unknown option {other}")),
        }
        harness.run();
    }
    harness.remove_cursor();
    harness.run();
    let image = harness.render()?;
    // The README's images: the smallest PNG the encoder makes.
    let file = std::fs::File::create(out).map_err(|e| format!("cannot write {out}: {e}"))?;
    let encoder = PngEncoder::new_with_quality(file, CompressionType::Best, FilterType::Adaptive);
    image
        .write_with_encoder(encoder)
        .map_err(|e| format!("cannot write {out}: {e}"))?;
    println!("wrote {out}");
    Ok(())
}
