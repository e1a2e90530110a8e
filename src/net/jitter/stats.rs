//! What the buffer counts: [`JitterStats`], and RFC 3550's interarrival jitter that its
//! receiver reports carry.

#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct JitterStats {
    pub received: u64,
    pub duplicates: u64,
    pub late: u64,
    pub reordered: u64,
    pub overflow: u64,
    /// Frames decoded from packets.
    pub played: u64,
    /// Packets the sequence numbers show missing (RFC 3550: expected minus received, over
    /// every stream this SSRC sent).
    pub lost: u64,
    /// Frames concealed because their packet was missing (lost or late) or had not come yet.
    pub missing: u64,
    /// Frames inside a talk spurt where the sender paused (nothing played).
    pub paused: u64,
    /// Frames inserted to grow the delay.
    pub stretched: u64,
    /// Frames skipped to shrink the delay.
    pub dropped: u64,
    /// Of the frames inserted and skipped, those made at the limits of the delay whatever the
    /// audio (no pause came in time); the others were inside pauses.
    pub forced: u64,
    /// The sender's clock against the playout's, in parts per million (positive: the sender
    /// is fast), from the trend of the packets' slack; 0 until it is known.
    pub drift_ppm: f64,
    /// Packets left behind when the stream's clock rate changed (a switch of codec).
    pub flushed: u64,
    /// Talk spurts started.
    pub spurts: u64,
    /// New streams on this SSRC after the first (after BYE, or a new sequence).
    pub restarts: u64,
    /// Timelines re-anchored at a timestamp discontinuity.
    pub rebased: u64,
    /// Streams that resumed after a stall, played on from where they stopped rather than
    /// dropped as late.
    pub resumed: u64,
    /// Packets held back while a far sequence number waits for its successor (RFC 3550 A.1).
    pub probation: u64,
    /// Times the stream was held up before it reached this receiver (its sender or a relay
    /// stalled): a packet that came [`super::HELD_UPSTREAM`] seconds or more later than its
    /// timestamp's step from the one before says.
    pub held_upstream: u64,
    /// RFC 3550 interarrival jitter in ms.
    pub jitter_ms: f64,
    pub target_delay_ms: f64,
    /// The delay the buffer plays at now (above the fastest packet seen).
    pub current_delay_ms: f64,
    pub buffered_frames: usize,
}

/// RFC 3550 A.8: the interarrival jitter, in clock ticks.
#[derive(Debug, Default)]
pub(super) struct Interarrival {
    transit: Option<f64>,
    jitter: f64,
}

impl Interarrival {
    /// A packet at tick offset `off` arriving at `now` (seconds) on a clock of `clock` Hz.
    pub fn observe(&mut self, now: f64, off: i64, clock: u32) {
        let transit = now * f64::from(clock) - off as f64;
        if let Some(prev) = self.transit {
            let d = (transit - prev).abs();
            self.jitter += (d - self.jitter) / 16.0;
        }
        self.transit = Some(transit);
    }

    /// A new timeline: the next packet's transit is compared with none.
    pub fn reset(&mut self) {
        self.transit = None;
    }

    pub fn ticks(&self) -> f64 {
        self.jitter
    }
}
