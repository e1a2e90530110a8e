//! The demo peer: the bundled speech sample, looped, sent to the app's own session as a
//! remote speaker would send it, so that an empty call still shows a talking head.

use std::net::SocketAddr;

use super::counters::DEMO_NAME;
use crate::codec::speex::codec::{Encoder, EncoderConfig, MAX_PACKET_BYTES};
use crate::net::session::{Session, SessionConfig};
use crate::vocab::FRAME_SIZE;

const DEMO_WAV: &[u8] = include_bytes!("../../assets/speech/demo.wav");

/// The bundled speech sample at 8 kHz.
fn demo_speech() -> anyhow::Result<Vec<i16>> {
    use crate::audio::wav;
    let reader = hound::WavReader::new(std::io::Cursor::new(DEMO_WAV))?;
    let spec = reader.spec();
    let channels = usize::from(spec.channels.max(1));
    let scale = 1.0 / (1u64 << (spec.bits_per_sample.clamp(1, 32) - 1)) as f32;
    let interleaved: Vec<f32> = reader
        .into_samples::<i32>()
        .map(|s| s.map(|v| v as f32 * scale))
        .collect::<Result<_, _>>()?;
    let samples = interleaved
        .chunks_exact(channels)
        .map(|f| f.iter().sum::<f32>() / channels as f32)
        .collect();
    let audio = wav::MonoAudio {
        rate: spec.sample_rate,
        samples,
    };
    Ok(wav::to_i16(&wav::resample(
        &audio,
        crate::vocab::SAMPLE_RATE,
    )?))
}

/// The looped demo speech, encoded frame by frame and sent to our own session, in Speex (the
/// reference path; calls send the codec of the settings).
pub(super) struct Demo {
    session: Session,
    encoder: Encoder,
    pcm: Vec<i16>,
    at: usize,
}

impl Demo {
    pub(super) fn start(to: SocketAddr) -> anyhow::Result<Self> {
        let pcm = demo_speech()?;
        anyhow::ensure!(pcm.len() >= FRAME_SIZE, "the demo speech sample is empty");
        let mut config = SessionConfig::new(SocketAddr::new(to.ip(), 0));
        config.destinations = vec![to];
        config.name = Some(DEMO_NAME.into());
        let session = Session::start(config)?;
        Ok(Self {
            session,
            encoder: Encoder::new(EncoderConfig::default())?,
            pcm,
            at: 0,
        })
    }

    pub(super) fn tick(&mut self) {
        let mut frame = [0i16; FRAME_SIZE];
        for s in frame.iter_mut() {
            *s = self.pcm[self.at];
            self.at = (self.at + 1) % self.pcm.len();
        }
        let mut packet = [0u8; MAX_PACKET_BYTES];
        if let Some(n) = self.encoder.encode_frame(&frame, &mut packet) {
            let _ = self.session.send_frames(&packet[..n], 1);
        }
    }

    /// Says BYE: a real peer came.
    pub(super) fn leave(self) {
        self.session.leave();
    }
}
