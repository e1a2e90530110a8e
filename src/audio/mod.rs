//! Audio in and out: WAV files (any rate, resampled to 8 kHz mono).

pub mod wav;
