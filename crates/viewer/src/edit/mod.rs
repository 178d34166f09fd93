//! The region editor, `pano4d-view --edit scene.yaml`: draw what moves on the panorama.
//!
//! - [`document`]: the regions in panorama pixels (boxes that may cross the seam, clicks,
//!   painted masks), brush caps on the sphere, the motion arrows.
//! - [`history`]: undo and redo.
//! - [`views`]: the equirect and perspective views and the image composed for them.
//! - [`bridge`]: `pano4d regions show | save | preview`, the Python side that owns
//!   scene.yaml.
//! - [`preview`]: "Animate preview" on a worker thread.
//! - [`app`]: the editor window.

pub mod app;
pub mod bridge;
pub mod document;
pub mod history;
pub mod preview;
pub mod views;
