//! Audio devices opened and closed off the engine's worker: the output device and the
//! microphone. Opening one can take 2 s (PulseAudio): a worker waiting on it would hold up
//! every peer's audio and face. The device opens on a short-lived thread and comes back to the
//! worker's loop, which swaps it in; the one it replaced closes on a thread too. A newer choice
//! drops one still opening (it closes on its own thread once open), and one that takes longer
//! than [`OPEN_WAIT`] fails.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, TryRecvError, sync_channel};
use std::time::{Duration, Instant};

use crate::audio::DeviceChoice;

/// Devices of one kind opening or closing at once at most, forgotten ones included (a user
/// who flips between devices faster than they open waits, rather than threads piling up).
const MOST_RUNNING: usize = 4;
/// How long an opening device is waited for.
pub const OPEN_WAIT: Duration = Duration::from_secs(10);

/// A device opened, or the line that says why not.
pub type Opened<T> = Result<T, String>;

struct Opening<T> {
    choice: DeviceChoice,
    began: Instant,
    answer: Receiver<Opened<T>>,
}

/// One device of a kind (`T`: an output, a microphone) opening at most.
pub struct DeviceOpener<T> {
    /// The kind, as messages name it: "output device", "microphone".
    what: &'static str,
    running: Arc<AtomicUsize>,
    pending: Option<Opening<T>>,
}

/// Counts a device's thread out however it ends.
struct Running(Arc<AtomicUsize>);

impl Drop for Running {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::Relaxed);
    }
}

impl<T: Send + 'static> DeviceOpener<T> {
    pub fn new(what: &'static str) -> Self {
        Self {
            what,
            running: Arc::default(),
            pending: None,
        }
    }

    /// Runs `work` on a thread of its own, counted against [`MOST_RUNNING`].
    fn spawn(&self, doing: &str, work: impl FnOnce() + Send + 'static) -> anyhow::Result<()> {
        let what = self.what;
        if self.running.load(Ordering::Relaxed) >= MOST_RUNNING {
            anyhow::bail!("cannot {doing} the {what}: {MOST_RUNNING} are still opening or closing");
        }
        self.running.fetch_add(1, Ordering::Relaxed);
        let running = Running(Arc::clone(&self.running));
        std::thread::Builder::new()
            .name("lipcall-device".into())
            .spawn(move || {
                let _running = running;
                work();
            })
            .map(drop)
            .map_err(|e| anyhow::anyhow!("cannot {doing} the {what}: {e}"))
    }

    /// Starts opening `choice` with `open` on a thread of its own, replacing any device still
    /// opening.
    pub fn start(
        &mut self,
        choice: DeviceChoice,
        open: impl FnOnce(&DeviceChoice) -> Opened<T> + Send + 'static,
    ) -> anyhow::Result<()> {
        self.pending = None;
        let (tell, answer) = sync_channel(1);
        let opening = choice.clone();
        // A device opened for a choice since replaced is dropped here, closing on this thread.
        self.spawn("open", move || {
            let _ = tell.send(open(&opening));
        })?;
        self.pending = Some(Opening {
            choice,
            began: Instant::now(),
            answer,
        });
        Ok(())
    }

    /// A device is opening (not yet taken by [`DeviceOpener::opened`]).
    pub fn is_opening(&self) -> bool {
        self.pending.is_some()
    }

    /// The opening device, once it opened or failed to (or waited too long), with its choice.
    pub fn opened(&mut self, now: Instant) -> Option<(DeviceChoice, Opened<T>)> {
        let opening = self.pending.as_ref()?;
        let opened = match opening.answer.try_recv() {
            Ok(opened) => opened,
            Err(TryRecvError::Empty) if now - opening.began < OPEN_WAIT => return None,
            Err(TryRecvError::Empty) => Err(format!(
                "the {} did not open within {} s",
                self.what,
                OPEN_WAIT.as_secs()
            )),
            Err(TryRecvError::Disconnected) => Err(format!("opening the {} failed", self.what)),
        };
        let opening = self.pending.take()?;
        Some((opening.choice, opened))
    }

    /// Closes a device that was replaced, on a thread of its own (on the worker where none
    /// can start: the work is dropped with the thread that never ran it).
    pub fn close(&self, retired: impl Send + 'static) {
        if let Err(e) = self.spawn("close", move || drop(retired)) {
            tracing::warn!("{e}: closed it on the worker");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;

    fn wait_for_opened(opener: &mut DeviceOpener<()>) -> (DeviceChoice, Opened<()>) {
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            if let Some(opened) = opener.opened(Instant::now()) {
                return opened;
            }
            assert!(Instant::now() < deadline, "never opened");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    #[test]
    fn a_device_slow_to_open_comes_back_later_and_a_newer_choice_replaces_it() {
        let mut opener = DeviceOpener::<()>::new("device");
        let (release, held) = mpsc::channel::<()>();
        let began = Instant::now();
        opener
            .start(DeviceChoice::Id("slow".into()), move |_| {
                let _ = held.recv();
                Err("the slow one".into())
            })
            .unwrap();
        assert!(began.elapsed() < Duration::from_secs(1), "start waited");
        assert!(opener.pending.is_some());
        assert!(opener.opened(Instant::now()).is_none(), "not open yet");
        // Past the wait it fails, without waiting on the thread.
        let (choice, opened) = opener.opened(Instant::now() + OPEN_WAIT).unwrap();
        assert_eq!(choice, DeviceChoice::Id("slow".into()));
        assert!(opened.is_err_and(|e| e.contains("did not open within")));
        assert!(opener.pending.is_none());

        opener
            .start(DeviceChoice::Id("held".into()), |_| Err("the first".into()))
            .unwrap();
        opener
            .start(DeviceChoice::Default, |_| Err("the second".into()))
            .unwrap();
        let (choice, opened) = wait_for_opened(&mut opener);
        assert_eq!(choice, DeviceChoice::Default);
        assert!(opened.is_err_and(|e| e == "the second"));
        release.send(()).unwrap();
    }

    #[test]
    fn devices_opening_at_once_are_capped() {
        let mut opener = DeviceOpener::<()>::new("device");
        let (release, held) = mpsc::channel::<()>();
        let held = Arc::new(std::sync::Mutex::new(held));
        for _ in 0..MOST_RUNNING {
            let held = Arc::clone(&held);
            opener
                .start(DeviceChoice::Default, move |_| {
                    let _ = held.lock().map(|h| h.recv());
                    Err("released".into())
                })
                .unwrap();
        }
        let refused = opener.start(DeviceChoice::Default, |_| Err("never".into()));
        assert!(refused.is_err_and(|e| e.to_string().contains("still opening")));
        for _ in 0..MOST_RUNNING {
            release.send(()).unwrap();
        }
        let deadline = Instant::now() + Duration::from_secs(30);
        while opener.running.load(Ordering::Relaxed) > 0 {
            assert!(Instant::now() < deadline, "threads never ended");
            std::thread::sleep(Duration::from_millis(5));
        }
        opener
            .start(DeviceChoice::Default, |_| Err("after".into()))
            .unwrap();
        assert!(wait_for_opened(&mut opener).1.is_err_and(|e| e == "after"));
    }
}
