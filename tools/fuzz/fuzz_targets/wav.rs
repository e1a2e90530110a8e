//! WAV input as every command reads it (`audio::wav::read_narrowband`: the regular-file check,
//! the header checks, mixing to mono, resampling to 8 kHz), from a scratch file as it takes
//! only a path. No panic, and no more audio comes out than the file's bytes can hold.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lipcall::audio::wav;
use lipcall_fuzz::ScratchFile;

fuzz_target!(|data: &[u8]| {
    let file = ScratchFile::new("wav", data);
    if let Ok(mono) = wav::read_mono(file.path()) {
        assert!(wav::RATES.contains(&mono.rate));
        assert!(mono.samples.len() <= data.len());
    }
    if let Ok(pcm) = wav::read_narrowband(file.path()) {
        let lowest = *wav::RATES.start() as usize;
        // Each input sample takes at least one byte; resampling to 8 kHz at most doubles them
        // (plus the resampler's rounding to whole chunks).
        assert!(pcm.len() <= data.len() * 8000 / lowest + 8192);
    }
});
