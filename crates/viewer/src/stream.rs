//! Dynamic sets decoded ahead of playback on a worker thread: while one timestamp is on
//! screen the next is read from the memory-mapped file, so showing it costs only its
//! upload. Asking for a timestamp that was not prefetched decodes it on the spot.

use std::collections::{HashMap, HashSet};
use std::sync::mpsc;
use std::sync::Arc;
use std::thread;

use splat_core::gaussians::GaussianSet;

use crate::scene::Scene;

type Decoded = (usize, Result<GaussianSet, String>);

/// Decodes dynamic sets of one scene in the background.
pub struct DynamicStream {
    scene: Arc<Scene>,
    requests: mpsc::Sender<usize>,
    results: mpsc::Receiver<Decoded>,
    /// Requested and not yet taken.
    pending: HashSet<usize>,
    ready: HashMap<usize, Result<GaussianSet, String>>,
}

impl DynamicStream {
    /// Starts the worker; it ends when the stream is dropped.
    pub fn new(scene: Arc<Scene>) -> Self {
        let (requests, inbox) = mpsc::channel::<usize>();
        let (outbox, results) = mpsc::channel();
        let worker_scene = Arc::clone(&scene);
        thread::Builder::new()
            .name("pano4d-view decode".into())
            .spawn(move || {
                for t in inbox {
                    if outbox.send((t, worker_scene.dynamic_set(t))).is_err() {
                        break;
                    }
                }
            })
            .expect("spawning a thread");
        Self {
            scene,
            requests,
            results,
            pending: HashSet::new(),
            ready: HashMap::new(),
        }
    }

    /// Starts decoding timestamp `t` unless it is already on its way.
    pub fn prefetch(&mut self, t: usize) {
        if t < self.scene.num_times() && self.pending.insert(t) {
            // A send fails only if the worker died; `take` then decodes by itself.
            let _ = self.requests.send(t);
        }
    }

    /// Timestamp `t`'s dynamic set: the prefetched one (waiting for it if it is still
    /// being decoded), or decoded now.
    pub fn take(&mut self, t: usize) -> Result<GaussianSet, String> {
        while let Ok((done, set)) = self.results.try_recv() {
            self.ready.insert(done, set);
        }
        while self.pending.contains(&t) && !self.ready.contains_key(&t) {
            match self.results.recv() {
                Ok((done, set)) => {
                    self.ready.insert(done, set);
                }
                Err(_) => break,
            }
        }
        self.pending.remove(&t);
        let taken = self.ready.remove(&t);
        // Anything else decoded was a guess playback did not take (the user jumped): drop
        // it rather than hold sets that may never be shown.
        for (stale, _) in self.ready.drain() {
            self.pending.remove(&stale);
        }
        taken.unwrap_or_else(|| self.scene.dynamic_set(t))
    }

    /// Timestamps decoded or being decoded and not yet taken.
    pub fn in_flight(&self) -> usize {
        self.pending.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic;
    use splat_core::ply4d;

    #[test]
    fn prefetched_and_direct_sets_are_the_same() {
        let dir = std::env::temp_dir().join(format!("pano4d-stream-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("scene.ply4d");
        ply4d::write(&path, &synthetic::scene(500, 200, 4, 1, 9)).unwrap();
        let scene = Arc::new(Scene::open(&path).unwrap());
        let mut stream = DynamicStream::new(Arc::clone(&scene));
        stream.prefetch(2);
        stream.prefetch(3);
        stream.prefetch(2);
        stream.prefetch(99); // out of range: ignored
        assert_eq!(stream.in_flight(), 2);
        for t in [2, 0, 3, 2] {
            let got = stream.take(t).unwrap();
            assert_eq!(
                got.means,
                scene.dynamic_set(t).unwrap().means,
                "timestamp {t}"
            );
        }
        assert_eq!(stream.in_flight(), 0);
        assert!(stream.take(99).is_err());
        drop(stream);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
