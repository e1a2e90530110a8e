//! Host names looked up off the engine's worker ([`OffWorker`]). DNS can take seconds (a
//! resolver that does not answer): a worker waiting on it would hold up every peer's audio and
//! face. A newer look-up (a newer call) or [`Lookups::forget`] (a leave) drops one still
//! running, and one that takes longer than [`LOOKUP_WAIT`] fails.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use super::off_worker::{OffWorker, Outcome, SpawnError};

/// How long a look-up is waited for.
pub const LOOKUP_WAIT: Duration = Duration::from_secs(15);

/// One look-up pending at most, and `T`: what is to follow it.
pub struct Lookups<T> {
    jobs: OffWorker<(String, T), SocketAddr>,
}

impl<T> Default for Lookups<T> {
    fn default() -> Self {
        Self {
            jobs: OffWorker::new("lipcall-lookup", LOOKUP_WAIT),
        }
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
        self.jobs
            .start((host.to_owned(), then), find)
            .map_err(|e| match e {
                SpawnError::Busy => anyhow::anyhow!(
                    "cannot look {host} up: earlier look-ups are still waiting on the resolver"
                ),
                SpawnError::Thread(e) => anyhow::anyhow!("cannot look {host} up: {e}"),
            })
    }

    pub fn forget(&mut self) {
        self.jobs.forget();
    }

    /// The pending look-up's answer, once it came (or it waited too long), with what is to
    /// follow it.
    pub fn answered(&mut self, now: Instant) -> Option<(T, Result<SocketAddr, String>)> {
        let ((host, then), outcome) = self.jobs.finished(now)?;
        let found = match outcome {
            Outcome::Done(found) => found,
            Outcome::TimedOut => Err(format!(
                "no address for {host} within {} s (the resolver does not answer)",
                LOOKUP_WAIT.as_secs()
            )),
            Outcome::Lost => Err(format!("looking {host} up failed")),
        };
        Some((then, found))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_look_up_answers_with_what_follows_it_and_a_silent_one_names_its_host() {
        let mut lookups = Lookups::default();
        let at: SocketAddr = "192.0.2.1:4000".parse().unwrap();
        lookups.start("a", 1, move || Ok(at)).unwrap();
        let deadline = Instant::now() + Duration::from_secs(30);
        let answer = loop {
            if let Some(answer) = lookups.answered(Instant::now()) {
                break answer;
            }
            assert!(Instant::now() < deadline, "no answer");
            std::thread::sleep(Duration::from_millis(5));
        };
        assert_eq!(answer, (1, Ok(at)));

        let (release, held) = std::sync::mpsc::channel::<()>();
        lookups
            .start("slow.example", 7, move || {
                let _ = held.recv();
                Ok(at)
            })
            .unwrap();
        assert!(lookups.answered(Instant::now()).is_none(), "still waiting");
        let (then, failed) = lookups.answered(Instant::now() + LOOKUP_WAIT).unwrap();
        assert_eq!(then, 7);
        let failed = failed.unwrap_err();
        assert!(
            failed.contains("slow.example") && failed.contains("does not answer"),
            "{failed}"
        );
        release.send(()).unwrap();
    }
}
