//! 20 ms of a stream's audio at the rate its codec decodes to (8 kHz G.711 and Speex narrowband,
//! 16 kHz G.722 and Speex wideband, 48 kHz Opus), beside the 8 kHz signal the features are
//! computed from. Fixed-size, so that a frame moves between threads without allocating.

use super::features::{FRAME_SIZE, SAMPLE_RATE};

/// The highest rate a decoder outputs (Opus fullband).
pub const MAX_AUDIO_RATE: u32 = 48_000;
/// Samples in 20 ms at [`MAX_AUDIO_RATE`].
pub const MAX_FRAME_SAMPLES: usize = MAX_AUDIO_RATE as usize / 50;

/// The rates a frame may carry: those whose 20 ms is a whole number of samples, up to 48 kHz.
pub const fn valid_rate(rate: u32) -> bool {
    rate >= SAMPLE_RATE && rate <= MAX_AUDIO_RATE && rate.is_multiple_of(50)
}

/// 20 ms of mono audio at `rate`.
#[derive(Clone, PartialEq)]
pub struct FrameAudio {
    rate: u32,
    samples: [i16; MAX_FRAME_SAMPLES],
}

impl std::fmt::Debug for FrameAudio {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FrameAudio")
            .field("rate", &self.rate)
            .finish_non_exhaustive()
    }
}

impl Default for FrameAudio {
    fn default() -> Self {
        Self::silence(SAMPLE_RATE)
    }
}

impl FrameAudio {
    /// 20 ms of silence at `rate` (8 kHz for a rate no frame may carry).
    pub fn silence(rate: u32) -> Self {
        Self {
            rate: if valid_rate(rate) { rate } else { SAMPLE_RATE },
            samples: [0; MAX_FRAME_SAMPLES],
        }
    }

    /// A narrowband frame as it is.
    pub fn narrowband(pcm: &[i16; FRAME_SIZE]) -> Self {
        let mut audio = Self::silence(SAMPLE_RATE);
        audio.samples_mut().copy_from_slice(pcm);
        audio
    }

    /// 20 ms at `rate` from the start of `pcm`, zero-padded where it is shorter.
    pub fn from_slice(rate: u32, pcm: &[i16]) -> Self {
        let mut audio = Self::silence(rate);
        let out = audio.samples_mut();
        let n = out.len().min(pcm.len());
        out[..n].copy_from_slice(&pcm[..n]);
        audio
    }

    pub fn rate(&self) -> u32 {
        self.rate
    }

    /// The 20 ms of samples: `rate / 50` of them.
    pub fn samples(&self) -> &[i16] {
        &self.samples[..self.len()]
    }

    pub fn samples_mut(&mut self) -> &mut [i16] {
        let n = self.len();
        &mut self.samples[..n]
    }

    fn len(&self) -> usize {
        self.rate as usize / 50
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_holds_20_ms_at_its_rate() {
        for (rate, n) in [(8000, 160), (16_000, 320), (24_000, 480), (48_000, 960)] {
            assert_eq!(FrameAudio::silence(rate).samples().len(), n);
        }
        assert_eq!(FrameAudio::silence(96_000).rate(), SAMPLE_RATE);
        assert_eq!(FrameAudio::silence(44_123).rate(), SAMPLE_RATE);
        let nb = FrameAudio::narrowband(&[7; FRAME_SIZE]);
        assert_eq!(nb.samples(), &[7; FRAME_SIZE][..]);
        let short = FrameAudio::from_slice(16_000, &[3; 10]);
        assert_eq!(short.samples()[..10], [3; 10]);
        assert!(short.samples()[10..].iter().all(|&s| s == 0));
    }
}
