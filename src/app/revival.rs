//! When a lost output device is opened again: 2 s after the loss, then less and less often, at
//! most every 30 s. A sound server that restarted, or a device that stalled on a starved
//! machine, gives it back; one that stays gone costs a try now and then.

use std::time::{Duration, Instant};

use crate::net::backoff::Backoff;

/// The first try after a loss, and the longest wait between tries.
const FLOOR: Duration = Duration::from_secs(2);
const CEILING: Duration = Duration::from_secs(30);

#[derive(Debug)]
pub struct Revival {
    backoff: Backoff,
    next: Option<Instant>,
    /// The device opening is a revival: its failure waits for the next try, quietly.
    opening: bool,
}

impl Default for Revival {
    fn default() -> Self {
        Self {
            backoff: Backoff::new(FLOOR, CEILING),
            next: None,
            opening: false,
        }
    }
}

impl Revival {
    /// The output plays: a later loss starts its wait afresh.
    pub fn playing(&mut self) {
        self.next = None;
    }

    /// The output is lost: whether to try opening it now.
    pub fn due(&mut self, now: Instant) -> bool {
        let next = *self
            .next
            .get_or_insert_with(|| now + self.backoff.next_wait());
        if now < next {
            return false;
        }
        self.next = None;
        self.opening = true;
        true
    }

    /// The user chose a device: what becomes of it is the user's to see.
    pub fn chosen(&mut self) {
        self.opening = false;
    }

    /// A device finished opening (`opened`, or not): whether it was a revival.
    pub fn finished(&mut self, opened: bool) -> bool {
        if opened {
            self.backoff.reset();
        }
        std::mem::take(&mut self.opening)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tries_come_2_s_after_a_loss_then_less_often_and_afresh_after_a_success() {
        let mut revival = Revival::default();
        let lost = Instant::now();
        let at = |s: u64| lost + Duration::from_secs(s);
        assert!(!revival.due(at(0)), "not at once");
        assert!(!revival.due(at(1)));
        assert!(revival.due(at(2)));
        assert!(revival.finished(false), "a revival, failed");
        // Failed: the next try waits twice as long, from when its wait began.
        assert!(!revival.due(at(3)));
        assert!(!revival.due(at(6)));
        assert!(revival.due(at(7)));
        revival.finished(false);
        let mut waits = Vec::new();
        let mut now = at(7);
        for _ in 0..4 {
            let began = now;
            while !revival.due(now) {
                now += Duration::from_secs(1);
            }
            waits.push((now - began).as_secs());
            revival.finished(false);
        }
        assert_eq!(waits, [8, 16, 30, 30], "capped at 30 s");
        assert!(!revival.finished(true), "nothing was opening");
        revival.playing();
        assert!(!revival.due(now));
        assert!(revival.due(now + FLOOR), "afresh after a success");
        revival.chosen();
        assert!(
            !revival.finished(false),
            "the user's choice is not a revival"
        );
    }
}
