//! The editor's work off the UI thread: opening the scene, saving it and rendering the
//! preview run on [`Worker`]s through Python; each frame polls them and takes the result.

use std::path::{Path, PathBuf};
use std::time::Instant;

use eframe::egui;

use super::app::EditorApp;
use super::bridge::{regions_json, Python};
use super::document::{Document, Region, Shape};
use super::history::History;
use super::preview;
use super::views::Pyramid;
use super::worker::Worker;

/// An opened scene.
pub(super) struct Loaded {
    pub(super) doc: Document,
    pub(super) panorama: Pyramid,
    pub(super) history: History<Vec<Region>>,
    /// The regions as last saved (or opened), for the "unsaved" mark.
    pub(super) saved: Vec<Region>,
    pub(super) frames: usize,
}

/// A scratch folder for the display panorama, masks and preview frames; removed on drop.
pub(super) struct WorkDir(pub(super) PathBuf);

impl WorkDir {
    pub(super) fn new() -> Self {
        use std::sync::atomic::{AtomicUsize, Ordering};
        static COUNT: AtomicUsize = AtomicUsize::new(0);
        let n = COUNT.fetch_add(1, Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("pano4d-edit-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let _ = std::fs::create_dir_all(&dir);
        Self(dir)
    }
}

impl Drop for WorkDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

impl EditorApp {
    pub(super) fn poll_open(&mut self, ctx: &egui::Context) {
        let Some(job) = &self.opening else {
            return;
        };
        match job.poll() {
            None => {
                self.status = format!("Opening {}… {:.0} s", self.scene.display(), job.seconds());
                ctx.request_repaint_after(std::time::Duration::from_millis(200));
            }
            Some(Ok(loaded)) => {
                self.status = format!(
                    "{} region(s); {}×{} panorama",
                    loaded.doc.regions.len(),
                    loaded.doc.width,
                    loaded.doc.height
                );
                self.loaded = Some(loaded);
                self.opening = None;
            }
            Some(Err(e)) => {
                self.status.clear();
                self.error = Some(e);
                self.opening = None;
            }
        }
    }

    /// Starts writing scene.yaml (and painted masks beside it) through Python.
    pub fn save(&mut self) {
        let Some(loaded) = &mut self.loaded else {
            return;
        };
        if self.saving.is_some() {
            return;
        }
        loaded.history.commit(&loaded.doc.regions);
        match regions_json(&loaded.doc, &self.work.0) {
            Ok(json) => {
                let (python, scene) = (self.python.clone(), self.scene.clone());
                let job = Worker::start(move || python.save(&scene, &json));
                self.saving = Some((job, loaded.doc.regions.clone()));
                self.status = "Saving…".into();
            }
            Err(e) => self.status = format!("Not saved: {e}"),
        }
    }

    pub(super) fn poll_save(&mut self, ctx: &egui::Context) {
        let (Some((job, _)), Some(loaded)) = (&self.saving, &mut self.loaded) else {
            return;
        };
        let result = match job.poll() {
            None => {
                self.status = format!("Saving… {:.0} s", job.seconds());
                ctx.request_repaint_after(std::time::Duration::from_millis(100));
                return;
            }
            Some(result) => result,
        };
        let Some((_, written)) = self.saving.take() else {
            return;
        };
        match result {
            Ok(saved) => {
                // Edits wait while a save runs, so the regions are still those written.
                debug_assert!(loaded.doc.regions == written);
                // Painted masks now have files beside scene.yaml, in region order.
                let mut masks = saved.masks.iter();
                for region in &mut loaded.doc.regions {
                    if let Shape::Mask {
                        file: file @ None, ..
                    } = &mut region.shape
                    {
                        *file = masks
                            .next()
                            .and_then(|p| p.file_name())
                            .map(|n| n.to_string_lossy().into_owned());
                    }
                }
                loaded.history.amend(&loaded.doc.regions);
                loaded.saved = loaded.doc.regions.clone();
                self.status = format!("Saved {}", saved.scene.display());
            }
            Err(e) => self.status = format!("Not saved: {e}"),
        }
    }

    /// Starts "Animate preview" for the regions as drawn.
    pub fn start_preview(&mut self) {
        let Some(loaded) = &mut self.loaded else {
            return;
        };
        let staging = self.work.0.join("preview-masks");
        let json = std::fs::create_dir_all(&staging)
            .map_err(|e| format!("cannot create {}: {e}", staging.display()))
            .and_then(|()| regions_json(&loaded.doc, &staging));
        match json {
            Ok(json) => {
                let (python, scene) = (self.python.clone(), self.scene.clone());
                let out = self.work.0.join("preview");
                self.preview_job = Some(Worker::start(move || {
                    preview::render(&python, &scene, &json, out)
                }));
                self.playback = None;
                self.status = "Rendering the preview…".into();
            }
            Err(e) => self.status = format!("No preview: {e}"),
        }
    }

    pub(super) fn poll_preview(&mut self, ctx: &egui::Context) {
        let Some(job) = &self.preview_job else {
            return;
        };
        match job.poll() {
            None => {
                self.status = format!("Rendering the preview… {:.0} s", job.seconds());
                ctx.request_repaint_after(std::time::Duration::from_millis(200));
            }
            Some(Ok(preview)) => {
                self.status = format!(
                    "Preview: {} frames at {} fps (animated in {:.1} s, {:.1} s in all)",
                    preview.frames.len(),
                    preview.fps,
                    preview.seconds,
                    job.seconds()
                );
                self.playback = Some((preview, Instant::now()));
                self.preview_job = None;
            }
            Some(Err(e)) => {
                self.status = format!("No preview: {e}");
                self.preview_job = None;
            }
        }
    }
}

/// Reads `scene` as the editor shows it: `pano4d regions show` writes the display panorama
/// and the masks into `work`; the pyramid is built here, off the UI thread too.
pub(super) fn open(python: &Python, scene: &Path, work: &Path) -> Result<Loaded, String> {
    let opened = python.show(scene, work)?;
    let doc = opened.document()?;
    let image = image::open(&opened.display)
        .map_err(|e| format!("cannot read {}: {e}", opened.display.display()))?
        .into_rgb8();
    Ok(Loaded {
        history: History::new(doc.regions.clone()),
        saved: doc.regions.clone(),
        panorama: Pyramid::new(image),
        frames: opened.frames,
        doc,
    })
}
