//! The central panel: the view with its pointer handling and drawing, or the error that
//! keeps the scene from being shown, or the spinner while it opens.

use eframe::egui::{self, Sense};

use super::app::EditorApp;
use super::views::PanoramaView;

impl EditorApp {
    pub(super) fn view_panel(&mut self, ui: &mut egui::Ui) {
        let rect = ui.available_rect_before_wrap();
        self.view_rect = rect;
        if let Some(error) = &self.error {
            ui.scope_builder(egui::UiBuilder::new().max_rect(rect.shrink(16.0)), |ui| {
                ui.heading("Cannot edit the regions");
                ui.colored_label(ui.visuals().error_fg_color, error.as_str());
            });
            return;
        }
        if self.opening.is_some() {
            ui.scope_builder(egui::UiBuilder::new().max_rect(rect.shrink(16.0)), |ui| {
                ui.horizontal(|ui| {
                    ui.spinner();
                    ui.label(&self.status);
                });
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
