//! Playback over a scene's timestamps: play/pause, loop, speed, frame steps.

/// Where playback is and how it moves.
#[derive(Clone, Debug, PartialEq)]
pub struct TimeControl {
    timestamps: Vec<f64>,
    /// The timestamp shown.
    pub index: usize,
    pub playing: bool,
    pub looping: bool,
    /// Playback rate relative to real time.
    pub speed: f64,
    /// Seconds since the first timestamp, advanced while playing.
    clock: f64,
}

impl TimeControl {
    /// `timestamps` in seconds, ascending; an empty list is treated as a single moment.
    pub fn new(timestamps: &[f64]) -> Self {
        let timestamps = if timestamps.is_empty() {
            vec![0.0]
        } else {
            timestamps.to_vec()
        };
        Self {
            timestamps,
            index: 0,
            playing: false,
            looping: true,
            speed: 1.0,
            clock: 0.0,
        }
    }

    pub fn count(&self) -> usize {
        self.timestamps.len()
    }

    /// Seconds of the shown timestamp.
    pub fn seconds(&self) -> f64 {
        self.timestamps[self.index]
    }

    /// Typical spacing of the timestamps (1/10 s for a single one).
    fn frame_period(&self) -> f64 {
        let n = self.timestamps.len();
        if n < 2 {
            return 0.1;
        }
        let span = self.timestamps[n - 1] - self.timestamps[0];
        if span > 0.0 {
            span / (n - 1) as f64
        } else {
            0.1
        }
    }

    /// One loop's length: the span plus one frame, so the last frame is shown as long as the others.
    fn loop_length(&self) -> f64 {
        self.timestamps[self.timestamps.len() - 1] - self.timestamps[0] + self.frame_period()
    }

    /// Jumps to timestamp `index` (clamped) and keeps playing from there.
    pub fn set_index(&mut self, index: usize) {
        self.index = index.min(self.count() - 1);
        self.clock = self.timestamps[self.index] - self.timestamps[0];
    }

    /// Moves `delta` frames, wrapping around when looping; pauses playback.
    pub fn step(&mut self, delta: i64) {
        self.playing = false;
        let n = self.count() as i64;
        let target = self.index as i64 + delta;
        let index = if self.looping {
            target.rem_euclid(n)
        } else {
            target.clamp(0, n - 1)
        };
        self.set_index(index as usize);
    }

    /// Starts or pauses; starting at the end of a non-looping run rewinds first.
    pub fn toggle_play(&mut self) {
        self.playing = !self.playing;
        if self.playing && !self.looping && self.index + 1 == self.count() {
            self.set_index(0);
        }
    }

    /// Advances the clock by `dt` real seconds; returns whether the shown index changed.
    pub fn advance(&mut self, dt: f64) -> bool {
        if !self.playing || self.count() < 2 {
            return false;
        }
        let before = self.index;
        self.clock += dt * self.speed;
        let length = self.loop_length();
        if self.looping {
            self.clock = self.clock.rem_euclid(length);
        } else if self.clock >= length - self.frame_period() {
            self.clock = length - self.frame_period();
            self.playing = false;
        }
        let now = self.timestamps[0] + self.clock;
        // The last timestamp not after the clock.
        self.index = self
            .timestamps
            .partition_point(|&t| t <= now + 1e-9)
            .saturating_sub(1);
        self.index != before
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tenths(n: usize) -> Vec<f64> {
        (0..n).map(|i| i as f64 * 0.1).collect()
    }

    #[test]
    fn playing_advances_and_loops() {
        let mut time = TimeControl::new(&tenths(4));
        assert!(!time.advance(1.0), "paused playback stays");
        time.toggle_play();
        assert!(!time.advance(0.05));
        assert!(time.advance(0.06));
        assert_eq!(time.index, 1);
        time.advance(0.2);
        assert_eq!(time.index, 3);
        // 0.41 s into a 0.4 s loop: back to the first frame.
        time.advance(0.1);
        assert_eq!(time.index, 0);
        assert!(time.playing);
    }

    #[test]
    fn without_loop_playback_stops_on_the_last_frame() {
        let mut time = TimeControl::new(&tenths(3));
        time.looping = false;
        time.speed = 2.0;
        time.toggle_play();
        time.advance(10.0);
        assert_eq!(time.index, 2);
        assert!(!time.playing);
        time.toggle_play();
        assert_eq!(time.index, 0, "playing again from the end rewinds");
    }

    #[test]
    fn stepping_wraps_or_clamps_and_pauses() {
        let mut time = TimeControl::new(&tenths(5));
        time.toggle_play();
        time.step(-1);
        assert_eq!(time.index, 4);
        assert!(!time.playing);
        time.step(2);
        assert_eq!(time.index, 1);
        time.looping = false;
        time.step(-5);
        assert_eq!(time.index, 0);
        time.step(50);
        assert_eq!(time.index, 4);
        assert!((time.seconds() - 0.4).abs() < 1e-12);
    }

    #[test]
    fn uneven_timestamps_and_single_moment() {
        let mut time = TimeControl::new(&[1.0, 1.5, 3.0]);
        time.set_index(1);
        time.toggle_play();
        time.advance(1.2);
        assert_eq!(time.index, 1, "clock at 2.7 s is still before 3.0 s");
        time.advance(0.4);
        assert_eq!(time.index, 2);
        let mut single = TimeControl::new(&[]);
        single.toggle_play();
        assert!(!single.advance(1.0));
        single.step(1);
        assert_eq!(single.index, 0);
    }
}
