//! "Animate preview": the flow animator run on a downscaled panorama for the regions as
//! they are drawn (saved or not), on a worker thread, then played in place as a loop.

use std::path::PathBuf;
use std::time::Duration;

use super::bridge::{Python, RegionJson};
use super::views::Pyramid;

/// The preview's panorama width: a few seconds of the flow animator on a CPU.
pub const PREVIEW_WIDTH: u32 = 512;

/// A rendered loop.
pub struct Preview {
    pub frames: Vec<Pyramid>,
    pub fps: f64,
    /// How long the animator took (Python's own count, without the interpreter's start).
    pub seconds: f64,
}

impl Preview {
    /// The frame to show `elapsed` after the loop started.
    pub fn frame_at(&self, elapsed: Duration) -> usize {
        (elapsed.as_secs_f64() * self.fps) as usize % self.frames.len()
    }
}

/// Runs `pano4d regions preview` for `regions` of `scene` (frames go to `out`) and reads
/// the frames back; on a [`super::worker::Worker`].
pub fn render(
    python: &Python,
    scene: &std::path::Path,
    regions: &[RegionJson],
    out: PathBuf,
) -> Result<Preview, String> {
    // A fresh folder per run: frames of an older preview never mix in.
    let _ = std::fs::remove_dir_all(&out);
    std::fs::create_dir_all(&out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    let answer = python.preview(scene, regions, &out, PREVIEW_WIDTH)?;
    let frames = answer
        .frames
        .iter()
        .map(|path| {
            image::open(path)
                .map(|image| Pyramid::new(image.into_rgb8()))
                .map_err(|e| format!("cannot read the preview frame {}: {e}", path.display()))
        })
        .collect::<Result<Vec<_>, _>>()?;
    if frames.is_empty() {
        return Err("the preview has no frames".into());
    }
    Ok(Preview {
        frames,
        fps: answer.fps,
        seconds: answer.seconds,
    })
}
