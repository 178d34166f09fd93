//! The tools and the pointer on the view: navigation (pan, look around, zoom) and the
//! gestures that draw boxes, clicks, brush strokes and motion arrows.

use eframe::egui::{self, PointerButton, Pos2, Rect};
use glam::{DVec2, DVec3};
use splat_core::camera::equirect_to_dir;

use super::app::EditorApp;
use super::document::{direction_of_drag, unwrap_near, PixelBox, Region, Shape};
use super::views::ViewKind;
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

pub(super) const TOOLS: [(Tool, &str, &str); 6] = [
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
pub(super) enum Gesture {
    Box { start: DVec2, end: DVec2 },
    Arrow { start: DVec2, end: DVec2 },
    Stroke { last: DVec3 },
}

impl EditorApp {
    /// The view's pointer handling: navigation on the secondary / middle button (and on
    /// the primary with the Navigate tool), the tool on the primary button.
    pub(super) fn interact(&mut self, ui: &egui::Ui, response: &egui::Response, rect: Rect) {
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
        if self.working() {
            // Looking around goes on while a save runs; the regions wait for it.
            return;
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
}
