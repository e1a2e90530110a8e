//! Joining a thread that may never end (one waiting on a peer that went silent) without
//! waiting on it for longer than a deadline.

use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How often a thread's end is looked for: `JoinHandle` has no join with a timeout.
const LOOK_EVERY: Duration = Duration::from_millis(5);

/// Waits up to `limit` for `thread` to end and joins it (taking it out of the option). True
/// when it ended (or there was none); false when it still runs at the deadline, left in place
/// to be waited on again or to end with the process. A thread that panicked counts as ended.
pub fn join_within<T>(thread: &mut Option<JoinHandle<T>>, limit: Duration) -> bool {
    let deadline = Instant::now().checked_add(limit);
    loop {
        let Some(running) = thread else {
            return true;
        };
        if running.is_finished() {
            if let Some(ended) = thread.take() {
                let _ = ended.join();
            }
            return true;
        }
        let now = Instant::now();
        let left = deadline.map_or(LOOK_EVERY, |d| d.saturating_duration_since(now));
        if left.is_zero() {
            return false;
        }
        std::thread::sleep(left.min(LOOK_EVERY));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;

    #[test]
    fn a_thread_that_ends_is_joined_and_one_that_does_not_is_left_at_the_deadline() {
        let mut none: Option<JoinHandle<()>> = None;
        assert!(join_within(&mut none, Duration::ZERO));

        let mut quick = Some(std::thread::spawn(|| 7));
        assert!(join_within(&mut quick, Duration::from_secs(30)));
        assert!(quick.is_none());

        let mut panicking = Some(std::thread::spawn(|| panic!("on purpose")));
        assert!(join_within(&mut panicking, Duration::from_secs(30)));

        let (release, held) = mpsc::channel::<()>();
        let mut stuck = Some(std::thread::spawn(move || held.recv()));
        let start = Instant::now();
        assert!(!join_within(&mut stuck, Duration::from_millis(50)));
        assert!(start.elapsed() >= Duration::from_millis(50));
        assert!(stuck.is_some(), "left to be waited on again");
        release.send(()).unwrap();
        assert!(join_within(&mut stuck, Duration::from_secs(30)));
        assert!(stuck.is_none());
    }
}
