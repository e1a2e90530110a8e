//! What the app's engine and its roster both name, in a leaf neither imports the other for:
//! the engine's counters and the demo peer's name.

use std::sync::atomic::{AtomicU64, Ordering};

/// Name the demo peer announces (SDES), so the UI can tell it apart.
pub const DEMO_NAME: &str = "Demo speaker";

/// Time spent in the animation network (and re-projection), for the CPU report.
#[derive(Debug, Default)]
pub struct EngineCounters {
    pub network_ns: AtomicU64,
    pub frames_animated: AtomicU64,
    pub ticks: AtomicU64,
    /// Weights scheduled; of them, those given out by the look-ahead's fallback (the next
    /// frame was late), and those scheduled after their frame had begun to be heard (the face
    /// lagged the voice by up to the lateness), with the summed lateness in microseconds.
    pub weights_sent: AtomicU64,
    pub weights_fallback: AtomicU64,
    pub weights_late: AtomicU64,
    pub late_us: AtomicU64,
    /// The longest time between two passes of the worker's loop since it was last taken, in
    /// microseconds: a pass that blocks (on a peer, a server, a lookup) delays every peer's
    /// audio and face by as much.
    pub longest_pass_us: AtomicU64,
}

impl EngineCounters {
    /// The longest gap between two passes of the worker's loop since the last call.
    pub fn take_longest_pass(&self) -> std::time::Duration {
        std::time::Duration::from_micros(self.longest_pass_us.swap(0, Ordering::Relaxed))
    }

    pub(crate) fn pass_took(&self, gap: std::time::Duration) {
        let us = u64::try_from(gap.as_micros()).unwrap_or(u64::MAX);
        self.longest_pass_us.fetch_max(us, Ordering::Relaxed);
    }

    /// Counts one row of weights for the frame at stream position `pos`, heard up to `heard`
    /// (positions in samples at `rate`).
    pub(crate) fn weights_scheduled(
        &self,
        pos: u64,
        heard: Option<u64>,
        rate: u32,
        fallback: bool,
    ) {
        self.weights_sent.fetch_add(1, Ordering::Relaxed);
        if fallback {
            self.weights_fallback.fetch_add(1, Ordering::Relaxed);
        }
        if let Some(heard) = heard
            && heard > pos
        {
            self.weights_late.fetch_add(1, Ordering::Relaxed);
            let late_us = (heard - pos).saturating_mul(1_000_000) / u64::from(rate.max(1));
            self.late_us.fetch_add(late_us, Ordering::Relaxed);
        }
    }
}
