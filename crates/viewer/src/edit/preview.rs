//! "Animate preview": the flow animator run on a downscaled panorama for the regions as
//! they are drawn (saved or not), on a worker thread, then played in place as a loop.

use std::path::PathBuf;
use std::sync::mpsc;
use std::thread;
use std::time::{Duration, Instant};

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

/// A preview being rendered.
pub struct PreviewJob {
    receiver: mpsc::Receiver<Result<Preview, String>>,
    pub started: Instant,
}

impl PreviewJob {
    /// Starts `pano4d regions preview` for `regions` of `scene`; frames go to `out`.
    pub fn start(python: Python, scene: PathBuf, regions: Vec<RegionJson>, out: PathBuf) -> Self {
        let (sender, receiver) = mpsc::channel();
        thread::spawn(move || {
            let result = render(&python, &scene, &regions, out);
            // The editor may have closed or started another preview meanwhile.
            let _ = sender.send(result);
        });
        Self {
            receiver,
            started: Instant::now(),
        }
    }

    /// The finished preview or its error; None while it runs.
    pub fn poll(&self) -> Option<Result<Preview, String>> {
        match self.receiver.try_recv() {
            Ok(result) => Some(result),
            Err(mpsc::TryRecvError::Empty) => None,
            Err(mpsc::TryRecvError::Disconnected) => Some(Err("the preview worker stopped".into())),
        }
    }
}

fn render(
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
