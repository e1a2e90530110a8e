//! The microphone to the call: each frame read in the length the encoder takes (Opus's 10 ms
//! or 20 ms), encoded and sent as soon as the device has delivered it; frames the gate closed
//! (mute, push-to-talk) move the stream's clock on instead.

use super::{Worker, lock};
use crate::audio::Gate;
use crate::call::link::Link;
use crate::codec::any::{FrameEncoder, MAX_FRAME_PAYLOAD};
use crate::vocab::MAX_FRAME_SAMPLES;

/// Links skip our stream's clock in whole frames of this length, ms.
const SKIP_MS: u8 = 20;

impl Worker {
    pub(super) fn send_mic(&mut self) {
        let Some(mic) = &mut self.mic else { return };
        let in_call = self.in_call || !self.answered.is_empty();
        // The microphone resampled once, straight to the rate and frame length the encoder
        // takes.
        if let Err(e) = mic.set_format(self.encoder.input_rate(), self.encoder.frame_ms()) {
            tracing::debug!(
                "microphone kept at {} samples a frame: {e}",
                mic.frame_samples()
            );
        }
        mic.wake_me();
        let frame_ms = mic.frame_ms();
        let mut frame = [0i16; MAX_FRAME_SAMPLES];
        let frame = &mut frame[..mic.frame_samples()];
        let mut payload = [0u8; MAX_FRAME_PAYLOAD];
        loop {
            match mic.read_frame(frame) {
                Ok(Some(Gate::Open)) if in_call => {
                    let rest = std::mem::take(&mut self.mic_skipped_ms);
                    send_silence(&mut self.encoder, self.link.as_mut(), rest, &mut payload);
                    // A microphone left at 20 ms (its format refused) still sends the
                    // encoder's frames.
                    let step = self.encoder.frame_samples().clamp(1, frame.len());
                    for part in frame.chunks_exact(step) {
                        if let Ok(Some((n, ticks))) = self.encoder.encode(part, &mut payload) {
                            self.link.send_audio(&payload[..n], ticks);
                        }
                    }
                }
                Ok(Some(_)) => {
                    if in_call {
                        self.mic_skipped_ms = self.mic_skipped_ms.saturating_add(frame_ms);
                        let whole = self.mic_skipped_ms / SKIP_MS;
                        if whole > 0 {
                            self.link.skip_frames(u32::from(whole));
                            self.mic_skipped_ms %= SKIP_MS;
                        }
                    }
                }
                Ok(None) => break,
                Err(e) => {
                    self.mic = None;
                    let mut s = lock(&self.shared);
                    s.input_status = format!("microphone lost ({e}): receive-only");
                    s.mic = None;
                    break;
                }
            }
        }
    }
}

/// A closed 10 ms frame that did not make a whole skipped frame (`rest_ms`) goes out as silence
/// before the voice that follows it, so the stream's clock stays on the microphone's.
fn send_silence(
    encoder: &mut FrameEncoder,
    link: &mut dyn Link,
    rest_ms: u8,
    payload: &mut [u8; MAX_FRAME_PAYLOAD],
) {
    if rest_ms == 0 || rest_ms != encoder.frame_ms() {
        return;
    }
    let silence = [0i16; MAX_FRAME_SAMPLES];
    let n = encoder.frame_samples().min(MAX_FRAME_SAMPLES);
    if let Ok(Some((len, ticks))) = encoder.encode(&silence[..n], payload) {
        link.send_audio(&payload[..len], ticks);
    }
}
