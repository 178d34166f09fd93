//! Where the shown time is and how it moves: play/pause, loop, speed, frame steps, the
//! slider.
//!
//! Time is counted in frames: timestamp indices, real-valued, the unit of a version-2
//! scene's functions of time (docs/ply4d.md; seconds are frames × the timestamps' spacing).
//! Frames rather than seconds because whole frames are exact: a step lands on timestamp `t`
//! itself, where a version-2 scene shows the set its reader gives at `t`, bit for bit, and
//! the loop's period, a whole number of frames, wraps exactly.
//!
//! How the shown time moves depends on the scene ([`Timeline`]): a version-2 scene is a
//! function of time, so its time is any real and moves continuously while playing; every
//! other scene holds each timestamp until the next, as a version-1 file's playback always
//! has.

/// How the shown time moves between timestamps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Timeline {
    /// Each timestamp is shown until the next (a version-1 `.ply4d`, a folder of `.ply`
    /// frames, a single `.ply`): the shown time is always a whole frame, moved by a clock
    /// in seconds, so that uneven timestamps are held as long as their spacing says.
    Held,
    /// Any real time, looping over the timestamps' frames (a version-2 `.ply4d`: one
    /// spacetime set, evaluated where it is shown): the loop is `count` frames long and time
    /// `count` is time 0.
    Continuous,
}

/// Where playback is and how it moves.
#[derive(Clone, Debug, PartialEq)]
pub struct TimeControl {
    timestamps: Vec<f64>,
    timeline: Timeline,
    /// The shown time in frames: a whole frame on a held timeline, in [0, count] on a
    /// continuous one.
    frame: f64,
    pub playing: bool,
    pub looping: bool,
    /// Playback rate relative to real time.
    pub speed: f64,
    /// A held timeline's seconds since the first timestamp, advanced while playing.
    clock: f64,
}

impl TimeControl {
    /// `timestamps` in seconds, ascending; an empty list is treated as a single moment.
    pub fn new(timestamps: &[f64], timeline: Timeline) -> Self {
        let timestamps = if timestamps.is_empty() {
            vec![0.0]
        } else {
            timestamps.to_vec()
        };
        Self {
            timestamps,
            timeline,
            frame: 0.0,
            playing: false,
            looping: true,
            speed: 1.0,
            clock: 0.0,
        }
    }

    pub fn count(&self) -> usize {
        self.timestamps.len()
    }

    pub fn timeline(&self) -> Timeline {
        self.timeline
    }

    /// The shown time in frames.
    pub fn frame(&self) -> f64 {
        self.frame
    }

    /// The timestamp at or before the shown time (on a held timeline, the shown one).
    pub fn index(&self) -> usize {
        self.frame.floor() as usize % self.count()
    }

    /// Seconds of the shown time.
    pub fn seconds(&self) -> f64 {
        match self.timeline {
            Timeline::Held => self.timestamps[self.index()],
            Timeline::Continuous => self.timestamps[0] + self.frame * self.frame_period(),
        }
    }

    /// The latest time the slider and a run that does not loop reach: the last timestamp
    /// (held), or the loop's end, which shows what time 0 shows (continuous).
    pub fn end(&self) -> f64 {
        match self.timeline {
            Timeline::Held => (self.count() - 1) as f64,
            Timeline::Continuous => self.count() as f64,
        }
    }

    /// Typical spacing of the timestamps in seconds (1/10 s for a single one): a frame's
    /// length in playback.
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

    /// One held loop's length in seconds: the span plus one frame, so the last frame is
    /// shown as long as the others.
    fn loop_length(&self) -> f64 {
        self.timestamps[self.timestamps.len() - 1] - self.timestamps[0] + self.frame_period()
    }

    /// Moves to `frame` (the slider) and keeps playing from there: clamped to
    /// [0, [`Self::end`]], and on a held timeline to the nearest timestamp.
    pub fn set_frame(&mut self, frame: f64) {
        let frame = frame.clamp(0.0, self.end());
        match self.timeline {
            Timeline::Held => {
                let index = frame.round() as usize;
                self.frame = index as f64;
                self.clock = self.timestamps[index] - self.timestamps[0];
            }
            Timeline::Continuous => self.frame = frame,
        }
    }

    /// Moves to `seconds` on the timestamps' clock, taken round the loop: on a continuous
    /// timeline the real time there, on a held one the timestamp holding it (the last at or
    /// before it), as playing shows them.
    pub fn set_seconds(&mut self, seconds: f64) {
        let clock = (seconds - self.timestamps[0]).rem_euclid(self.loop_length());
        match self.timeline {
            Timeline::Held => self.hold(clock),
            Timeline::Continuous => self.frame = clock / self.frame_period(),
        }
    }

    /// Moves to the `delta`-th timestamp from the shown time (from a time between two, the
    /// nearer of them in that direction counts as the first), wrapping around when looping;
    /// pauses playback.
    pub fn step(&mut self, delta: i64) {
        self.playing = false;
        let from = if delta > 0 {
            self.frame.floor()
        } else {
            self.frame.ceil()
        } as i64;
        let n = self.count() as i64;
        let target = from + delta;
        let index = if self.looping {
            target.rem_euclid(n)
        } else {
            target.clamp(0, n - 1)
        };
        self.set_frame(index as f64);
    }

    /// Starts or pauses; starting at the end of a non-looping run rewinds first.
    pub fn toggle_play(&mut self) {
        self.playing = !self.playing;
        if self.playing && !self.looping && self.frame >= self.end() {
            self.set_frame(0.0);
        }
    }

    /// Advances by `dt` real seconds (× speed); returns whether the shown time changed.
    pub fn advance(&mut self, dt: f64) -> bool {
        if !self.playing || self.end() == 0.0 {
            return false;
        }
        let before = self.frame;
        match self.timeline {
            Timeline::Held => self.advance_held(dt),
            Timeline::Continuous => self.advance_continuous(dt),
        }
        self.frame != before
    }

    fn advance_continuous(&mut self, dt: f64) {
        let frame = self.frame + dt * self.speed / self.frame_period();
        if self.looping {
            self.frame = frame.rem_euclid(self.count() as f64);
        } else if frame >= self.end() {
            self.frame = self.end();
            self.playing = false;
        } else {
            self.frame = frame;
        }
    }

    fn advance_held(&mut self, dt: f64) {
        self.clock += dt * self.speed;
        let length = self.loop_length();
        if self.looping {
            self.clock = self.clock.rem_euclid(length);
        } else if self.clock >= length - self.frame_period() {
            self.clock = length - self.frame_period();
            self.playing = false;
        }
        self.hold(self.clock);
    }

    /// Shows the timestamp holding `clock` seconds after the first: the last not after it.
    fn hold(&mut self, clock: f64) {
        self.clock = clock;
        let now = self.timestamps[0] + clock;
        let index = self
            .timestamps
            .partition_point(|&t| t <= now + 1e-9)
            .saturating_sub(1);
        self.frame = index as f64;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tenths(n: usize) -> Vec<f64> {
        (0..n).map(|i| i as f64 * 0.1).collect()
    }

    fn held(timestamps: &[f64]) -> TimeControl {
        TimeControl::new(timestamps, Timeline::Held)
    }

    fn continuous(frames: usize) -> TimeControl {
        TimeControl::new(&tenths(frames), Timeline::Continuous)
    }

    fn assert_near(got: f64, want: f64) {
        assert!((got - want).abs() < 1e-9, "{got}, not {want}");
    }

    #[test]
    fn playing_advances_and_loops() {
        let mut time = held(&tenths(4));
        assert!(!time.advance(1.0), "paused playback stays");
        time.toggle_play();
        assert!(!time.advance(0.05));
        assert!(time.advance(0.06));
        assert_eq!(time.index(), 1);
        time.advance(0.2);
        assert_eq!(time.index(), 3);
        // 0.41 s into a 0.4 s loop: back to the first frame.
        time.advance(0.1);
        assert_eq!(time.index(), 0);
        assert_eq!(time.frame(), 0.0);
        assert!(time.playing);
    }

    #[test]
    fn without_loop_playback_stops_on_the_last_frame() {
        let mut time = held(&tenths(3));
        time.looping = false;
        time.speed = 2.0;
        time.toggle_play();
        time.advance(10.0);
        assert_eq!(time.index(), 2);
        assert!(!time.playing);
        time.toggle_play();
        assert_eq!(time.index(), 0, "playing again from the end rewinds");
    }

    #[test]
    fn stepping_wraps_or_clamps_and_pauses() {
        let mut time = held(&tenths(5));
        time.toggle_play();
        time.step(-1);
        assert_eq!(time.index(), 4);
        assert!(!time.playing);
        time.step(2);
        assert_eq!(time.index(), 1);
        time.looping = false;
        time.step(-5);
        assert_eq!(time.index(), 0);
        time.step(50);
        assert_eq!(time.index(), 4);
        assert!((time.seconds() - 0.4).abs() < 1e-12);
    }

    #[test]
    fn uneven_timestamps_and_single_moment() {
        let mut time = held(&[1.0, 1.5, 3.0]);
        time.set_frame(1.0);
        time.toggle_play();
        time.advance(1.2);
        assert_eq!(time.index(), 1, "clock at 2.7 s is still before 3.0 s");
        time.advance(0.4);
        assert_eq!(time.index(), 2);
        let mut single = held(&[]);
        single.toggle_play();
        assert!(!single.advance(1.0));
        single.step(1);
        assert_eq!(single.index(), 0);
    }

    #[test]
    fn a_held_slider_lands_on_the_nearest_timestamp() {
        let mut time = held(&tenths(4));
        time.set_frame(1.6);
        assert_eq!(time.frame(), 2.0);
        time.set_frame(9.0);
        assert_eq!(time.frame(), 3.0);
        assert_eq!(time.end(), 3.0);
    }

    #[test]
    fn continuous_time_moves_at_the_display_rate_times_speed_and_loops() {
        // Four frames 0.1 s apart: a 0.4 s loop.
        let mut time = continuous(4);
        time.speed = 1.5;
        assert!(!time.advance(0.05), "paused playback stays");
        time.toggle_play();
        // 0.05 s × 1.5 = 0.075 s: three quarters of a frame, shown as it is.
        assert!(time.advance(0.05));
        assert_near(time.frame(), 0.75);
        assert_eq!(time.index(), 0);
        assert_near(time.seconds(), 0.075);
        time.advance(0.1);
        assert_near(time.frame(), 2.25);
        assert_eq!(time.index(), 2);
        // 4.5 frames into a 4-frame loop: half a frame past its start.
        time.advance(0.15);
        assert_near(time.frame(), 0.5);
        assert!(time.playing);
    }

    #[test]
    fn without_loop_continuous_playback_stops_at_the_loops_end() {
        let mut time = continuous(4);
        time.looping = false;
        time.toggle_play();
        assert!(time.advance(0.35));
        assert_near(time.frame(), 3.5);
        time.advance(10.0);
        assert_eq!(time.frame(), 4.0, "the loop's end, which shows time 0");
        assert_eq!(time.index(), 0);
        assert!(!time.playing);
        time.toggle_play();
        assert_eq!(time.frame(), 0.0, "playing again from the end rewinds");
    }

    #[test]
    fn a_time_in_seconds_is_a_real_time_or_the_timestamp_holding_it() {
        let mut time = continuous(4);
        time.set_seconds(0.15);
        assert_near(time.frame(), 1.5);
        assert_near(time.seconds(), 0.15);
        time.set_seconds(0.45);
        assert_near(time.frame(), 0.5);
        time.set_seconds(-0.05);
        assert_near(time.frame(), 3.5);

        let mut time = held(&tenths(4));
        time.set_seconds(0.19);
        assert_eq!(
            time.frame(),
            1.0,
            "held until the next timestamp, not the nearest"
        );
        // 0.3 s is timestamp 3 (stored as 3 × 0.1 = 0.30000000000000004).
        time.set_seconds(0.3);
        assert_eq!(time.frame(), 3.0);
        time.set_seconds(0.45);
        assert_eq!(time.frame(), 0.0, "round the 0.4 s loop");
        // Playing on goes on from there.
        time.toggle_play();
        time.advance(0.06);
        assert_eq!(time.frame(), 1.0);

        let mut uneven = held(&[1.0, 1.5, 3.0]);
        uneven.set_seconds(2.9);
        assert_eq!(uneven.frame(), 1.0);
        uneven.set_seconds(4.2); // a 3 s loop from 1.0 s: 1.2 s
        assert_eq!(uneven.frame(), 0.0);
    }

    #[test]
    fn continuous_slider_and_steps() {
        let mut time = continuous(4);
        assert_eq!(time.end(), 4.0);
        time.set_frame(2.4);
        assert_near(time.frame(), 2.4);
        time.set_frame(7.0);
        assert_eq!(time.frame(), 4.0);
        // A step from between two frames lands on the nearer one in its direction; from a
        // whole frame it moves by one.
        time.set_frame(2.4);
        time.step(1);
        assert_eq!(time.frame(), 3.0);
        time.step(1);
        assert_eq!(time.frame(), 0.0, "wrapped");
        time.set_frame(2.4);
        time.step(-1);
        assert_eq!(time.frame(), 2.0);
        time.step(-1);
        assert_eq!(time.frame(), 1.0);
        time.looping = false;
        time.set_frame(3.5);
        time.step(1);
        assert_eq!(time.frame(), 3.0, "clamped to the last timestamp");
    }
}
