//! Work that runs Python off the UI thread: opening, saving and the preview each take
//! seconds (the interpreter starts and imports torch), and the window keeps drawing meanwhile.

use std::sync::mpsc;
use std::thread;
use std::time::Instant;

/// One job on its own thread; the window polls it once a frame.
pub struct Worker<T> {
    receiver: mpsc::Receiver<Result<T, String>>,
    pub started: Instant,
}

impl<T: Send + 'static> Worker<T> {
    /// Runs `job` on a new thread.
    pub fn start(job: impl FnOnce() -> Result<T, String> + Send + 'static) -> Self {
        let (sender, receiver) = mpsc::channel();
        thread::spawn(move || {
            // The editor may have closed or dropped the job meanwhile: nobody to tell.
            let _ = sender.send(job());
        });
        Self {
            receiver,
            started: Instant::now(),
        }
    }

    /// The job's result; None while it runs.
    pub fn poll(&self) -> Option<Result<T, String>> {
        match self.receiver.try_recv() {
            Ok(result) => Some(result),
            Err(mpsc::TryRecvError::Empty) => None,
            Err(mpsc::TryRecvError::Disconnected) => Some(Err("the worker thread stopped".into())),
        }
    }

    /// Seconds since the job started, for the status line.
    pub fn seconds(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn wait<T: Send + 'static>(worker: &Worker<T>) -> Result<T, String> {
        loop {
            if let Some(result) = worker.poll() {
                return result;
            }
            thread::sleep(Duration::from_millis(5));
        }
    }

    #[test]
    fn a_result_and_an_error_come_back() {
        assert_eq!(wait(&Worker::start(|| Ok(7))), Ok(7));
        assert_eq!(
            wait(&Worker::<u8>::start(|| Err("no".into()))),
            Err("no".to_string())
        );
    }

    #[test]
    fn a_panicking_job_is_reported_not_waited_for() {
        let worker = Worker::<u8>::start(|| panic!("planted"));
        assert!(wait(&worker).unwrap_err().contains("stopped"));
    }
}
