//! The regions panel: the list of regions, and the selected one's name, shape and motion.

use eframe::egui;

use super::app::EditorApp;
use super::document::{Shape, DEFAULT_MOTION};
use super::views::region_colour;

impl EditorApp {
    pub(super) fn regions_panel(&mut self, ui: &mut egui::Ui) {
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
}
