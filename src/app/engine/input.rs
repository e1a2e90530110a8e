//! The engine's microphone: the one chosen opens off the worker through
//! [`crate::app::device_opener`] and is swapped in once open; the one it replaced closes off
//! the worker too.

use std::time::Instant;

use super::{NO_AUDIO, Worker, lock};
use crate::audio::{Capture, DeviceChoice};

impl Worker {
    /// The microphone of the engine's start, opened before the worker runs (the app applies
    /// the settings' push-to-talk to it as it starts).
    pub(super) fn open_first_mic(&mut self) {
        if self.config.no_audio {
            lock(&self.shared).input_status = format!("No microphone: {NO_AUDIO}");
            return;
        }
        let opened = Capture::start(&self.config.input).map_err(|e| e.to_string());
        self.use_mic(opened);
    }

    /// Opens `choice` off the worker ([`Worker::follow_input`] swaps it in).
    pub(super) fn open_input(&mut self, choice: DeviceChoice) -> anyhow::Result<()> {
        if self.config.no_audio {
            return Ok(());
        }
        self.inputs.start(choice, |choice| {
            Capture::start(choice).map_err(|e| e.to_string())
        })
    }

    /// Swaps the microphone in once open, each pass of the worker's loop. One that failed
    /// leaves the engine receive-only, as the user asked for another than the one before.
    pub(super) fn follow_input(&mut self) {
        if let Some((_, opened)) = self.inputs.opened(Instant::now()) {
            self.use_mic(opened);
        }
    }

    fn use_mic(&mut self, opened: Result<Capture, String>) {
        let status = match &opened {
            Ok(mic) => format!("microphone: {}", mic.device_name()),
            // The device layer's own line may already say what follows.
            Err(e) => format!(
                "no microphone ({}): receive-only",
                e.strip_suffix(": receive-only").unwrap_or(e)
            ),
        };
        let mic = opened.ok();
        let controls = mic.as_ref().map(Capture::controls);
        if let (Some(new), Some(old)) = (&controls, &self.mic_controls) {
            new.set_muted(old.muted());
            new.set_push_to_talk(old.push_to_talk());
        }
        if controls.is_some() {
            self.mic_controls.clone_from(&controls);
        }
        if let Some(old) = std::mem::replace(&mut self.mic, mic) {
            self.inputs.close(old);
        }
        let mut s = lock(&self.shared);
        s.input_status = status;
        s.mic = controls;
    }
}
