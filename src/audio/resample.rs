//! The one way the real-time paths build a resampler: rubato's FFT resampler between two rates
//! (8 kHz or a stream's own, and a device's or a file's), or none when the rates already match.

use rubato::audioadapter_buffers::direct::InterleavedSlice;
use rubato::{Fft, FixedSync, Resampler};

use super::error::AudioError;

pub(crate) fn fft_resampler(
    from: u32,
    to: u32,
    chunk: usize,
    fixed: FixedSync,
) -> Result<Option<Fft<f32>>, AudioError> {
    if from == 0 || to == 0 {
        return Err(AudioError::Resampler("device rate 0".into()));
    }
    if from == to {
        return Ok(None);
    }
    Fft::<f32>::new(from as usize, to as usize, chunk, 1, fixed)
        .map(Some)
        .map_err(|e| AudioError::Resampler(e.to_string()))
}

/// One stream's 20 ms frames from their rate to another, each frame in giving one frame out
/// (after the resampler's delay, which it reports), buffers allocated once. With equal rates it
/// copies. Used once per peer, so that a peer is resampled in one step to where it is heard.
pub struct FrameResampler {
    resampler: Option<Fft<f32>>,
    from: u32,
    to: u32,
    input: Vec<f32>,
    output: Vec<f32>,
}

impl std::fmt::Debug for FrameResampler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FrameResampler")
            .field("from", &self.from)
            .field("to", &self.to)
            .finish_non_exhaustive()
    }
}

impl FrameResampler {
    /// From `from` to `to` Hz; both must hold a whole number of samples in 20 ms.
    pub fn new(from: u32, to: u32) -> Result<Self, AudioError> {
        if !from.is_multiple_of(50) || !to.is_multiple_of(50) {
            return Err(AudioError::Resampler(format!(
                "{from} Hz to {to} Hz: 20 ms frames need rates divisible by 50"
            )));
        }
        let (n_in, n_out) = (from as usize / 50, to as usize / 50);
        let resampler = fft_resampler(from, to, n_in, FixedSync::Both)?;
        Ok(Self {
            resampler,
            from,
            to,
            input: vec![0.0; n_in],
            output: vec![0.0; n_out],
        })
    }

    pub fn from_rate(&self) -> u32 {
        self.from
    }

    pub fn to_rate(&self) -> u32 {
        self.to
    }

    /// Output samples by which the output lags the input.
    pub fn delay(&self) -> usize {
        self.resampler.as_ref().map_or(0, |r| r.output_delay())
    }

    /// 20 ms at the input rate into `out` (20 ms at the output rate, or as much as it holds).
    pub fn process_into(&mut self, frame: &[i16], out: &mut [i16]) -> Result<(), AudioError> {
        let mut mix = [0i32; crate::vocab::MAX_FRAME_SAMPLES];
        let n = out.len().min(self.output.len());
        self.add_into(frame, &mut mix[..n])?;
        for (o, &m) in out.iter_mut().zip(&mix[..n]) {
            *o = m.clamp(-32768, 32767) as i16;
        }
        Ok(())
    }

    /// 20 ms at the input rate (shorter is zero-padded, longer cut) into 20 ms at the output
    /// rate, added to `mix` (as long as it is).
    pub fn add_into(&mut self, frame: &[i16], mix: &mut [i32]) -> Result<(), AudioError> {
        for (i, x) in self.input.iter_mut().enumerate() {
            *x = frame.get(i).map_or(0.0, |&s| f32::from(s) / 32768.0);
        }
        let out = match self.resampler.as_mut() {
            None => &self.input,
            Some(r) => {
                let err = |e: &dyn std::fmt::Display| AudioError::Resampler(e.to_string());
                let (n_in, n_out) = (self.input.len(), self.output.len());
                let inp = InterleavedSlice::new(&self.input[..], 1, n_in).map_err(|e| err(&e))?;
                let mut outp = InterleavedSlice::new_mut(&mut self.output[..], 1, n_out)
                    .map_err(|e| err(&e))?;
                r.process_into_buffer(&inp, &mut outp, None)
                    .map_err(|e| err(&e))?;
                &self.output
            }
        };
        for (m, &x) in mix.iter_mut().zip(out) {
            *m += (x * 32768.0).round().clamp(-32768.0, 32767.0) as i32;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tone_keeps_its_level_and_frequency_across_rates() {
        for (from, to) in [
            (8000, 48_000),
            (48_000, 16_000),
            (16_000, 48_000),
            (8000, 8000),
        ] {
            let mut r = FrameResampler::new(from, to).unwrap();
            let (n_in, n_out) = (from as usize / 50, to as usize / 50);
            let mut out = Vec::new();
            for f in 0..50 {
                let frame: Vec<i16> = (0..n_in)
                    .map(|i| {
                        let t = (f * n_in + i) as f64 / f64::from(from);
                        (10000.0 * (2.0 * std::f64::consts::PI * 1000.0 * t).sin()) as i16
                    })
                    .collect();
                let mut mix = vec![0i32; n_out];
                r.add_into(&frame, &mut mix).unwrap();
                out.extend(mix);
            }
            let settled = &out[out.len() / 2..];
            let rms = (settled.iter().map(|&s| (s as f64).powi(2)).sum::<f64>()
                / settled.len() as f64)
                .sqrt();
            assert!(
                (rms / (10000.0 / 2f64.sqrt()) - 1.0).abs() < 0.05,
                "{from}->{to}: {rms}"
            );
            let crossings = settled.windows(2).filter(|w| w[0] < 0 && w[1] >= 0).count();
            let expected = 1000.0 * settled.len() as f64 / f64::from(to);
            assert!((crossings as f64 - expected).abs() <= 2.0, "{from}->{to}");
        }
        assert!(FrameResampler::new(8000, 44_123).is_err());
    }
}
