//! Work the engine's worker must not wait on (a host's look-up, a device opening or closing)
//! runs on a short-lived thread of its own, and its answer comes back to the worker's loop
//! with what is to follow it. One job is pending at most: a newer one drops the one still
//! running (its thread ends on its own), and one not answered within its wait fails. Threads
//! running at once are capped, forgotten ones included: a user who redials or flips devices
//! faster than they answer waits, rather than threads piling up.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, TryRecvError, sync_channel};
use std::time::{Duration, Instant};

/// Threads of one kind running at once at most.
pub const MOST_RUNNING: usize = 4;

/// Why no thread was started.
#[derive(Debug, thiserror::Error)]
pub enum SpawnError {
    #[error("{MOST_RUNNING} are still running")]
    Busy,
    #[error("{0}")]
    Thread(#[from] std::io::Error),
}

/// How a pending job ended.
#[derive(Debug, PartialEq)]
pub enum Outcome<V> {
    Done(Result<V, String>),
    /// Not answered within the wait; its thread goes on and ends on its own.
    TimedOut,
    /// Its thread ended without answering (it panicked).
    Lost,
}

struct Job<K, V> {
    key: K,
    began: Instant,
    answer: Receiver<Result<V, String>>,
}

/// One job pending at most, `K` being what follows it and `V` its answer.
pub struct OffWorker<K, V> {
    name: &'static str,
    wait: Duration,
    running: Arc<AtomicUsize>,
    pending: Option<Job<K, V>>,
}

/// Counts a thread out however it ends.
struct Running(Arc<AtomicUsize>);

impl Drop for Running {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::Relaxed);
    }
}

impl<K, V: Send + 'static> OffWorker<K, V> {
    /// Threads named `name`; a job is waited for `wait`.
    pub fn new(name: &'static str, wait: Duration) -> Self {
        Self {
            name,
            wait,
            running: Arc::default(),
            pending: None,
        }
    }

    /// Runs `work` on a thread of its own, counted against [`MOST_RUNNING`], its answer not
    /// waited for (a device closing).
    pub fn spawn(&self, work: impl FnOnce() + Send + 'static) -> Result<(), SpawnError> {
        if self.running.load(Ordering::Relaxed) >= MOST_RUNNING {
            return Err(SpawnError::Busy);
        }
        self.running.fetch_add(1, Ordering::Relaxed);
        let running = Running(Arc::clone(&self.running));
        std::thread::Builder::new()
            .name(self.name.into())
            .spawn(move || {
                let _running = running;
                work();
            })?;
        Ok(())
    }

    /// Starts `work` on a thread of its own, replacing any job pending.
    pub fn start(
        &mut self,
        key: K,
        work: impl FnOnce() -> Result<V, String> + Send + 'static,
    ) -> Result<(), SpawnError> {
        self.pending = None;
        let (tell, answer) = sync_channel(1);
        // An answer to a job since replaced is dropped on its thread (a device closes there).
        self.spawn(move || {
            let _ = tell.send(work());
        })?;
        self.pending = Some(Job {
            key,
            began: Instant::now(),
            answer,
        });
        Ok(())
    }

    pub fn is_pending(&self) -> bool {
        self.pending.is_some()
    }

    pub fn forget(&mut self) {
        self.pending = None;
    }

    /// The pending job's outcome once it answered or waited too long, with its key; said once.
    pub fn finished(&mut self, now: Instant) -> Option<(K, Outcome<V>)> {
        let job = self.pending.as_ref()?;
        let outcome = match job.answer.try_recv() {
            Ok(answer) => Outcome::Done(answer),
            Err(TryRecvError::Empty) if now - job.began < self.wait => return None,
            Err(TryRecvError::Empty) => Outcome::TimedOut,
            Err(TryRecvError::Disconnected) => Outcome::Lost,
        };
        let job = self.pending.take()?;
        Some((job.key, outcome))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Mutex, mpsc};

    const WAIT: Duration = Duration::from_secs(10);

    fn wait_for(jobs: &mut OffWorker<u32, u32>) -> (u32, Outcome<u32>) {
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            if let Some(finished) = jobs.finished(Instant::now()) {
                return finished;
            }
            assert!(Instant::now() < deadline, "no answer");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    #[test]
    fn the_newest_answer_comes_back_once_and_a_silent_job_times_out() {
        let mut jobs = OffWorker::new("test-job", WAIT);
        jobs.start(1, || Ok(10)).unwrap();
        assert_eq!(wait_for(&mut jobs), (1, Outcome::Done(Ok(10))));
        assert!(jobs.finished(Instant::now()).is_none(), "said once");

        let (release, held) = mpsc::channel::<()>();
        let began = Instant::now();
        jobs.start(2, move || {
            let _ = held.recv();
            Ok(20)
        })
        .unwrap();
        assert!(began.elapsed() < Duration::from_secs(1), "start waited");
        assert!(jobs.is_pending());
        assert!(jobs.finished(Instant::now()).is_none(), "not answered yet");
        // Past the wait it fails, without waiting on the thread.
        assert_eq!(
            jobs.finished(Instant::now() + WAIT),
            Some((2, Outcome::TimedOut))
        );
        assert!(!jobs.is_pending());

        // A newer job replaces one still running; only the newer answers.
        let (release_3, held_3) = mpsc::channel::<()>();
        jobs.start(3, move || {
            let _ = held_3.recv();
            Ok(30)
        })
        .unwrap();
        jobs.start(4, || Err("the fourth".into())).unwrap();
        assert_eq!(
            wait_for(&mut jobs),
            (4, Outcome::Done(Err("the fourth".into())))
        );
        let _ = release.send(());
        let _ = release_3.send(());

        jobs.start(5, || panic!("a job that panics")).unwrap();
        assert_eq!(wait_for(&mut jobs), (5, Outcome::Lost));
    }

    #[test]
    fn threads_running_at_once_are_capped_and_counted_out() {
        let mut jobs = OffWorker::new("test-job", WAIT);
        let (release, held) = mpsc::channel::<()>();
        let held = Arc::new(Mutex::new(held));
        for n in 0..MOST_RUNNING {
            let held = Arc::clone(&held);
            jobs.start(u32::try_from(n).unwrap(), move || {
                let _ = held.lock().map(|h| h.recv());
                Err("released".into())
            })
            .unwrap();
        }
        assert!(matches!(jobs.start(9, || Ok(9)), Err(SpawnError::Busy)));
        assert!(matches!(jobs.spawn(|| ()), Err(SpawnError::Busy)));
        for _ in 0..MOST_RUNNING {
            release.send(()).unwrap();
        }
        let deadline = Instant::now() + Duration::from_secs(30);
        while jobs.running.load(Ordering::Relaxed) > 0 {
            assert!(Instant::now() < deadline, "threads never counted out");
            std::thread::sleep(Duration::from_millis(5));
        }
        jobs.start(6, || Ok(60)).unwrap();
        assert_eq!(wait_for(&mut jobs), (6, Outcome::Done(Ok(60))));
    }
}
