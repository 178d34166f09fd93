//! The keyboard shortcuts (undo, redo, save, delete) and the guard against closing the
//! window with unsaved changes.

use eframe::egui::{self, Key};

use super::app::EditorApp;

impl EditorApp {
    pub(super) fn handle_keys(&mut self, ctx: &egui::Context) {
        if ctx.egui_wants_keyboard_input() || self.working() {
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

    /// Closing with unsaved changes is refused once, with a warning; the next close
    /// discards them.
    pub(super) fn guard_close(&mut self, ctx: &egui::Context) {
        if !ctx.input(|i| i.viewport().close_requested()) || !self.unsaved() {
            return;
        }
        if !self.close_warned {
            ctx.send_viewport_cmd(egui::ViewportCommand::CancelClose);
            self.close_warned = true;
            self.status = "Unsaved changes: Save (ctrl+S), or close again to discard them".into();
        }
    }
}
