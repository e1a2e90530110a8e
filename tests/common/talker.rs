//! A synthetic talker for the drift and playout tests: spurts of a voiced sound with faint
//! noise between them, so a test can tell frames that must be heard from those a playout may
//! drop or stretch.

use lipcall::vocab::FRAME_SIZE;

/// Frame `k` of a talker who sounds for the first `loud` frames of every `period` and is
/// faint noise (-66 dBFS) for the rest; and whether the frame is loud.
pub fn talker(k: usize, loud: usize, period: usize) -> ([i16; FRAME_SIZE], bool) {
    let is_loud = k % period < loud;
    let pcm = std::array::from_fn(|i| {
        let n = k * FRAME_SIZE + i;
        if !is_loud {
            return ((n * 7919 % 31) as i16 - 15) * 2;
        }
        // A pitch gliding between 100 and 140 Hz (its phase, the pitch's integral, in
        // cycles) and 11 harmonics under one formant.
        let t = n as f64 / 8000.0;
        let pitch = 120.0 + 20.0 * (2.0 * t).sin();
        let cycles = 120.0 * t - 10.0 * (2.0 * t).cos();
        let s: f64 = (1..12)
            .map(|h| {
                let f = pitch * f64::from(h);
                (std::f64::consts::TAU * cycles * f64::from(h)).sin()
                    / (1.0 + ((f - 650.0) / 300.0).powi(2))
            })
            .sum();
        (4000.0 * s) as i16
    });
    (pcm, is_loud)
}
