//! Drawing the view: the image composed for the current view (the panorama tinted with
//! the regions, or a preview frame), redrawn only when what it shows changes, and the
//! overlays over it (outlines, names, motion arrows, the gesture in progress, the brush).

use eframe::egui::{self, Color32, Pos2, Rect, Stroke};
use glam::{DVec2, DVec3};
use splat_core::camera::equirect_to_dir;

use super::app::EditorApp;
use super::document::{click_box, unwrap_near, PixelBox, Shape};
use super::tools::{Gesture, Tool};
use super::views::{compose, region_colour, Tint, View};

/// What the view image was composed from; a new image only when it changes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct ComposeKey {
    pub(super) view: View,
    pub(super) rect: Rect,
    pub(super) pixels_per_point: f32,
    pub(super) version: u64,
    pub(super) selected: Option<usize>,
    pub(super) preview_frame: Option<usize>,
}

impl EditorApp {
    pub(super) fn draw_image(&mut self, ctx: &egui::Context, painter: &egui::Painter, rect: Rect) {
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
    pub(super) fn draw_overlays(&self, painter: &egui::Painter, rect: Rect, hover: Option<Pos2>) {
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
                    Some(click_box(*at, *size, w, h))
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
