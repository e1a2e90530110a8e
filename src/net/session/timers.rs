//! The session's timers without a clock: when to report, to ask the relay for our place again
//! and to forget the silent. The time is passed in, so the session's tests run them in
//! simulated time.

use std::time::{Duration, Instant};

use super::SessionConfig;

/// How soon an unanswered relay join is sent again.
const JOIN_RETRY: Duration = Duration::from_millis(500);
/// How often silent peers and stale hints are looked for.
pub(super) const EXPIRY_INTERVAL: Duration = Duration::from_secs(1);

/// What is due at a moment.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) struct Due {
    /// A periodic RTCP report.
    pub report: bool,
    /// Asking the relay for our place: a join retried, or the keepalive.
    pub keepalive: bool,
    /// Forgetting silent peers and stale hints.
    pub expiry: bool,
}

pub(super) struct Timers {
    /// `None` when the session sends no RTCP.
    rtcp_interval: Option<Duration>,
    keepalive_interval: Duration,
    /// A uniform random draw over `u32`, for the reports' spread.
    draw: fn() -> u32,
    next_report: Instant,
    next_keepalive: Instant,
    next_expiry: Instant,
}

impl Timers {
    /// The timers of a session starting at `now` (its first join, if any, already sent).
    pub(super) fn new(config: &SessionConfig, now: Instant, draw: fn() -> u32) -> Self {
        let rtcp_interval = config.send_rtcp.then_some(config.rtcp_interval);
        Self {
            rtcp_interval,
            keepalive_interval: config.keepalive_interval,
            draw,
            next_report: now + spread(config.rtcp_interval, draw()),
            next_keepalive: now + config.keepalive_interval.min(JOIN_RETRY),
            next_expiry: now + EXPIRY_INTERVAL,
        }
    }

    /// When something is next due.
    pub(super) fn next_deadline(&self) -> Instant {
        let deadline = self.next_keepalive.min(self.next_expiry);
        match self.rtcp_interval {
            Some(_) => deadline.min(self.next_report),
            None => deadline,
        }
    }

    /// What is due at `now`, each due timer rescheduled from `now`. `joining` tells whether
    /// the relay has yet to confirm or refuse our place (asked only when the keepalive is due):
    /// until it has, the join is retried sooner, a datagram may have been lost.
    pub(super) fn due(&mut self, now: Instant, joining: impl FnOnce() -> bool) -> Due {
        let mut due = Due::default();
        if let Some(interval) = self.rtcp_interval
            && now >= self.next_report
        {
            due.report = true;
            self.next_report = now + spread(interval, (self.draw)());
        }
        if now >= self.next_keepalive {
            due.keepalive = true;
            let interval = if joining() {
                self.keepalive_interval.min(JOIN_RETRY)
            } else {
                self.keepalive_interval
            };
            self.next_keepalive = now + interval;
        }
        if now >= self.next_expiry {
            due.expiry = true;
            self.next_expiry = now + EXPIRY_INTERVAL;
        }
        due
    }
}

/// `interval` times 0.5 to 1.5 (RFC 3550 6.3.1), by where `draw` falls in `u32`'s range: reports
/// of many members do not fall into step.
fn spread(interval: Duration, draw: u32) -> Duration {
    interval.mul_f64(0.5 + f64::from(draw) / f64::from(u32::MAX))
}

/// The system's randomness (the middle of the range if it fails).
pub(super) fn system_draw() -> u32 {
    getrandom::u32().unwrap_or(0x8000_0000)
}
