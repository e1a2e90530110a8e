//! The one way the real-time paths build a resampler: rubato's FFT resampler between 8 kHz and a
//! device rate, or none when the rates already match.

use rubato::{Fft, FixedSync};

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
