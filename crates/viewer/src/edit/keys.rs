//! The keyboard shortcuts (undo, redo, save, delete) and the guard against closing the
//! window with unsaved changes.

use eframe::egui::{self, Key, KeyboardShortcut, Modifiers};

use super::app::EditorApp;

const UNDO: KeyboardShortcut = KeyboardShortcut::new(Modifiers::COMMAND, Key::Z);
const REDO: KeyboardShortcut =
    KeyboardShortcut::new(Modifiers::COMMAND.plus(Modifiers::SHIFT), Key::Z);
const REDO_Y: KeyboardShortcut = KeyboardShortcut::new(Modifiers::COMMAND, Key::Y);
const SAVE: KeyboardShortcut = KeyboardShortcut::new(Modifiers::COMMAND, Key::S);

impl EditorApp {
    pub(super) fn handle_keys(&mut self, ctx: &egui::Context) {
        if ctx.egui_wants_keyboard_input() || self.working() {
            return;
        }
        // Each shortcut is matched against the modifiers its own key event carried, not
        // `i.modifiers` (those held at the end of the frame): a ctrl+S typed fast, or sent
        // by `xdotool key ctrl+s`, presses and releases ctrl within one frame, and then the
        // frame's modifiers no longer have ctrl. Redo is taken first: ctrl+shift+Z also
        // matches ctrl+Z (extra shift is ignored).
        let (redo, undo, save, delete) = ctx.input_mut(|i| {
            let redo = i.consume_shortcut(&REDO) || i.consume_shortcut(&REDO_Y);
            (
                redo,
                i.consume_shortcut(&UNDO),
                i.consume_shortcut(&SAVE),
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
