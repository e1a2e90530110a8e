//! Audio devices opened and closed off the engine's worker ([`OffWorker`]): the output device
//! and the microphone. Opening one can take 2 s (PulseAudio): a worker waiting on it would hold
//! up every peer's audio and face. The worker's loop swaps an opened device in, and the one it
//! replaced closes on a thread too. A newer choice drops one still opening (it closes on its
//! own thread once open), and one that takes longer than [`OPEN_WAIT`] fails.

use std::time::{Duration, Instant};

use super::off_worker::{OffWorker, Outcome};
use crate::audio::DeviceChoice;

/// How long an opening device is waited for.
pub const OPEN_WAIT: Duration = Duration::from_secs(10);

/// A device opened, or the line that says why not.
pub type Opened<T> = Result<T, String>;

/// One device of a kind (`T`: an output, a microphone) opening at most.
pub struct DeviceOpener<T> {
    /// The kind, as messages name it: "output device", "microphone".
    what: &'static str,
    jobs: OffWorker<DeviceChoice, T>,
}

impl<T: Send + 'static> DeviceOpener<T> {
    pub fn new(what: &'static str) -> Self {
        Self {
            what,
            jobs: OffWorker::new("lipcall-device", OPEN_WAIT),
        }
    }

    /// Starts opening `choice` with `open` on a thread of its own, replacing any device still
    /// opening.
    pub fn start(
        &mut self,
        choice: DeviceChoice,
        open: impl FnOnce(&DeviceChoice) -> Opened<T> + Send + 'static,
    ) -> anyhow::Result<()> {
        let opening = choice.clone();
        self.jobs
            .start(choice, move || open(&opening))
            .map_err(|e| anyhow::anyhow!("cannot open the {}: {e}", self.what))
    }

    /// A device is opening (not yet taken by [`DeviceOpener::opened`]).
    pub fn is_opening(&self) -> bool {
        self.jobs.is_pending()
    }

    /// The opening device, once it opened or failed to (or waited too long), with its choice.
    pub fn opened(&mut self, now: Instant) -> Option<(DeviceChoice, Opened<T>)> {
        let (choice, outcome) = self.jobs.finished(now)?;
        let opened = match outcome {
            Outcome::Done(opened) => opened,
            Outcome::TimedOut => Err(format!(
                "the {} did not open within {} s",
                self.what,
                OPEN_WAIT.as_secs()
            )),
            Outcome::Lost => Err(format!("opening the {} failed", self.what)),
        };
        Some((choice, opened))
    }

    /// Closes a device that was replaced, on a thread of its own (on the worker where none
    /// can start: the work is dropped with the thread that never ran it).
    pub fn close(&self, retired: impl Send + 'static) {
        if let Err(e) = self.jobs.spawn(move || drop(retired)) {
            tracing::warn!(
                "cannot close the {} off the worker ({e}): closed it there",
                self.what
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_device_slow_to_open_fails_by_name_and_keeps_its_choice() {
        let mut opener = DeviceOpener::<()>::new("microphone");
        let (release, held) = std::sync::mpsc::channel::<()>();
        opener
            .start(DeviceChoice::Id("slow".into()), move |_| {
                let _ = held.recv();
                Err("the slow one".into())
            })
            .unwrap();
        assert!(opener.is_opening());
        assert!(opener.opened(Instant::now()).is_none(), "not open yet");
        let (choice, opened) = opener.opened(Instant::now() + OPEN_WAIT).unwrap();
        assert_eq!(choice, DeviceChoice::Id("slow".into()));
        assert!(opened.is_err_and(|e| e == "the microphone did not open within 10 s"));
        assert!(!opener.is_opening());
        release.send(()).unwrap();
    }
}
