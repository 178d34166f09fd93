//! Changes to the regions: add, delete, undo / redo, the brush and the motion direction.
//! Every change bumps the version the view image is drawn for and stops a stale preview.

use std::sync::Arc;

use glam::DVec3;

use super::app::EditorApp;
use super::document::{Motion, Region, Shape};

impl EditorApp {
    pub(super) fn changed(&mut self) {
        self.version += 1;
        // A preview shows the regions it was made for; edits make it stale.
        self.playback = None;
    }

    pub(super) fn add_region(&mut self, region: Region) {
        let Some(loaded) = &mut self.loaded else {
            return;
        };
        loaded.doc.regions.push(region);
        self.selected = Some(loaded.doc.regions.len() - 1);
        self.changed();
    }

    pub(super) fn delete_selected(&mut self) {
        let (Some(loaded), Some(index)) = (&mut self.loaded, self.selected) else {
            return;
        };
        let region = loaded.doc.regions.remove(index);
        self.status = format!("Deleted {}", region.label(index));
        self.selected = None;
        self.changed();
    }

    pub(super) fn undo(&mut self) {
        if let Some(loaded) = &mut self.loaded {
            if let Some(regions) = loaded.history.undo(&loaded.doc.regions) {
                loaded.doc.regions = regions;
                self.after_history_step();
            }
        }
    }

    pub(super) fn redo(&mut self) {
        if let Some(loaded) = &mut self.loaded {
            if let Some(regions) = loaded.history.redo(&loaded.doc.regions) {
                loaded.doc.regions = regions;
                self.after_history_step();
            }
        }
    }

    pub(super) fn after_history_step(&mut self) {
        let count = self.loaded.as_ref().map_or(0, |l| l.doc.regions.len());
        self.selected = self.selected.filter(|&i| i < count);
        self.gesture = None;
        self.changed();
    }

    /// Paints (or erases) a dab of the brush at direction `d` into the selected mask.
    pub(super) fn dab(&mut self, d: DVec3, erase: bool) {
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
    pub(super) fn stroke(&mut self, from: DVec3, to: DVec3, erase: bool) {
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
    pub(super) fn paint_target(&mut self, erase: bool) -> bool {
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

    pub(super) fn set_direction(&mut self, direction_deg: f64) {
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
}
