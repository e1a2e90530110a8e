//! WAV files in and out. Any input (rate, channels, integer or float samples) becomes 8 kHz mono.

use std::path::Path;

use rubato::audioadapter_buffers::direct::InterleavedSlice;
use rubato::{Fft, FixedSync, Resampler};

use crate::vocab::SAMPLE_RATE;

#[derive(Debug, thiserror::Error)]
pub enum WavError {
    #[error(transparent)]
    Input(#[from] crate::input::InputError),
    #[error("{path}: not a readable WAV file ({reason})")]
    Format { path: String, reason: String },
    #[error("{path}: the WAV file holds no audio")]
    Empty { path: String },
    #[error("resampling failed: {0}")]
    Resample(String),
    #[error("{path}: cannot write WAV: {reason}")]
    Write { path: String, reason: String },
}

/// Audio read from a file: mono samples in [-1, 1] at `rate`.
#[derive(Debug, Clone, PartialEq)]
pub struct MonoAudio {
    pub rate: u32,
    pub samples: Vec<f32>,
}

fn format_error(path: &Path, e: impl std::fmt::Display) -> WavError {
    WavError::Format {
        path: path.display().to_string(),
        reason: e.to_string(),
    }
}

/// Sample rates accepted from files: below 4 kHz there is no narrowband speech to code, and a
/// header's absurd rate would otherwise make resampling invent hours of audio.
pub const RATES: std::ops::RangeInclusive<u32> = 4000..=384_000;

/// Opens a WAV file and checks its header against what the file really holds: a sample rate in
/// [`RATES`], and no more audio claimed than the file's bytes (the sample iterator's length, and
/// so every allocation sized by it, comes from the header). Returns the reader and its format.
pub fn open(path: &Path) -> Result<hound::WavReader<std::io::BufReader<std::fs::File>>, WavError> {
    let (file, size) = crate::input::open(path, crate::input::MAX_INPUT_BYTES)?;
    let reader =
        hound::WavReader::new(std::io::BufReader::new(file)).map_err(|e| format_error(path, e))?;
    let spec = reader.spec();
    if spec.channels == 0 {
        return Err(format_error(path, "zero channels"));
    }
    if !RATES.contains(&spec.sample_rate) {
        return Err(format_error(
            path,
            format!(
                "sample rate {} Hz, expected {} to {} Hz",
                spec.sample_rate,
                RATES.start(),
                RATES.end()
            ),
        ));
    }
    let claimed = u64::from(reader.len()) * u64::from(spec.bits_per_sample.div_ceil(8));
    if claimed > size {
        return Err(format_error(
            path,
            format!("the header claims {claimed} bytes of audio, the file has {size} bytes"),
        ));
    }
    Ok(reader)
}

/// Reads a WAV file and mixes its channels down to mono.
pub fn read_mono(path: &Path) -> Result<MonoAudio, WavError> {
    let name = || path.display().to_string();
    let reader = open(path)?;
    let spec = reader.spec();
    let channels = usize::from(spec.channels);
    let interleaved: Vec<f32> = match spec.sample_format {
        hound::SampleFormat::Float => {
            let samples: Vec<f32> = reader
                .into_samples::<f32>()
                .collect::<Result<_, _>>()
                .map_err(|e| format_error(path, e))?;
            if let Some(n) = samples.iter().position(|s| !s.is_finite()) {
                return Err(format_error(
                    path,
                    format!("sample {} is not a number", n / channels),
                ));
            }
            // Beyond full scale a float sample clips, as it would on output; unclipped, values
            // near f32's limit overflow the resampler's FFT into NaN, on which rubato panics.
            samples.into_iter().map(|s| s.clamp(-1.0, 1.0)).collect()
        }
        hound::SampleFormat::Int => {
            let scale = 1.0 / (1u64 << (spec.bits_per_sample.clamp(1, 32) - 1)) as f32;
            reader
                .into_samples::<i32>()
                .map(|s| s.map(|v| v as f32 * scale))
                .collect::<Result<_, _>>()
                .map_err(|e| format_error(path, e))?
        }
    };
    let samples: Vec<f32> = interleaved
        .chunks_exact(channels)
        .map(|frame| frame.iter().sum::<f32>() / channels as f32)
        .collect();
    if samples.is_empty() {
        return Err(WavError::Empty { path: name() });
    }
    Ok(MonoAudio {
        rate: spec.sample_rate,
        samples,
    })
}

/// Resamples mono audio to `rate` with rubato's FFT resampler (its delay is trimmed).
pub fn resample(audio: &MonoAudio, rate: u32) -> Result<Vec<f32>, WavError> {
    if audio.rate == rate {
        return Ok(audio.samples.clone());
    }
    let err = |e: &dyn std::fmt::Display| WavError::Resample(e.to_string());
    let mut resampler = Fft::<f32>::new(
        audio.rate as usize,
        rate as usize,
        1024,
        1,
        FixedSync::Input,
    )
    .map_err(|e| err(&e))?;
    let input =
        InterleavedSlice::new(&audio.samples, 1, audio.samples.len()).map_err(|e| err(&e))?;
    let out = resampler
        .process_all(&input, audio.samples.len(), None)
        .map_err(|e| err(&e))?;
    Ok(out.take_data())
}

/// Converts float samples to 16-bit PCM with rounding and clipping.
pub fn to_i16(samples: &[f32]) -> Vec<i16> {
    samples
        .iter()
        .map(|&s| (s * 32768.0).round().clamp(-32768.0, 32767.0) as i16)
        .collect()
}

/// Reads any WAV and returns 8 kHz mono 16-bit samples, ready for the narrowband codec.
pub fn read_narrowband(path: &Path) -> Result<Vec<i16>, WavError> {
    let audio = read_mono(path)?;
    Ok(to_i16(&resample(&audio, SAMPLE_RATE)?))
}

/// Writes 16-bit mono PCM.
pub fn write_mono_i16(path: &Path, rate: u32, samples: &[i16]) -> Result<(), WavError> {
    let werr = |e: hound::Error| WavError::Write {
        path: path.display().to_string(),
        reason: e.to_string(),
    };
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: rate,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut writer = hound::WavWriter::create(path, spec).map_err(werr)?;
    let mut w = writer.get_i16_writer(samples.len() as u32);
    for &s in samples {
        w.write_sample(s);
    }
    w.flush().map_err(werr)?;
    writer.finalize().map_err(werr)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sine(rate: u32, freq: f32, seconds: f32) -> Vec<f32> {
        let n = (rate as f32 * seconds) as usize;
        (0..n)
            .map(|i| 0.5 * (2.0 * std::f32::consts::PI * freq * i as f32 / rate as f32).sin())
            .collect()
    }

    #[test]
    fn resampling_keeps_length_and_pitch() {
        let audio = MonoAudio {
            rate: 48_000,
            samples: sine(48_000, 440.0, 1.0),
        };
        let out = resample(&audio, 8000).unwrap();
        assert!((out.len() as i64 - 8000).abs() <= 1, "{}", out.len());
        // Count zero crossings: 440 Hz gives 880 a second.
        let crossings = out
            .windows(2)
            .filter(|w| (w[0] < 0.0) != (w[1] < 0.0))
            .count();
        assert!((crossings as i64 - 880).abs() <= 4, "{crossings}");
    }

    #[test]
    fn stereo_float_wav_is_mixed_down() {
        let dir = std::env::temp_dir().join(format!("lipcall-wav-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("stereo.wav");
        let spec = hound::WavSpec {
            channels: 2,
            sample_rate: 44_100,
            bits_per_sample: 32,
            sample_format: hound::SampleFormat::Float,
        };
        let mut w = hound::WavWriter::create(&path, spec).unwrap();
        for _ in 0..441 {
            w.write_sample(0.5f32).unwrap();
            w.write_sample(-0.25f32).unwrap();
        }
        w.finalize().unwrap();
        let a = read_mono(&path).unwrap();
        assert_eq!(a.rate, 44_100);
        assert_eq!(a.samples.len(), 441);
        assert!(a.samples.iter().all(|&s| (s - 0.125).abs() < 1e-6));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
