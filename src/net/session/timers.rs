//! The session's timers without a clock: when to report, to ask the relay for our place again
//! and to forget the silent. The time is passed in, so the session's tests run them in
//! simulated time.

use std::time::{Duration, Instant};

use super::SessionConfig;
use crate::net::rtcp::ReportTimer;

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
    report: Option<ReportTimer>,
    keepalive_interval: Duration,
    next_keepalive: Instant,
    next_expiry: Instant,
}

impl Timers {
    /// The timers of a session starting at `now` (its first join, if any, already sent).
    pub(super) fn new(config: &SessionConfig, now: Instant, draw: fn() -> u32) -> Self {
        Self {
            report: config
                .send_rtcp
                .then(|| ReportTimer::new(config.rtcp_interval, now, draw)),
            keepalive_interval: config.keepalive_interval,
            next_keepalive: now + config.keepalive_interval.min(JOIN_RETRY),
            next_expiry: now + EXPIRY_INTERVAL,
        }
    }

    /// When something is next due.
    pub(super) fn next_deadline(&self) -> Instant {
        let deadline = self.next_keepalive.min(self.next_expiry);
        match &self.report {
            Some(report) => deadline.min(report.next()),
            None => deadline,
        }
    }

    /// What is due at `now`, each due timer rescheduled from `now`. `joining` tells whether
    /// the relay has yet to confirm or refuse our place (asked only when the keepalive is due):
    /// until it has, the join is retried sooner, a datagram may have been lost.
    pub(super) fn due(&mut self, now: Instant, joining: impl FnOnce() -> bool) -> Due {
        let mut due = Due {
            report: self.report.as_mut().is_some_and(|r| r.due(now)),
            ..Due::default()
        };
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
