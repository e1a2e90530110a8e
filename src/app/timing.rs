//! The worker's clocks: the system clock's 20 ms ticks, and the wait for a relay to confirm
//! a call's join; both sans-I/O, tested in simulated time.

use std::time::{Duration, Instant};

use crate::net::session::SessionStats;

const TICK: Duration = Duration::from_millis(20);
/// How long a relay may take to confirm our place in its room before the call says so.
pub(super) const RELAY_CONFIRM_WAIT: Duration = Duration::from_secs(3);

/// The system clock's 20 ms ticks, for the demo sender and the status. Ticks missed by a
/// little are caught up at once, as a remote sender's late packets would come; after a longer
/// stall (a suspended machine) the count is rebased instead of bursting.
#[derive(Debug)]
pub(super) struct Ticker {
    start: Instant,
    count: u32,
}

/// Ticks missed beyond which the ticker rebases.
const CATCH_UP_TICKS: u32 = 10;

impl Ticker {
    pub(super) fn new(start: Instant) -> Self {
        Self { start, count: 0 }
    }

    /// When the next tick is due.
    pub(super) fn due(&self) -> Instant {
        self.start + TICK * self.count
    }

    /// The tick's number if one is due at `now`.
    pub(super) fn poll(&mut self, now: Instant) -> Option<u32> {
        let due = self.due();
        if now < due {
            return None;
        }
        self.count = self.count.wrapping_add(1);
        if now.duration_since(due) > TICK * CATCH_UP_TICKS {
            self.count = (now.duration_since(self.start).as_millis() / TICK.as_millis()) as u32;
        }
        Some(self.count)
    }
}

/// A relay call's join: says when the relay refused the room, or has not confirmed it in time.
#[derive(Debug, Default)]
pub(super) struct RelayWatch {
    /// When to say the relay has not confirmed (none: confirmed, said, or not a relay call).
    deadline: Option<Instant>,
}

impl RelayWatch {
    pub(super) fn joining(now: Instant) -> Self {
        Self {
            deadline: Some(now + RELAY_CONFIRM_WAIT),
        }
    }

    /// The call's error to show, from the session's account of the relay at `now`.
    pub(super) fn check(&mut self, stats: &SessionStats, now: Instant) -> Option<String> {
        if let Some(why) = stats.relay_refusal {
            self.deadline = None;
            return Some(format!("the relay refused to join the room: {why}"));
        }
        if stats.relay_joined {
            self.deadline = None;
        }
        if self.deadline.is_some_and(|d| now >= d) {
            self.deadline = None;
            return Some(
                "the relay has not confirmed the join (no relay there, or one of an older \
                 lipcall version)"
                    .into(),
            );
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::net::control::Refusal;

    fn stats(joined: bool, refusal: Option<Refusal>) -> SessionStats {
        SessionStats {
            relay_joined: joined,
            relay_refusal: refusal,
            ..Default::default()
        }
    }

    /// The ticks due at `now`, polled as the worker's loop does.
    fn ticks_at(ticker: &mut Ticker, now: Instant) -> Vec<u32> {
        std::iter::from_fn(|| ticker.poll(now)).collect()
    }

    #[test]
    fn ticks_come_every_20_ms_and_a_short_stall_is_caught_up() {
        let t0 = Instant::now();
        let ms = |n| t0 + Duration::from_millis(n);
        let mut ticker = Ticker::new(t0);
        assert_eq!(ticks_at(&mut ticker, ms(0)), [1]);
        assert_eq!(ticks_at(&mut ticker, ms(19)), [] as [u32; 0]);
        assert_eq!(ticks_at(&mut ticker, ms(20)), [2]);
        assert_eq!(ticker.due(), ms(40));
        assert_eq!(ticks_at(&mut ticker, ms(120)), [3, 4, 5, 6, 7]);
        assert_eq!(ticker.due(), ms(140));
    }

    #[test]
    fn a_long_stall_is_not_made_up_in_a_burst() {
        let t0 = Instant::now();
        let mut ticker = Ticker::new(t0);
        ticker.poll(t0);
        let after = t0 + Duration::from_secs(5);
        let ticks = ticks_at(&mut ticker, after);
        assert!(ticks.len() <= 2, "{ticks:?}");
        assert_eq!(
            *ticks.last().unwrap(),
            251,
            "counted from the start: 5 s of ticks"
        );
        assert!(ticker.due() > after);
    }

    #[test]
    fn an_unconfirmed_join_is_said_once_after_the_wait() {
        let t0 = Instant::now();
        let mut watch = RelayWatch::joining(t0);
        let waiting = stats(false, None);
        assert_eq!(watch.check(&waiting, t0), None);
        let just_before = t0 + RELAY_CONFIRM_WAIT - Duration::from_millis(1);
        assert_eq!(watch.check(&waiting, just_before), None);
        let said = watch.check(&waiting, t0 + RELAY_CONFIRM_WAIT).unwrap();
        assert!(said.contains("has not confirmed"), "{said}");
        assert_eq!(
            watch.check(&waiting, t0 + RELAY_CONFIRM_WAIT * 2),
            None,
            "said once, not every check"
        );
    }

    #[test]
    fn a_confirmed_join_is_never_called_unconfirmed() {
        let t0 = Instant::now();
        let mut watch = RelayWatch::joining(t0);
        assert_eq!(watch.check(&stats(true, None), t0), None);
        assert_eq!(
            watch.check(&stats(false, None), t0 + RELAY_CONFIRM_WAIT * 2),
            None
        );
    }

    #[test]
    fn a_refusal_is_said_at_once_and_ends_the_wait() {
        let t0 = Instant::now();
        let mut watch = RelayWatch::joining(t0);
        let refused = stats(false, Some(Refusal::RoomFull));
        let said = watch.check(&refused, t0).unwrap();
        assert!(said.contains("refused") && said.contains("full"), "{said}");
        let after = watch.check(&stats(false, None), t0 + RELAY_CONFIRM_WAIT);
        assert_eq!(after, None, "no second complaint once refused");
    }

    #[test]
    fn a_direct_call_is_not_watched() {
        let mut watch = RelayWatch::default();
        let later = Instant::now() + RELAY_CONFIRM_WAIT * 10;
        assert_eq!(watch.check(&stats(false, None), later), None);
    }
}
