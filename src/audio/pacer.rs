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
/// Frames the pacer keeps pulled ahead of a mixer that mixes whole frames: it may take two in a
/// row (a device period of 40 ms) before the next poll refills.
pub const DEFAULT_LEAD: u64 = 2;
/// Frames ahead of the playback engine's mixer, which mixes half frames, wakes the puller as it
/// finishes each frame and waits for a peer's next frame while its ring allows: one (the frame
/// it is about to begin, or is halfway through).
pub const PLAYBACK_LEAD: u64 = 1;
/// The mixer's count standing still this long means it stopped.
const STALL: Duration = Duration::from_millis(250);
/// Frames the mixer has already mixed (as silence, the puller being late) are pulled and
/// dropped, so that the jitter buffers stay in step; this many and more are skipped (a
/// suspended process).
const MAX_BEHIND: u64 = 25;

/// What a poll asks for: `late` frames to pull and drop (the mixer has mixed silence in
/// their place, or stands still), then `queued` frames to pull and queue, the last of them
/// `lead` frames ahead of the mixer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pulls {
    pub late: u64,
    pub queued: u64,
    lead: u64,
}

impl Pulls {
    pub fn total(&self) -> u64 {
        self.late + self.queued
    }

    /// For the `i`th pull of the poll: `None` to drop its frames, or how many frames ahead of
    /// the mixer they are ([`super::PeerFeed::push_paced`]).
    pub fn ahead(&self, i: u64) -> Option<usize> {
        let q = i.checked_sub(self.late)?;
        let left = self.queued.checked_sub(q + 1)?;
        Some(self.lead.saturating_sub(left).max(1) as usize)
    }
}

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

    /// Frames skipped because the mixer got far ahead (the puller stood still).
    pub fn skipped(&self) -> u64 {
        self.skipped
    }

    /// The mixer stands still (over 250 ms): the pulls follow the system clock meanwhile.
    pub fn stalled(&self) -> bool {
        self.stalled
    }

    /// What to pull now, given the chunks the mixer has mixed so far (`mixed`); it counts as
    /// pulled.
    pub fn poll(&mut self, mixed: u64, now: Instant) -> Pulls {
        let demand = self.demand(mixed, now);
        let pulled = *self.pulled.get_or_insert(demand);
        let target = demand + self.lead;
        if self.stalled {
            self.pulled = Some(pulled.max(target));
            return Pulls {
                late: target.saturating_sub(pulled),
                queued: 0,
                lead: self.lead,
            };
        }
        let behind = demand.saturating_sub(pulled);
        let late = if behind > MAX_BEHIND {
            self.skipped += behind;
            0
        } else {
            behind
        };
        let start = pulled.max(demand);
        self.pulled = Some(start.max(target));
        Pulls {
            late,
            queued: target.saturating_sub(start),
            lead: self.lead,
        }
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
                let due = pacer.poll(mixed, t0 + Duration::from_millis(ms));
                assert_eq!(due.late, 0);
                pulls += due.queued;
                most = most.max(pacer.pulled() - mixed);
            }
            assert_eq!(pulls, mixed + DEFAULT_LEAD, "{rate}");
            assert_eq!((most, starved), (DEFAULT_LEAD, 0), "{rate}");
        }
    }

    #[test]
    fn late_pulls_are_dropped_and_a_stalled_mixer_hands_over_to_the_system_clock() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        let mut pacer = FramePacer::new(2);
        let due = pacer.poll(100, t0);
        assert_eq!((due.late, due.queued), (0, 2));
        assert_eq!((due.ahead(0), due.ahead(1)), (Some(1), Some(2)));
        assert_eq!(pacer.poll(101, at(20)).queued, 1);
        // The puller was held up while the mixer mixed four chunks (silence for this peer):
        // those frames are pulled and dropped, the next two queued.
        let due = pacer.poll(105, at(100));
        assert_eq!((due.late, due.queued), (2, 2));
        assert_eq!(
            (0..4).map(|i| due.ahead(i)).collect::<Vec<_>>(),
            [None, None, Some(1), Some(2)]
        );
        // The mixer stops at 105. After 250 ms the system clock takes over: the pulls catch up
        // at once, then go on every 20 ms, all dropped.
        let (mut late, mut queued) = (0, 0);
        for ms in (105..=100 + 1000).step_by(5) {
            let due = pacer.poll(105, at(ms));
            (late, queued) = (late + due.late, queued + due.queued);
        }
        assert!(pacer.stalled());
        assert_eq!((late, queued), (50, 0));
        assert_eq!(pacer.pulled(), 105 + 50 + 2);
        // It comes back at 106: what was queued before the stall is still there (up to 107),
        // so one frame is due.
        let due = pacer.poll(106, at(3000));
        assert_eq!((due.late, due.queued), (0, 1));
        assert!(!pacer.stalled());
        // Far behind (a suspended process): skipped.
        let due = pacer.poll(200, at(3020));
        assert_eq!((due.late, due.queued, pacer.skipped()), (0, 2, 200 - 108));
    }
}
