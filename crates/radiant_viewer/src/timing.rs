//! Frame timing: frames presented, the time between them, and when to refresh the title.

use std::time::{Duration, Instant};

/// When frames were presented.
pub(crate) struct FrameTimer {
    last_frame: Instant,
    last_title: Instant,
    frames: u64,
}

impl FrameTimer {
    /// A timer starting now.
    pub(crate) fn new() -> Self {
        let now = Instant::now();
        Self {
            last_frame: now,
            last_title: now,
            frames: 0,
        }
    }

    /// Frames presented.
    pub(crate) fn frames(&self) -> u64 {
        self.frames
    }

    /// Seconds since the last presented frame, at most 0.1 (a stall does not fling the camera).
    pub(crate) fn dt(&self, now: Instant) -> f64 {
        now.duration_since(self.last_frame).as_secs_f64().min(0.1)
    }

    /// Counts a presented frame started at `now`; returns the milliseconds since the previous
    /// one (none for the first).
    pub(crate) fn presented(&mut self, now: Instant) -> Option<f64> {
        self.frames += 1;
        let ms = now.duration_since(self.last_frame).as_secs_f64() * 1e3;
        self.last_frame = now;
        (self.frames > 1).then_some(ms)
    }

    /// Whether the title is due for a refresh (twice a second); resets the clock if so.
    pub(crate) fn title_due(&mut self, now: Instant) -> bool {
        let due = now.duration_since(self.last_title) > Duration::from_millis(500);
        if due {
            self.last_title = now;
        }
        due
    }
}
