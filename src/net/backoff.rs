//! Pacing of retries: a floor interval that doubles after each failure up to a ceiling, and
//! is back at the floor after a success. Whatever a server answers, retries cannot storm.

use std::time::Duration;

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Backoff {
    floor: Duration,
    ceiling: Duration,
    next: Duration,
}

impl Backoff {
    pub const fn new(floor: Duration, ceiling: Duration) -> Self {
        Self {
            floor,
            ceiling,
            next: floor,
        }
    }

    /// How long to wait before the next try; the wait after it is twice as long, at most the
    /// ceiling.
    pub fn next_wait(&mut self) -> Duration {
        let wait = self.next;
        self.next = self
            .next
            .saturating_mul(2)
            .min(self.ceiling)
            .max(self.floor);
        wait
    }

    /// A try succeeded: the next failure waits the floor again.
    pub fn reset(&mut self) {
        self.next = self.floor;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waits_double_from_the_floor_to_the_ceiling_and_start_over_after_a_success() {
        let mut b = Backoff::new(Duration::from_secs(10), Duration::from_secs(60));
        let waits: Vec<u64> = (0..5).map(|_| b.next_wait().as_secs()).collect();
        assert_eq!(waits, [10, 20, 40, 60, 60]);
        b.reset();
        assert_eq!(b.next_wait(), Duration::from_secs(10));
        let mut huge = Backoff::new(Duration::MAX, Duration::MAX);
        assert_eq!(
            (huge.next_wait(), huge.next_wait()),
            (Duration::MAX, Duration::MAX)
        );
    }
}
