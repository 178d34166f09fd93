//! The region editor, `pano4d-view --edit scene.yaml`: draw what moves on the panorama.
//!
//! - [`document`]: the regions in panorama pixels (boxes that may cross the seam, clicks,
//!   painted masks), brush caps on the sphere, the motion arrows.
//! - [`history`]: undo and redo.
//! - [`views`]: the equirect and perspective views and the image composed for them.
//! - [`bridge`]: `pano4d regions show | save | preview`, the Python side that owns
//!   scene.yaml.
//! - [`preview`]: "Animate preview": the flow animator's loop.
//! - [`worker`]: opening, saving and the preview off the UI thread.
//! - [`app`]: the editor window: its state, what tests read of it, the order of a frame.
//!   Its jobs are private modules, each an `impl EditorApp` block:
//!   - `jobs`: opening, saving and the preview on [`worker`]s, and polling them;
//!   - `edits`: changes to the regions (add, delete, undo / redo, brush, direction);
//!   - `keys`: the keyboard shortcuts and the guard against closing unsaved;
//!   - `tools`: the tools, and the pointer on the view (navigation, gestures);
//!   - `drawing`: the view's image and the overlays over it;
//!   - `toolbar`, `region_panel`, `view_panel`: the three panels.

pub mod app;
pub mod bridge;
pub mod document;
pub mod history;
pub mod preview;
pub mod views;
pub mod worker;

mod drawing;
mod edits;
mod jobs;
mod keys;
mod region_panel;
mod toolbar;
mod tools;
mod view_panel;
