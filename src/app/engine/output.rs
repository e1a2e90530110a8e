//! The engine's side of [`crate::app::output`]: the output device chosen opens off the
//! worker and is swapped in once open; one that was lost (the sound server restarted, the
//! device stalled on a starved machine) is opened again, 2 s after the loss, then less and
//! less often.

use std::time::Instant;

use super::{Worker, describe_output, lock};
use crate::audio::{DeviceChoice, Playback};

impl Worker {
    /// Opens `choice` off the worker ([`Worker::follow_output`] swaps it in).
    pub(super) fn open_output(&mut self, choice: DeviceChoice) -> anyhow::Result<()> {
        self.revival.chosen();
        self.start_output(choice)
    }

    fn start_output(&mut self, choice: DeviceChoice) -> anyhow::Result<()> {
        let buffer = lock(&self.shared).playback.buffer();
        self.outputs.start(choice, move |choice| {
            Playback::open_output(choice, buffer).map_err(|e| e.to_string())
        })
    }

    /// Swaps the device in once open, each pass of the worker's loop; the one it replaced
    /// closes off the worker.
    pub(super) fn follow_output(&mut self) {
        let Some((choice, opened)) = self.outputs.opened(Instant::now()) else {
            return;
        };
        let mut s = lock(&self.shared);
        let swapped =
            opened.and_then(|o| s.playback.use_output(choice, o).map_err(|e| e.to_string()));
        s.output_status = describe_output(s.playback.status());
        let revived = self.revival.finished(swapped.is_ok());
        match swapped {
            Ok(retired) => {
                drop(s);
                if revived {
                    tracing::info!("the output device is back");
                }
                self.outputs.close(retired);
            }
            Err(e) if revived => tracing::debug!("the lost output device: {e}"),
            Err(e) => s.call.error = Some(e),
        }
    }

    /// Notices an output lost (the UI's look does too) and opens its choice again when the
    /// wait is up, unless the user's own choice is opening.
    pub(super) fn revive_output(&mut self, now: Instant) {
        let lost = {
            let mut s = lock(&self.shared);
            if let Some(status) = s.playback.poll() {
                s.output_status = describe_output(status);
            }
            s.playback.lost_output().cloned()
        };
        let Some(choice) = lost else {
            self.revival.playing();
            return;
        };
        if self.outputs.is_opening() || !self.revival.due(now) {
            return;
        }
        if let Err(e) = self.start_output(choice) {
            self.revival.finished(false);
            tracing::debug!("the lost output device: {e}");
        }
    }
}
