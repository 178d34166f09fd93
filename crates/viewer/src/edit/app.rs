//! The region editor window: the panorama (equirect or perspective), a toolbar of tools,
//! the list of regions with the selected one's name, shape and motion, and save / undo /
//! redo / preview. Drawing never waits for Python: opening, saving and the preview run on
//! worker threads (a save holds edits, not the window, until scene.yaml is written).
//!
//! This file holds the editor's state, what tests read of it, and the order of a frame;
//! the window's jobs are sibling modules, each an `impl EditorApp` block (see `edit/mod.rs`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use eframe::egui::{self, Pos2, Rect};
use glam::DVec2;
use splat_core::camera::equirect_to_dir;

use super::bridge::{Python, Saved};
use super::document::{unwrap_near, Document, Region};
use super::drawing::ComposeKey;
use super::jobs::{open, Loaded, WorkDir};
use super::preview::Preview;
use super::tools::{Gesture, Tool};
use super::views::{PanoramaView, PerspectiveView, View, ViewKind};
use super::worker::Worker;

/// The region editor's state.
pub struct EditorApp {
    pub(super) python: Python,
    pub(super) scene: PathBuf,
    pub(super) work: WorkDir,
    pub(super) loaded: Option<Loaded>,
    /// Why the scene cannot be shown.
    pub(super) error: Option<String>,
    pub(super) status: String,
    pub(super) tool: Tool,
    /// Brush diameter in panorama pixels (at the horizon; a cap on the sphere).
    pub brush_px: f64,
    /// Side of the square a new click region grows into, in panorama pixels.
    pub click_size: f64,
    pub(super) view_kind: ViewKind,
    /// Set on the first frame, when the view's size is known.
    pub(super) panorama_view: Option<PanoramaView>,
    pub(super) perspective: PerspectiveView,
    pub(super) gesture: Option<Gesture>,
    pub(super) selected: Option<usize>,
    /// Bumped on every change of the regions: the tint and the image are redrawn.
    pub(super) version: u64,
    pub(super) labels: (u64, Vec<u8>),
    pub(super) texture: Option<egui::TextureHandle>,
    pub(super) composed: Option<ComposeKey>,
    pub(super) opening: Option<Worker<Loaded>>,
    /// The save in flight and the regions it writes.
    pub(super) saving: Option<(Worker<Saved>, Vec<Region>)>,
    pub(super) preview_job: Option<Worker<Preview>>,
    pub(super) playback: Option<(Preview, Instant)>,
    pub(super) view_rect: Rect,
    /// A close was refused once for unsaved changes: the next one closes.
    pub(super) close_warned: bool,
}

impl EditorApp {
    /// Opens `scene` through `python` (`pano4d regions show`, on a worker thread); failures
    /// are shown in the window.
    pub fn new(scene: &Path, python: Python) -> Self {
        let work = WorkDir::new();
        let opening = {
            let (python, scene, work) = (python.clone(), scene.to_path_buf(), work.0.clone());
            Worker::start(move || open(&python, &scene, &work))
        };
        Self {
            python,
            scene: scene.to_path_buf(),
            work,
            loaded: None,
            error: None,
            status: format!("Opening {}…", scene.display()),
            tool: Tool::Box,
            brush_px: 24.0,
            click_size: 128.0,
            view_kind: ViewKind::Panorama,
            panorama_view: None,
            perspective: PerspectiveView::default(),
            gesture: None,
            selected: None,
            version: 0,
            labels: (u64::MAX, Vec::new()),
            texture: None,
            composed: None,
            opening: Some(opening),
            saving: None,
            preview_job: None,
            playback: None,
            view_rect: Rect::NOTHING,
            close_warned: false,
        }
    }

    // --- what tests and the screenshot read -------------------------------------------
    pub fn error(&self) -> Option<&str> {
        self.error.as_deref()
    }

    pub fn status(&self) -> &str {
        &self.status
    }

    pub fn document(&self) -> Option<&Document> {
        self.loaded.as_ref().map(|l| &l.doc)
    }

    pub fn selected(&self) -> Option<usize> {
        self.selected
    }

    /// Where the panorama was drawn in the last pass, in points.
    pub fn view_rect(&self) -> Rect {
        self.view_rect
    }

    /// The view shown in the last pass.
    pub fn view(&self) -> View {
        match (self.view_kind, self.panorama_view) {
            (ViewKind::Panorama, Some(view)) => View::Panorama(view),
            (ViewKind::Panorama, None) => View::Panorama(PanoramaView::fit(
                self.view_rect,
                self.size().0,
                self.size().1,
            )),
            (ViewKind::Perspective, _) => View::Perspective(self.perspective),
        }
    }

    /// Points the perspective view (tests, the screenshot).
    pub fn perspective_mut(&mut self) -> &mut PerspectiveView {
        &mut self.perspective
    }

    /// The screen point of panorama pixel `uv` in the current view (the copy nearest the
    /// view's centre in the equirect view).
    pub fn screen_of(&self, uv: DVec2) -> Option<Pos2> {
        let (w, h) = self.size();
        match self.view() {
            View::Panorama(view) => {
                let u = unwrap_near(uv.x, view.centre.x, w);
                Some(view.to_screen(self.view_rect, DVec2::new(u, uv.y)))
            }
            View::Perspective(view) => {
                view.to_screen(self.view_rect, equirect_to_dir(uv.x, uv.y, w, h))
            }
        }
    }

    /// The panorama pixel under screen point `p` in the current view.
    pub fn pixel_at(&self, p: Pos2) -> Option<DVec2> {
        let (w, h) = self.size();
        self.view().to_pixel(self.view_rect, p, w, h)
    }

    /// Whether the scene is being opened or saved (the window draws; edits wait).
    pub fn working(&self) -> bool {
        self.opening.is_some() || self.saving.is_some()
    }

    /// Whether a preview is being rendered or played.
    pub fn preview_state(&self) -> (bool, Option<usize>) {
        let playing = self
            .playback
            .as_ref()
            .map(|(preview, start)| preview.frame_at(start.elapsed()));
        (self.preview_job.is_some(), playing)
    }

    /// The preview frame the view image last drawn shows (the clock moves on between a
    /// frame being drawn and being looked at).
    pub fn shown_preview_frame(&self) -> Option<usize> {
        self.composed.and_then(|key| key.preview_frame)
    }

    /// Whether the regions differ from the file's.
    pub fn unsaved(&self) -> bool {
        self.loaded
            .as_ref()
            .is_some_and(|l| l.doc.regions != l.saved)
    }

    pub(super) fn size(&self) -> (u32, u32) {
        self.loaded
            .as_ref()
            .map_or((2, 1), |l| (l.doc.width, l.doc.height))
    }
}

impl eframe::App for EditorApp {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        self.poll_open(&ctx);
        self.poll_save(&ctx);
        self.guard_close(&ctx);
        self.handle_keys(&ctx);
        self.poll_preview(&ctx);
        if self.playback.is_some() {
            ctx.request_repaint();
        }
        let editable = !self.working();
        egui::Panel::top("editor-tools").show(ui, |ui| {
            ui.add_enabled_ui(editable, |ui| self.toolbar(ui));
        });
        egui::Panel::right("editor-regions")
            .resizable(true)
            .show(ui, |ui| {
                ui.add_enabled_ui(editable, |ui| {
                    egui::ScrollArea::vertical().show(ui, |ui| self.regions_panel(ui));
                });
            });
        egui::CentralPanel::default()
            .frame(egui::Frame::NONE)
            .show(ui, |ui| self.view_panel(ui));
        // An edit is one undo step once it is finished: no button held, no text being typed.
        let idle = ctx.input(|i| !i.pointer.any_down()) && ctx.memory(|m| m.focused().is_none());
        if let (true, None, Some(loaded)) = (idle, self.gesture, &mut self.loaded) {
            loaded.history.commit(&loaded.doc.regions);
        }
    }
}
