//! The region editor window: the panorama (equirect or perspective), a toolbar of tools,
//! the list of regions with the selected one's name, shape and motion, and save / undo /
//! redo / preview. Drawing never blocks on Python except opening and saving.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use eframe::egui::{self, Color32, Key, PointerButton, Pos2, Rect, Sense, Stroke};
use glam::{DVec2, DVec3};
use splat_core::camera::equirect_to_dir;

use super::bridge::{regions_json, Python};
use super::document::{
    direction_of_drag, unwrap_near, Document, Motion, PixelBox, Region, Shape, DEFAULT_MOTION,
};
use super::history::History;
use super::preview::{Preview, PreviewJob};
use super::views::{
    compose, region_colour, PanoramaView, PerspectiveView, Pyramid, Tint, View, ViewKind,
};
use crate::camera::{MAX_FOV_DEG, MIN_FOV_DEG};

/// What a primary drag or click in the view does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tool {
    /// Drag pans (equirect) or looks around (perspective); a click selects a region.
    Navigate,
    /// Drag a box.
    Box,
    /// Paint into the selected mask region (a new one if none is selected).
    Paint,
    /// Erase from the selected mask region.
    Erase,
    /// A click adds a click region.
    Click,
    /// Drag the selected region's motion direction.
    Arrow,
}

const TOOLS: [(Tool, &str, &str); 6] = [
    (
        Tool::Navigate,
        "Navigate",
        "drag: pan / look around; click: select a region",
    ),
    (Tool::Box, "Box", "drag a box (across the seam too)"),
    (
        Tool::Paint,
        "Paint",
        "paint a mask region (the selected one, or a new one)",
    ),
    (Tool::Erase, "Erase", "erase from the selected mask region"),
    (
        Tool::Click,
        "Click",
        "click: a region grown from that point",
    ),
    (
        Tool::Arrow,
        "Arrow",
        "drag: the selected region's motion direction",
    ),
];

/// A drag in progress, in panorama pixels with u continuous.
#[derive(Clone, Copy, Debug)]
enum Gesture {
    Box { start: DVec2, end: DVec2 },
    Arrow { start: DVec2, end: DVec2 },
    Stroke { last: DVec3 },
}

/// An opened scene.
struct Loaded {
    doc: Document,
    panorama: Pyramid,
    history: History<Vec<Region>>,
    /// The regions as last saved (or opened), for the "unsaved" mark.
    saved: Vec<Region>,
    frames: usize,
}

/// A scratch folder for the display panorama, masks and preview frames; removed on drop.
struct WorkDir(PathBuf);

impl WorkDir {
    fn new() -> Self {
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

/// What the view image was composed from; a new image only when it changes.
#[derive(Clone, Copy, Debug, PartialEq)]
struct ComposeKey {
    view: View,
    rect: Rect,
    pixels_per_point: f32,
    version: u64,
    selected: Option<usize>,
    preview_frame: Option<usize>,
}

/// The region editor's state.
pub struct EditorApp {
    python: Python,
    scene: PathBuf,
    work: WorkDir,
    loaded: Option<Loaded>,
    /// Why the scene cannot be shown.
    error: Option<String>,
    status: String,
    tool: Tool,
    /// Brush diameter in panorama pixels (at the horizon; a cap on the sphere).
    pub brush_px: f64,
    /// Side of the square a new click region grows into, in panorama pixels.
    pub click_size: f64,
    view_kind: ViewKind,
    /// Set on the first frame, when the view's size is known.
    panorama_view: Option<PanoramaView>,
    perspective: PerspectiveView,
    gesture: Option<Gesture>,
    selected: Option<usize>,
    /// Bumped on every change of the regions: the tint and the image are redrawn.
    version: u64,
    labels: (u64, Vec<u8>),
    texture: Option<egui::TextureHandle>,
    composed: Option<ComposeKey>,
    preview_job: Option<PreviewJob>,
    playback: Option<(Preview, Instant)>,
    view_rect: Rect,
    /// A close was refused once for unsaved changes: the next one closes.
    close_warned: bool,
}

impl EditorApp {
    /// Opens `scene` through `python` (`pano4d regions show`); failures are shown in the
    /// window.
    pub fn new(scene: &Path, python: Python) -> Self {
        let mut app = Self {
            python,
            scene: scene.to_path_buf(),
            work: WorkDir::new(),
            loaded: None,
            error: None,
            status: String::new(),
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
            preview_job: None,
            playback: None,
            view_rect: Rect::NOTHING,
            close_warned: false,
        };
        match app.open() {
            Ok(loaded) => {
                app.status = format!(
                    "{} region(s); {}×{} panorama",
                    loaded.doc.regions.len(),
                    loaded.doc.width,
                    loaded.doc.height
                );
                app.loaded = Some(loaded);
            }
            Err(e) => app.error = Some(e),
        }
        app
    }

    fn open(&self) -> Result<Loaded, String> {
        let opened = self.python.show(&self.scene, &self.work.0)?;
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

    /// Closing with unsaved changes is refused once, with a warning; the next close
    /// discards them.
    fn guard_close(&mut self, ctx: &egui::Context) {
        if !ctx.input(|i| i.viewport().close_requested()) || !self.unsaved() {
            return;
        }
        if !self.close_warned {
            ctx.send_viewport_cmd(egui::ViewportCommand::CancelClose);
            self.close_warned = true;
            self.status = "Unsaved changes: Save (ctrl+S), or close again to discard them".into();
        }
    }

    fn size(&self) -> (u32, u32) {
        self.loaded
            .as_ref()
            .map_or((2, 1), |l| (l.doc.width, l.doc.height))
    }

    // --- edits --------------------------------------------------------------------------
    fn changed(&mut self) {
        self.version += 1;
        // A preview shows the regions it was made for; edits make it stale.
        self.playback = None;
    }

    fn add_region(&mut self, region: Region) {
        let Some(loaded) = &mut self.loaded else {
            return;
        };
        loaded.doc.regions.push(region);
        self.selected = Some(loaded.doc.regions.len() - 1);
        self.changed();
    }

    fn delete_selected(&mut self) {
        let (Some(loaded), Some(index)) = (&mut self.loaded, self.selected) else {
            return;
        };
        let region = loaded.doc.regions.remove(index);
        self.status = format!("Deleted {}", region.label(index));
        self.selected = None;
        self.changed();
    }

    fn undo(&mut self) {
        if let Some(loaded) = &mut self.loaded {
            if let Some(regions) = loaded.history.undo(&loaded.doc.regions) {
                loaded.doc.regions = regions;
                self.after_history_step();
            }
        }
    }

    fn redo(&mut self) {
        if let Some(loaded) = &mut self.loaded {
            if let Some(regions) = loaded.history.redo(&loaded.doc.regions) {
                loaded.doc.regions = regions;
                self.after_history_step();
            }
        }
    }

    fn after_history_step(&mut self) {
        let count = self.loaded.as_ref().map_or(0, |l| l.doc.regions.len());
        self.selected = self.selected.filter(|&i| i < count);
        self.gesture = None;
        self.changed();
    }

    /// Writes scene.yaml (and painted masks beside it) through Python.
    pub fn save(&mut self) {
        let Some(loaded) = &mut self.loaded else {
            return;
        };
        loaded.history.commit(&loaded.doc.regions);
        let result = regions_json(&loaded.doc, &self.work.0)
            .and_then(|json| self.python.save(&self.scene, &json));
        match result {
            Ok(saved) => {
                // Painted masks now have files beside scene.yaml, in region order.
                let mut written = saved.masks.iter();
                for region in &mut loaded.doc.regions {
                    if let Shape::Mask {
                        file: file @ None, ..
                    } = &mut region.shape
                    {
                        *file = written
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
                self.preview_job = Some(PreviewJob::start(
                    self.python.clone(),
                    self.scene.clone(),
                    json,
                    self.work.0.join("preview"),
                ));
                self.playback = None;
                self.status = "Rendering the preview…".into();
            }
            Err(e) => self.status = format!("No preview: {e}"),
        }
    }

    fn poll_preview(&mut self, ctx: &egui::Context) {
        let Some(job) = &self.preview_job else {
            return;
        };
        match job.poll() {
            None => {
                self.status = format!(
                    "Rendering the preview… {:.0} s",
                    job.started.elapsed().as_secs_f64()
                );
                ctx.request_repaint_after(std::time::Duration::from_millis(200));
            }
            Some(Ok(preview)) => {
                self.status = format!(
                    "Preview: {} frames at {} fps (animated in {:.1} s, {:.1} s in all)",
                    preview.frames.len(),
                    preview.fps,
                    preview.seconds,
                    job.started.elapsed().as_secs_f64()
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

    /// Paints (or erases) a dab of the brush at direction `d` into the selected mask.
    fn dab(&mut self, d: DVec3, erase: bool) {
        let (Some(loaded), Some(index)) = (&mut self.loaded, self.selected) else {
            return;
        };
        let radius = self.brush_px / 2.0 * std::f64::consts::TAU / loaded.doc.width as f64;
        if let Shape::Mask { mask, file } = &mut loaded.doc.regions[index].shape {
            // Copy on write: the history keeps the mask as it was before this stroke.
            Arc::make_mut(mask).paint_cap(d, radius, !erase);
            *file = None;
            self.changed();
        }
    }

    /// Dabs from `from` to `to` along the great circle, half a radius apart.
    fn stroke(&mut self, from: DVec3, to: DVec3, erase: bool) {
        let width = self.size().0 as f64;
        let step = (self.brush_px / 4.0 * std::f64::consts::TAU / width).max(1e-6);
        let angle = from.angle_between(to);
        let steps = (angle / step).ceil().max(1.0) as usize;
        for k in 1..=steps {
            let t = k as f64 / steps as f64;
            self.dab(from.lerp(to, t).normalize(), erase);
        }
    }

    /// Makes sure the selection is a mask region to paint into: a new one for Paint when
    /// none is, an explanation for Erase.
    fn paint_target(&mut self, erase: bool) -> bool {
        let Some(loaded) = &self.loaded else {
            return false;
        };
        let is_mask = self
            .selected
            .is_some_and(|i| matches!(loaded.doc.regions[i].shape, Shape::Mask { .. }));
        if is_mask {
            return true;
        }
        if erase {
            self.status = "Select a mask region to erase from".into();
            return false;
        }
        let mask = loaded.doc.new_mask();
        self.add_region(Region {
            name: None,
            shape: Shape::Mask {
                mask: Arc::new(mask),
                file: None,
            },
            motion: None,
        });
        true
    }

    fn set_direction(&mut self, direction_deg: f64) {
        let (Some(loaded), Some(index)) = (&mut self.loaded, self.selected) else {
            self.status = "Select a region to give it a motion direction".into();
            return;
        };
        let region = &mut loaded.doc.regions[index];
        let speed = region.motion_or_default().speed;
        region.motion = Some(Motion {
            direction_deg,
            speed,
        });
        self.status = format!("{}: direction {direction_deg:.1}°", region.label(index));
        self.changed();
    }

    // --- input ---------------------------------------------------------------------------
    fn handle_keys(&mut self, ctx: &egui::Context) {
        if ctx.egui_wants_keyboard_input() {
            return;
        }
        let (undo, redo, save, delete) = ctx.input(|i| {
            let command = i.modifiers.command;
            (
                command && !i.modifiers.shift && i.key_pressed(Key::Z),
                command && (i.key_pressed(Key::Y) || (i.modifiers.shift && i.key_pressed(Key::Z))),
                command && i.key_pressed(Key::S),
                i.key_pressed(Key::Delete),
            )
        });
        if undo {
            self.undo();
        }
        if redo {
            self.redo();
        }
        if save {
            self.save();
        }
        if delete {
            self.delete_selected();
        }
    }

    /// The view's pointer handling: navigation on the secondary / middle button (and on
    /// the primary with the Navigate tool), the tool on the primary button.
    fn interact(&mut self, ui: &egui::Ui, response: &egui::Response, rect: Rect) {
        let (w, h) = self.size();
        let navigating = response.dragged_by(PointerButton::Secondary)
            || response.dragged_by(PointerButton::Middle)
            || (self.tool == Tool::Navigate && response.dragged_by(PointerButton::Primary));
        if navigating {
            let delta = response.drag_delta();
            match self.view_kind {
                ViewKind::Panorama => {
                    if let Some(view) = &mut self.panorama_view {
                        view.pan(delta);
                    }
                }
                ViewKind::Perspective => {
                    self.perspective.camera.drag(delta.x as f64, delta.y as f64);
                }
            }
        }
        if response.hovered() {
            let scroll = ui.input(|i| i.smooth_scroll_delta.y as f64);
            if scroll != 0.0 {
                match self.view_kind {
                    ViewKind::Panorama => {
                        let at = response.hover_pos().unwrap_or(rect.center());
                        let min = rect.height() as f64 / h as f64;
                        if let Some(view) = &mut self.panorama_view {
                            view.zoom_at(rect, at, 1.002_f64.powf(scroll), min);
                        }
                    }
                    ViewKind::Perspective => {
                        let camera = &mut self.perspective.camera;
                        camera.zoom(scroll / 50.0);
                        camera.fov_deg = camera.fov_deg.clamp(MIN_FOV_DEG, MAX_FOV_DEG);
                    }
                }
            }
        }
        let view = self.view();
        let pixel = |p: Pos2| view.to_pixel(rect, p, w, h);
        let pointer = response.interact_pointer_pos();
        let origin = ui.input(|i| i.pointer.press_origin());

        if response.clicked_by(PointerButton::Primary) {
            let Some(at) = pointer.and_then(pixel) else {
                return;
            };
            match self.tool {
                Tool::Navigate | Tool::Box | Tool::Arrow => {
                    self.selected = self.document().and_then(|d| d.region_at(at.x, at.y));
                }
                Tool::Click => {
                    let at = DVec2::new(at.x.rem_euclid(w as f64).round(), at.y.round());
                    self.add_region(Region {
                        name: None,
                        shape: Shape::Click {
                            at,
                            size: self.click_size,
                        },
                        motion: None,
                    });
                }
                Tool::Paint | Tool::Erase => {
                    let erase = self.tool == Tool::Erase;
                    if self.paint_target(erase) {
                        self.dab(equirect_to_dir(at.x, at.y, w, h), erase);
                    }
                }
            }
            return;
        }
        if response.drag_started_by(PointerButton::Primary) {
            let Some(start) = origin.and_then(pixel) else {
                return;
            };
            let tool = self.tool;
            let erase = tool == Tool::Erase;
            self.gesture = match tool {
                Tool::Box => Some(Gesture::Box { start, end: start }),
                Tool::Arrow => Some(Gesture::Arrow { start, end: start }),
                Tool::Paint | Tool::Erase if self.paint_target(erase) => {
                    let d = equirect_to_dir(start.x, start.y, w, h);
                    self.dab(d, erase);
                    Some(Gesture::Stroke { last: d })
                }
                _ => None,
            };
        }
        if response.dragged_by(PointerButton::Primary) {
            if let Some(now) = pointer.and_then(pixel) {
                match &mut self.gesture {
                    Some(Gesture::Box { end, .. } | Gesture::Arrow { end, .. }) => {
                        // Follow the pointer continuously across the seam.
                        *end = DVec2::new(unwrap_near(now.x, end.x, w), now.y);
                    }
                    Some(Gesture::Stroke { last }) => {
                        let (from, to) = (*last, equirect_to_dir(now.x, now.y, w, h));
                        *last = to;
                        self.stroke(from, to, self.tool == Tool::Erase);
                    }
                    None => {}
                }
            }
        }
        if response.drag_stopped_by(PointerButton::Primary) {
            match self.gesture.take() {
                Some(Gesture::Box { start, end }) => {
                    match PixelBox::from_corners(start, end, w, h) {
                        Some(b) => self.add_region(Region {
                            name: None,
                            shape: Shape::Box(b),
                            motion: None,
                        }),
                        None => self.status = "The box has no area".into(),
                    }
                }
                Some(Gesture::Arrow { start, end }) => match direction_of_drag(start, end) {
                    Some(direction) => self.set_direction(direction),
                    None => self.status = "Drag further to set a direction".into(),
                },
                Some(Gesture::Stroke { .. }) | None => {}
            }
        }
    }

    // --- drawing -------------------------------------------------------------------------
    fn draw_image(&mut self, ctx: &egui::Context, painter: &egui::Painter, rect: Rect) {
        let Some(loaded) = &self.loaded else {
            return;
        };
        let preview_frame = self
            .playback
            .as_ref()
            .map(|(preview, start)| preview.frame_at(start.elapsed()));
        let key = ComposeKey {
            view: self.view(),
            rect,
            pixels_per_point: ctx.pixels_per_point(),
            version: self.version,
            selected: self.selected,
            preview_frame,
        };
        if self.composed != Some(key) {
            if self.labels.0 != self.version {
                self.labels = (self.version, loaded.doc.labels());
            }
            let doc = &loaded.doc;
            let tint = Tint {
                labels: &self.labels.1,
                width: doc.mask_width,
                height: doc.mask_height,
                selected: self.selected,
            };
            // The preview plays without the tint, so the motion shows.
            let (source, tint) = match (&self.playback, preview_frame) {
                (Some((preview, _)), Some(t)) => (&preview.frames[t], None),
                _ => (&loaded.panorama, Some(&tint)),
            };
            let image = compose(
                &key.view,
                rect,
                key.pixels_per_point,
                source,
                tint,
                doc.width,
                doc.height,
            );
            match &mut self.texture {
                Some(texture) => texture.set(image, egui::TextureOptions::NEAREST),
                None => {
                    self.texture =
                        Some(ctx.load_texture("editor-view", image, egui::TextureOptions::NEAREST))
                }
            }
            self.composed = Some(key);
        }
        if let Some(texture) = &self.texture {
            let uv = Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0));
            painter.image(texture.id(), rect, uv, Color32::WHITE);
        }
    }

    /// Outlines, names, arrows, the gesture in progress and the brush.
    fn draw_overlays(&self, painter: &egui::Painter, rect: Rect, hover: Option<Pos2>) {
        let Some(loaded) = &self.loaded else {
            return;
        };
        let doc = &loaded.doc;
        let (w, h) = (doc.width, doc.height);
        let view = self.view();
        let lines = |path: &[DVec2], stroke: Stroke| {
            for line in view.polylines(rect, path, w, h) {
                painter.line(line, stroke);
            }
        };
        for (index, region) in doc.regions.iter().enumerate() {
            let colour = region_colour(index);
            let selected = self.selected == Some(index);
            let width = if selected { 3.0 } else { 1.5 };
            let outline = match &region.shape {
                Shape::Box(b) => Some(*b),
                Shape::Click { at, size } => {
                    if let Some(p) = self.screen_of(*at) {
                        painter.circle_filled(p, 4.0, colour);
                    }
                    Some(super::document::click_box(*at, *size, w, h))
                }
                Shape::Mask { .. } => None,
            };
            if let Some(b) = outline {
                lines(&b.outline(w, 32), Stroke::new(width, colour));
            }
            // The arrow: the motion the animator will apply, faint when it is the default.
            let path = doc.motion_path(index, loaded.frames, 24);
            let arrow = if region.motion.is_some() {
                Color32::WHITE
            } else {
                Color32::from_white_alpha(110)
            };
            for line in view.polylines(rect, &path, w, h) {
                draw_arrow(
                    painter,
                    &line,
                    Stroke::new(if selected { 3.0 } else { 2.0 }, arrow),
                );
            }
            if let Some(p) = self
                .screen_of(doc.anchor(index))
                .filter(|p| rect.contains(*p))
            {
                let motion = region.motion_or_default();
                let text = format!("{}  {:.1}°/frame", region.label(index), motion.speed);
                let galley = painter.layout_no_wrap(text, egui::FontId::proportional(13.0), colour);
                // Below the anchor: arrows mostly run sideways or up from it.
                let at = p + egui::vec2(-galley.size().x / 2.0, 10.0);
                let backdrop = Rect::from_min_size(at, galley.size()).expand(3.0);
                painter.rect_filled(backdrop, 3.0, Color32::from_black_alpha(170));
                painter.galley(at, galley, colour);
            }
        }
        match self.gesture {
            Some(Gesture::Box { start, end }) => {
                if let Some(b) = PixelBox::from_corners(start, end, w, h) {
                    lines(&b.outline(w, 32), Stroke::new(2.0, Color32::WHITE));
                }
            }
            Some(Gesture::Arrow { start, end }) => {
                let path: Vec<DVec2> = (0..=16).map(|k| start.lerp(end, k as f64 / 16.0)).collect();
                for line in view.polylines(rect, &path, w, h) {
                    draw_arrow(painter, &line, Stroke::new(3.0, Color32::YELLOW));
                }
            }
            _ => {}
        }
        if matches!(self.tool, Tool::Paint | Tool::Erase) {
            if let Some(at) = hover.and_then(|p| view.to_pixel(rect, p, w, h)) {
                let radius = self.brush_px / 2.0 * std::f64::consts::TAU / w as f64;
                let rim = cap_rim(equirect_to_dir(at.x, at.y, w, h), radius, w, h, at.x);
                lines(&rim, Stroke::new(1.5, Color32::WHITE));
            }
        }
    }

    // --- panels --------------------------------------------------------------------------
    fn toolbar(&mut self, ui: &mut egui::Ui) {
        ui.horizontal_wrapped(|ui| {
            let before = self.view_kind;
            ui.selectable_value(&mut self.view_kind, ViewKind::Panorama, "Panorama");
            ui.selectable_value(&mut self.view_kind, ViewKind::Perspective, "Perspective");
            if before != self.view_kind {
                self.gesture = None;
            }
            ui.separator();
            for (tool, label, hint) in TOOLS {
                ui.selectable_value(&mut self.tool, tool, label)
                    .on_hover_text(hint);
            }
            ui.separator();
            let brush = ui.label("Brush px");
            ui.add(egui::DragValue::new(&mut self.brush_px).range(1.0..=1024.0))
                .labelled_by(brush.id);
            let click = ui.label("Click size px");
            ui.add(egui::DragValue::new(&mut self.click_size).range(8.0..=4096.0))
                .labelled_by(click.id);
            ui.separator();
            let unsaved = self.unsaved();
            let (can_undo, can_redo) = self.loaded.as_ref().map_or((false, false), |l| {
                (
                    l.history.can_undo(&l.doc.regions),
                    l.history.can_redo(&l.doc.regions),
                )
            });
            if ui
                .add_enabled(can_undo, egui::Button::new("Undo"))
                .on_hover_text("ctrl+Z")
                .clicked()
            {
                self.undo();
            }
            if ui
                .add_enabled(can_redo, egui::Button::new("Redo"))
                .on_hover_text("ctrl+shift+Z")
                .clicked()
            {
                self.redo();
            }
            let save = if unsaved { "Save *" } else { "Save" };
            if ui
                .add_enabled(self.loaded.is_some(), egui::Button::new(save))
                .on_hover_text("ctrl+S")
                .clicked()
            {
                self.save();
            }
            if self.playback.is_some() {
                if ui.button("Stop preview").clicked() {
                    self.playback = None;
                }
            } else {
                let idle = self.preview_job.is_none() && self.loaded.is_some();
                if ui
                    .add_enabled(idle, egui::Button::new("Animate preview"))
                    .on_hover_text(
                        "the flow animator on a small panorama, for the regions as drawn",
                    )
                    .clicked()
                {
                    self.start_preview();
                }
            }
        });
        if !self.status.is_empty() {
            ui.label(&self.status);
        }
    }

    fn regions_panel(&mut self, ui: &mut egui::Ui) {
        ui.heading("Regions");
        ui.label(self.scene.display().to_string());
        let Some(loaded) = &mut self.loaded else {
            return;
        };
        ui.separator();
        for (index, region) in loaded.doc.regions.iter().enumerate() {
            let text = format!("{} ({})", region.label(index), region.kind());
            let label = egui::RichText::new(text).color(region_colour(index));
            if ui
                .selectable_label(self.selected == Some(index), label)
                .clicked()
            {
                self.selected = Some(index);
            }
        }
        if loaded.doc.regions.is_empty() {
            ui.label("None yet: draw a box, paint, or click.");
        }
        let Some(index) = self.selected.filter(|&i| i < loaded.doc.regions.len()) else {
            return;
        };
        ui.separator();
        let mut changed = false;
        let (w, mask_width) = (loaded.doc.width, loaded.doc.mask_width);
        let region = &mut loaded.doc.regions[index];
        let name_label = ui.label("Name");
        let mut name = region.name.clone().unwrap_or_default();
        let field =
            egui::TextEdit::singleline(&mut name).hint_text(format!("region {}", index + 1));
        if ui.add(field).labelled_by(name_label.id).changed() {
            region.name = (!name.trim().is_empty()).then_some(name);
            changed = true;
        }
        match &mut region.shape {
            Shape::Box(b) => {
                let seam = if b.wraps() { " (across the seam)" } else { "" };
                ui.label(format!(
                    "box [{}, {}, {}, {}]{seam}",
                    b.u0, b.v0, b.u1, b.v1
                ));
            }
            Shape::Click { at, size } => {
                ui.label(format!("click [{}, {}]", at.x, at.y));
                let size_label = ui.label("Size px");
                changed |= ui
                    .add(egui::DragValue::new(size).range(8.0..=(2 * w) as f64))
                    .labelled_by(size_label.id)
                    .changed();
            }
            Shape::Mask { mask, file } => {
                let scale = (w / mask_width).pow(2) as usize;
                let source = file.as_deref().unwrap_or("painted, not saved yet");
                ui.label(format!("mask: {} pixels ({source})", mask.count() * scale));
            }
        }
        let mut hinted = region.motion.is_some();
        if ui.checkbox(&mut hinted, "Motion hint").changed() {
            region.motion = hinted.then_some(DEFAULT_MOTION);
            changed = true;
        }
        if let Some(motion) = &mut region.motion {
            let direction = ui.label("Direction ° (0: +u, 90: up)");
            changed |= ui
                .add(
                    egui::DragValue::new(&mut motion.direction_deg)
                        .range(-180.0..=180.0)
                        .speed(1.0),
                )
                .labelled_by(direction.id)
                .changed();
            let speed = ui.label("Speed °/frame");
            changed |= ui
                .add(
                    egui::DragValue::new(&mut motion.speed)
                        .range(0.0..=30.0)
                        .speed(0.05),
                )
                .labelled_by(speed.id)
                .changed();
        } else {
            ui.label("No hint: the default, 0° at 0.5°/frame");
        }
        if ui
            .button("Delete region")
            .on_hover_text("Delete key")
            .clicked()
        {
            self.delete_selected();
            return;
        }
        if changed {
            self.changed();
        }
    }

    fn view_panel(&mut self, ui: &mut egui::Ui) {
        let rect = ui.available_rect_before_wrap();
        self.view_rect = rect;
        if let Some(error) = &self.error {
            ui.scope_builder(egui::UiBuilder::new().max_rect(rect.shrink(16.0)), |ui| {
                ui.heading("Cannot edit the regions");
                ui.colored_label(ui.visuals().error_fg_color, error.as_str());
            });
            return;
        }
        let (w, h) = self.size();
        if self.panorama_view.is_none() && self.loaded.is_some() {
            self.panorama_view = Some(PanoramaView::fit(rect, w, h));
        }
        let response = ui.interact(
            rect,
            ui.make_persistent_id("editor-view"),
            Sense::click_and_drag(),
        );
        self.interact(ui, &response, rect);
        let painter = ui.painter_at(rect);
        self.draw_image(ui.ctx(), &painter, rect);
        self.draw_overlays(&painter, rect, response.hover_pos());
    }
}

/// A polyline with an arrowhead at its end.
fn draw_arrow(painter: &egui::Painter, line: &[Pos2], stroke: Stroke) {
    painter.line(line.to_vec(), stroke);
    let [.., a, b] = line else {
        return;
    };
    let direction = (*b - *a).normalized();
    if !direction.is_finite() {
        return;
    }
    for turn in [2.6_f32, -2.6] {
        let (s, c) = turn.sin_cos();
        let side = egui::vec2(
            direction.x * c - direction.y * s,
            direction.x * s + direction.y * c,
        );
        painter.line_segment([*b, *b + side * 10.0], stroke);
    }
}

/// The rim of the cap of `radius` round `centre`, as panorama pixels continuous in u
/// from near `u_near`.
fn cap_rim(centre: DVec3, radius: f64, width: u32, height: u32, u_near: f64) -> Vec<DVec2> {
    let c = centre.normalize();
    let helper = if c.z.abs() < 0.9 { DVec3::Z } else { DVec3::X };
    let (a, b) = (
        c.cross(helper).normalize(),
        c.cross(c.cross(helper)).normalize(),
    );
    let mut previous = u_near;
    (0..=48)
        .map(|k| {
            let t = k as f64 / 48.0 * std::f64::consts::TAU;
            let d = c * radius.cos() + (a * t.cos() + b * t.sin()) * radius.sin();
            let uv = splat_core::camera::dir_to_equirect(d, width, height);
            previous = unwrap_near(uv.x, previous, width);
            DVec2::new(previous, uv.y)
        })
        .collect()
}

impl eframe::App for EditorApp {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        self.guard_close(&ctx);
        self.handle_keys(&ctx);
        self.poll_preview(&ctx);
        if self.playback.is_some() {
            ctx.request_repaint();
        }
        egui::Panel::top("editor-tools").show(ui, |ui| self.toolbar(ui));
        egui::Panel::right("editor-regions")
            .resizable(true)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| self.regions_panel(ui));
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
