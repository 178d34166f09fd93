//! The editor's link to the pano4d Python package, the one owner of scene.yaml:
//! `python -m pano4d.cli regions show | save | preview` (the commands in
//! python/pano4d/region_cli.py, the file work in python/pano4d/region_edit.py).
//! Regions travel as JSON in scene.yaml's own keys; painted masks as PNG files.

use std::ffi::OsStr;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;

use glam::DVec2;
use serde::{Deserialize, Serialize};

use super::document::{Document, Mask, Motion, PixelBox, Region, Shape, DEFAULT_CLICK_SIZE};

/// The Python interpreter that has the pano4d package.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Python {
    pub program: PathBuf,
}

impl Python {
    /// `$PANO4D_PYTHON`, else the `python` beside this executable (pano4d-view installed
    /// into the project's virtual environment by `make setup`), else `python3`.
    pub fn locate() -> Self {
        if let Some(program) = std::env::var_os("PANO4D_PYTHON") {
            return Self {
                program: program.into(),
            };
        }
        let beside = std::env::current_exe()
            .ok()
            .and_then(|exe| Some(exe.parent()?.join("python")))
            .filter(|p| p.is_file());
        Self {
            program: beside.unwrap_or_else(|| "python3".into()),
        }
    }

    /// Runs `pano4d regions ARGS` with `stdin`; its stdout, or the one-line error it gave.
    fn regions(&self, args: &[&OsStr], stdin: Option<&str>) -> Result<String, String> {
        let mut child = Command::new(&self.program)
            .args(["-m", "pano4d.cli", "regions"])
            .args(args)
            // rich wraps messages at the terminal width, 80 without one.
            .env("COLUMNS", "10000")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| {
                format!(
                    "cannot run {} ({e}); the editor saves and previews through the pano4d \
                     Python package: activate its virtual environment or set PANO4D_PYTHON",
                    self.program.display()
                )
            })?;
        let mut input = child.stdin.take().expect("piped");
        input
            .write_all(stdin.unwrap_or("").as_bytes())
            .map_err(|e| format!("cannot talk to {}: {e}", self.program.display()))?;
        drop(input);
        let output = child
            .wait_with_output()
            .map_err(|e| format!("{} failed: {e}", self.program.display()))?;
        if output.status.success() {
            return Ok(String::from_utf8_lossy(&output.stdout).into_owned());
        }
        let stderr = String::from_utf8_lossy(&output.stderr);
        let message = stderr.trim().trim_start_matches("error: ").trim();
        Err(if message.contains("No module named") {
            format!(
                "{} has no pano4d package ({message}); set PANO4D_PYTHON to the project's \
                 .venv/bin/python",
                self.program.display()
            )
        } else if message.is_empty() {
            format!("pano4d regions failed with {}", output.status)
        } else {
            message.to_string()
        })
    }

    /// Opens `scene`: the display panorama and masks are written into `work`.
    pub fn show(&self, scene: &Path, work: &Path) -> Result<Opened, String> {
        let out = self.regions(
            &[
                "show".as_ref(),
                scene.as_os_str(),
                "--work".as_ref(),
                work.as_os_str(),
            ],
            None,
        )?;
        serde_json::from_str(&out)
            .map_err(|e| format!("unexpected answer from pano4d ({e}): {out}"))
    }

    /// Replaces `scene`'s regions with `regions`; returns the mask files written.
    pub fn save(&self, scene: &Path, regions: &[RegionJson]) -> Result<Saved, String> {
        let out = self.regions(
            &["save".as_ref(), scene.as_os_str()],
            Some(&payload(regions)),
        )?;
        serde_json::from_str(&out)
            .map_err(|e| format!("unexpected answer from pano4d ({e}): {out}"))
    }

    /// Renders the flow preview of `regions` into `out` (`width` pixels wide).
    pub fn preview(
        &self,
        scene: &Path,
        regions: &[RegionJson],
        out: &Path,
        width: u32,
    ) -> Result<PreviewFrames, String> {
        let width = width.to_string();
        let args = [
            "preview".as_ref(),
            scene.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
            "--width".as_ref(),
            width.as_ref(),
        ];
        let answer = self.regions(&args, Some(&payload(regions)))?;
        serde_json::from_str(&answer)
            .map_err(|e| format!("unexpected answer from pano4d ({e}): {answer}"))
    }
}

fn payload(regions: &[RegionJson]) -> String {
    serde_json::json!({ "regions": regions }).to_string()
}

/// A region as scene.yaml writes it (plus `mask_png`, a mask PNG to read or to save).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegionJson {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(rename = "box", skip_serializing_if = "Option::is_none")]
    pub bbox: Option<[f64; 4]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub click: Option<[f64; 2]>,
    /// Whole pixels: scene.yaml's `size` is an integer.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub size: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mask: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mask_png: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub motion: Option<Motion>,
}

/// What `regions show` answers.
#[derive(Clone, Debug, Deserialize)]
pub struct Opened {
    pub scene: PathBuf,
    pub panorama: PathBuf,
    pub width: u32,
    pub height: u32,
    pub mask_width: u32,
    pub mask_height: u32,
    /// The panorama as an 8-bit PNG.
    pub display: PathBuf,
    pub frames: usize,
    pub fps: f64,
    pub regions: Vec<RegionJson>,
}

impl Opened {
    /// The regions as a document (mask PNGs read).
    pub fn document(&self) -> Result<Document, String> {
        let regions = self
            .regions
            .iter()
            .enumerate()
            .map(|(i, r)| region_from_json(r).map_err(|e| format!("regions[{i}]: {e}")))
            .collect::<Result<_, _>>()?;
        Ok(Document {
            width: self.width,
            height: self.height,
            mask_width: self.mask_width,
            mask_height: self.mask_height,
            regions,
        })
    }
}

/// What `regions save` answers.
#[derive(Clone, Debug, Deserialize)]
pub struct Saved {
    pub scene: PathBuf,
    pub masks: Vec<PathBuf>,
}

/// What `regions preview` answers.
#[derive(Clone, Debug, Deserialize)]
pub struct PreviewFrames {
    pub frames: Vec<PathBuf>,
    pub fps: f64,
    pub width: u32,
    pub height: u32,
    pub seconds: f64,
}

fn region_from_json(r: &RegionJson) -> Result<Region, String> {
    let shape = match (r.bbox, r.click, &r.mask, &r.mask_png) {
        (Some([u0, v0, u1, v1]), None, None, None) => Shape::Box(PixelBox { u0, v0, u1, v1 }),
        (None, Some([u, v]), None, None) => Shape::Click {
            at: DVec2::new(u, v),
            size: r.size.map_or(DEFAULT_CLICK_SIZE, f64::from),
        },
        (None, None, Some(file), Some(png)) => Shape::Mask {
            mask: Arc::new(Mask::from_png(Path::new(png))?),
            file: Some(file.clone()),
        },
        _ => return Err(format!("expected one of box / click / mask, got {r:?}")),
    };
    Ok(Region {
        name: r.name.clone(),
        shape,
        motion: r.motion,
    })
}

/// The document's regions as JSON; painted masks are written as `staging/mask-<i>.png`.
pub fn regions_json(doc: &Document, staging: &Path) -> Result<Vec<RegionJson>, String> {
    let mut out = Vec::with_capacity(doc.regions.len());
    for (index, region) in doc.regions.iter().enumerate() {
        let mut json = RegionJson {
            name: region.name.clone(),
            motion: region.motion,
            ..Default::default()
        };
        match &region.shape {
            Shape::Box(b) => json.bbox = Some([b.u0, b.v0, b.u1, b.v1]),
            Shape::Click { at, size } => {
                json.click = Some([at.x, at.y]);
                json.size = Some(size.round().max(1.0) as u32);
            }
            Shape::Mask {
                file: Some(file), ..
            } => json.mask = Some(file.clone()),
            Shape::Mask { mask, file: None } => {
                let png = staging.join(format!("mask-{index}.png"));
                mask.save_png(&png)?;
                json.mask_png = Some(png.to_string_lossy().into_owned());
            }
        }
        out.push(json);
    }
    Ok(out)
}
