//! The toolbar: the view, the tools, brush and click sizes, undo / redo / save and the
//! preview; the status line under it.

use eframe::egui;

use super::app::EditorApp;
use super::tools::TOOLS;
use super::views::ViewKind;

impl EditorApp {
    pub(super) fn toolbar(&mut self, ui: &mut egui::Ui) {
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
}
