//! The engine's side of [`crate::app::output`]: the output device chosen opens off the
//! worker and is swapped in once open.

use std::time::Instant;

use super::{Worker, describe_output, lock};
use crate::audio::{DeviceChoice, Playback};

impl Worker {
    /// Opens `choice` off the worker ([`Worker::follow_output`] swaps it in).
    pub(super) fn open_output(&mut self, choice: DeviceChoice) -> anyhow::Result<()> {
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
        match swapped {
            Ok(retired) => {
                drop(s);
                self.outputs.close(retired);
            }
            Err(e) => s.call.error = Some(e),
        }
    }
}
