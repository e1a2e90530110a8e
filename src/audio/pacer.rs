//! Pulling decoded audio on the output's demand.
//!
//! The mixer takes 20 ms from every peer's queue each time the output device has room, at the
//! device's pace: its crystal, not the system clock. A decoder loop paced by the system clock
//! (a 20 ms timer) pushes at the other's pace, and over a long call the two part: a device a
//! little fast drains the queues (dropouts), a slow one fills them (latency that grows until
//! the queue overflows). [`FramePacer`] paces the pulls by the mixer's own count instead, a few
//! frames ahead of it, so the queues hold the same few frames however long the call. Whatever
//! drift there is between a sender's clock and the device's then shows in the jitter buffer,
//! which corrects it inside pauses.
//!
//! A frame is pulled at the time it is due (the jitter buffer's deadline for its packet is
//! that moment, however long it then waits in the queue), so a device that takes 40 ms at a
//! time makes pulls come in pairs: the buffer measures that as jitter of its own clock. If the
//! mixer stops counting (a device that has not started or stalls, a stopped mixer thread),
//! the system clock paces the pulls meanwhile, so that the jitter buffers do not fill up with
//! what would be heard late; those frames are not queued ([`FramePacer::stalled`]).

use std::time::{Duration, Instant};

/// One pull: 20 ms of every peer.
pub const FRAME: Duration = Duration::from_millis(20);
/// Frames the pacer keeps pulled ahead of the mixer, by default: the mixer may take two in a
/// row (a device period of 40 ms) before the next poll refills.
pub const DEFAULT_LEAD: u64 = 2;
/// The mixer's count standing still this long means it stopped.
const STALL: Duration = Duration::from_millis(250);
/// Frames so far behind the mixer are skipped: they were mixed as silence already.
const MAX_BEHIND: u64 = 5;

/// Says how many frames to pull (see the module documentation).
#[derive(Debug, Clone)]
pub struct FramePacer {
    lead: u64,
    /// Frames pulled, on the mixer's count; `None` before the first poll.
    pulled: Option<u64>,
    /// The mixer's count last seen and when it last moved.
    seen: Option<(u64, Instant)>,
    skipped: u64,
    stalled: bool,
    /// While stalled: the frames pulled (and queued) before the stall.
    queued_upto: u64,
}

impl FramePacer {
    /// Keeps `lead` frames (at least one) pulled ahead of the mixer.
    pub fn new(lead: u64) -> Self {
        Self {
            lead: lead.max(1),
            pulled: None,
            seen: None,
            skipped: 0,
            stalled: false,
            queued_upto: 0,
        }
    }

    /// Frames pulled so far, counted as the mixer counts its chunks.
    pub fn pulled(&self) -> u64 {
        self.pulled.unwrap_or(0)
    }

    /// Frames skipped because the mixer got ahead (the puller stalled).
    pub fn skipped(&self) -> u64 {
        self.skipped
    }

    /// The mixer has stood still since the last poll's STALL ago: the frames pulled meanwhile
    /// (on the system clock) will not be heard; do not queue them.
    pub fn stalled(&self) -> bool {
        self.stalled
    }

    /// The frames to pull now, given the chunks the mixer has mixed so far (`mixed`); they
    /// count as pulled. Queue the `i`th of `n` with [`super::PeerFeed::push_paced`] and an
    /// `ahead` of `lead - (n - 1 - i)`: it is that many frames ahead of the mixer.
    pub fn poll(&mut self, mixed: u64, now: Instant) -> u64 {
        let demand = self.demand(mixed, now);
        let mut pulled = *self.pulled.get_or_insert(demand);
        if !self.stalled && pulled + MAX_BEHIND < demand {
            self.skipped += demand - pulled;
            pulled = demand;
        }
        let target = demand + self.lead;
        self.pulled = Some(pulled.max(target));
        target.saturating_sub(pulled)
    }

    /// The mixer's count, or, while it stands still, where it would be on the system clock
    /// (so that the jitter buffers go on at the pace their packets come).
    fn demand(&mut self, mixed: u64, now: Instant) -> u64 {
        match self.seen {
            Some((count, since)) if count == mixed => {
                let still = now.saturating_duration_since(since);
                if still <= STALL {
                    return mixed;
                }
                if !self.stalled {
                    // What is queued stays queued: the mixer takes it first when it comes back.
                    self.stalled = true;
                    self.queued_upto = self.pulled.unwrap_or(mixed);
                }
                mixed + (still.as_secs_f64() / FRAME.as_secs_f64()) as u64
            }
            _ => {
                if std::mem::take(&mut self.stalled) {
                    // Back after the system clock paced the pulls (which were not queued).
                    self.pulled = Some(self.queued_upto);
                }
                self.seen = Some((mixed, now));
                mixed
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pulls_follow_the_device_clock_not_the_system_clock() {
        // Ten minutes of a device 1 % fast and 1 % slow that takes 40 ms at a time (the mixer
        // mixes two chunks in a row), polled every 5 ms: as many frames pulled as mixed (not
        // as the system clock counts), never more than the lead ahead, and none mixed before
        // it was pulled.
        for rate in [1.01, 0.99] {
            let t0 = Instant::now();
            let mut pacer = FramePacer::new(DEFAULT_LEAD);
            let (mut pulls, mut most, mut starved) = (0, 0, 0);
            let mut mixed = 0;
            for ms in (0..600_000u64).step_by(5) {
                mixed = ((ms as f64 * rate / 40.0).floor() as u64) * 2;
                if ms > 0 {
                    starved += mixed.saturating_sub(pacer.pulled());
                }
                pulls += pacer.poll(mixed, t0 + Duration::from_millis(ms));
                most = most.max(pacer.pulled() - mixed);
            }
            assert_eq!(pulls, mixed + DEFAULT_LEAD, "{rate}");
            assert_eq!((most, starved), (DEFAULT_LEAD, 0), "{rate}");
        }
    }

    #[test]
    fn a_stalled_mixer_hands_over_to_the_system_clock_and_back() {
        let t0 = Instant::now();
        let mut pacer = FramePacer::new(2);
        assert_eq!(pacer.poll(100, t0), 2);
        assert_eq!(pacer.poll(101, t0 + Duration::from_millis(20)), 1);
        // The mixer stops at 101. After 250 ms the system clock takes over: the pulls catch up
        // at once (frames that will not be heard), then go on every 20 ms.
        let mut pulls = 0;
        for ms in (25..=20 + 1000).step_by(5) {
            pulls += pacer.poll(101, t0 + Duration::from_millis(ms));
        }
        assert!(pacer.stalled());
        assert_eq!(pacer.pulled(), 101 + 50 + 2);
        assert_eq!((pulls, pacer.skipped()), (50, 0));
        // It comes back at 102: what was queued before the stall is still there (up to 103),
        // so one frame is due.
        assert_eq!(pacer.poll(102, t0 + Duration::from_secs(3)), 1);
        assert_eq!(pacer.pulled(), 104);
        assert!(!pacer.stalled());
        // A puller that stalled while the mixer ran on skips what was mixed meanwhile.
        assert_eq!(pacer.poll(130, t0 + Duration::from_millis(3020)), 2);
        assert_eq!(pacer.skipped(), 130 - 104);
    }
}
