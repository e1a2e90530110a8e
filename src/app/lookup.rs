//! Host names looked up off the engine's worker. DNS can take seconds (a resolver that does
//! not answer): a worker waiting on it would hold up every peer's audio and face. The look-up
//! runs on a short-lived thread and its answer comes back to the worker's loop, with what was
//! to follow it. A newer look-up (a newer call) or [`Lookups::forget`] (a leave) drops one
//! still running (its thread ends on its own), and one that takes longer than [`LOOKUP_WAIT`]
//! fails.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, TryRecvError, sync_channel};
use std::time::{Duration, Instant};

/// Look-ups running at once at most, forgotten ones included (a user who redials while the
/// resolver is silent waits, rather than threads piling up).
const MOST_RUNNING: usize = 4;
/// How long a look-up is waited for.
pub const LOOKUP_WAIT: Duration = Duration::from_secs(15);

struct Lookup<T> {
    then: T,
    host: String,
    began: Instant,
    answer: Receiver<Result<SocketAddr, String>>,
}

/// One look-up pending at most, and `T`: what is to follow it.
pub struct Lookups<T> {
    running: Arc<AtomicUsize>,
    pending: Option<Lookup<T>>,
}

impl<T> Default for Lookups<T> {
    fn default() -> Self {
        Self {
            running: Arc::default(),
            pending: None,
        }
    }
}

/// Counts a look-up's thread out however it ends.
struct Running(Arc<AtomicUsize>);

impl Drop for Running {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::Relaxed);
    }
}

impl<T> Lookups<T> {
    /// Starts finding `host` with `find` on a thread of its own, replacing any look-up
    /// pending.
    pub fn start(
        &mut self,
        host: &str,
        then: T,
        find: impl FnOnce() -> Result<SocketAddr, String> + Send + 'static,
    ) -> anyhow::Result<()> {
        self.pending = None;
        if self.running.load(Ordering::Relaxed) >= MOST_RUNNING {
            anyhow::bail!(
                "cannot look {host} up: {MOST_RUNNING} look-ups are still waiting on the resolver"
            );
        }
        self.running.fetch_add(1, Ordering::Relaxed);
        let running = Running(Arc::clone(&self.running));
        let (tell, answer) = sync_channel(1);
        std::thread::Builder::new()
            .name("lipcall-lookup".into())
            .spawn(move || {
                let _running = running;
                let _ = tell.send(find());
            })
            .map_err(|e| anyhow::anyhow!("cannot look {host} up: {e}"))?;
        self.pending = Some(Lookup {
            then,
            host: host.to_owned(),
            began: Instant::now(),
            answer,
        });
        Ok(())
    }

    pub fn forget(&mut self) {
        self.pending = None;
    }

    /// The pending look-up's answer, once it came (or it waited too long), with what is to
    /// follow it.
    pub fn answered(&mut self, now: Instant) -> Option<(T, Result<SocketAddr, String>)> {
        let lookup = self.pending.as_ref()?;
        let found = match lookup.answer.try_recv() {
            Ok(found) => found,
            Err(TryRecvError::Empty) if now - lookup.began < LOOKUP_WAIT => return None,
            Err(TryRecvError::Empty) => Err(format!(
                "no address for {} within {} s (the resolver does not answer)",
                lookup.host,
                LOOKUP_WAIT.as_secs()
            )),
            Err(TryRecvError::Disconnected) => Err(format!("looking {} up failed", lookup.host)),
        };
        let lookup = self.pending.take()?;
        Some((lookup.then, found))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;

    fn wait_for_answer(lookups: &mut Lookups<u32>) -> (u32, Result<SocketAddr, String>) {
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            if let Some(answer) = lookups.answered(Instant::now()) {
                return answer;
            }
            assert!(Instant::now() < deadline, "no answer");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    #[test]
    fn the_newest_answer_comes_back_and_hung_look_ups_are_capped_and_timed_out() {
        let mut lookups = Lookups::default();
        let at: SocketAddr = "192.0.2.1:4000".parse().unwrap();
        lookups.start("a", 1, move || Ok(at)).unwrap();
        assert_eq!(wait_for_answer(&mut lookups), (1, Ok(at)));
        assert!(lookups.answered(Instant::now()).is_none(), "said once");

        // Resolvers that never answer: each replaces the last, up to the cap.
        let (release, held) = mpsc::channel::<()>();
        let held = Arc::new(std::sync::Mutex::new(held));
        for n in 0..MOST_RUNNING {
            let held = Arc::clone(&held);
            let n = u32::try_from(n).unwrap();
            lookups
                .start("hung", n, move || {
                    let _ = held.lock().unwrap().recv();
                    Err("released".into())
                })
                .unwrap();
        }
        let refused = lookups.start("one more", 9, move || Ok(at)).unwrap_err();
        assert!(refused.to_string().contains("still waiting"), "{refused}");
        lookups
            .start("again", 5, || Ok("192.0.2.2:1".parse().unwrap()))
            .unwrap_err();
        // Past the wait, the one pending fails naming its host.
        let (_silent, answer) = sync_channel(1);
        lookups.pending = Some(Lookup {
            then: 7,
            host: "slow.example".into(),
            began: Instant::now(),
            answer,
        });
        assert!(lookups.answered(Instant::now()).is_none(), "still waiting");
        let later = Instant::now() + LOOKUP_WAIT;
        let (then, failed) = lookups.answered(later).unwrap();
        assert_eq!(then, 7);
        assert!(failed.unwrap_err().contains("slow.example"));
        // Released, their threads count out and look-ups start again.
        for _ in 0..MOST_RUNNING {
            release.send(()).unwrap();
        }
        let deadline = Instant::now() + Duration::from_secs(30);
        while lookups.running.load(Ordering::Relaxed) > 0 {
            assert!(Instant::now() < deadline, "threads never counted out");
            std::thread::sleep(Duration::from_millis(5));
        }
        lookups.start("b", 2, move || Ok(at)).unwrap();
        assert_eq!(wait_for_answer(&mut lookups), (2, Ok(at)));
    }
}
