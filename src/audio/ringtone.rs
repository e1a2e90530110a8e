//! The ringtone of a call that rings: two tones together in bursts (1 s on, 2 s off), made
//! sample by sample in the mixer thread and added to the mix, so it needs no sound file and
//! plays on whatever output the peers play on (the virtual sink included).
//!
//! Switched by an atomic ([`RingSwitch`]): the engine sets it while the call's phase is ringing
//! and the mixer reads it once a piece; nothing locks or allocates.

use std::f32::consts::TAU;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// The two tones (Hz), heard together: the pair of North American ringback.
pub const RING_TONES_HZ: [f32; 2] = [440.0, 480.0];
/// Each tone's peak (of full scale 1.0): together at most -14 dBFS, under a voice's peaks.
pub const RING_LEVEL: f32 = 0.1;
/// A burst's length and the silence after it, in milliseconds.
pub const RING_ON_MS: u64 = 1000;
pub const RING_OFF_MS: u64 = 2000;
/// Each burst fades in and out over this long, so that it starts and stops without a click.
const RAMP_MS: u64 = 10;

/// Turns the ringtone on and off from any thread.
#[derive(Debug, Clone, Default)]
pub struct RingSwitch(Arc<AtomicBool>);

impl RingSwitch {
    pub fn set(&self, ringing: bool) {
        self.0.store(ringing, Ordering::Relaxed);
    }

    pub fn is_on(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}

/// The tone's generator at the mixer's rate: where it stands in the cadence.
#[derive(Debug)]
pub struct Ringtone {
    rate: u32,
    switch: RingSwitch,
    /// Samples since the ringing began, `None` while it does not ring.
    since: Option<u64>,
}

impl Ringtone {
    pub fn new(rate: u32, switch: RingSwitch) -> Self {
        Self {
            rate: rate.max(1),
            switch,
            since: None,
        }
    }

    /// Adds the next `out.len()` samples of the tone to `out` while the switch is on; each
    /// ringing starts with a burst, and stops (a call answered mid-burst) with a fade, not a
    /// click.
    #[inline]
    pub fn add_to(&mut self, out: &mut [f32]) {
        if self.switch.is_on() {
            self.ring(out);
        } else if self.since.is_some() {
            self.fade_out(out);
        }
    }

    // Out of line and cold: inlined into the mixer, the tone's loops changed how its
    // per-peer sum compiled.
    #[cold]
    #[inline(never)]
    fn ring(&mut self, out: &mut [f32]) {
        let start = self.since.unwrap_or(0);
        for (i, o) in out.iter_mut().enumerate() {
            *o += self.sample(start + i as u64);
        }
        self.since = Some(start + out.len() as u64);
    }

    #[cold]
    #[inline(never)]
    fn fade_out(&mut self, out: &mut [f32]) {
        let Some(start) = self.since.take() else {
            return;
        };
        let ramp = ((RAMP_MS * u64::from(self.rate) / 1000).max(1) as usize).min(out.len());
        for (i, o) in out.iter_mut().take(ramp).enumerate() {
            let fade = 1.0 - (i + 1) as f32 / ramp as f32;
            *o += self.sample(start + i as u64) * fade;
        }
    }

    /// The tone's sample `n` of a ringing (bursts with faded edges, silence between).
    fn sample(&self, n: u64) -> f32 {
        let rate = u64::from(self.rate);
        let on = RING_ON_MS * rate / 1000;
        let period = (RING_ON_MS + RING_OFF_MS) * rate / 1000;
        let ramp = (RAMP_MS * rate / 1000).max(1);
        let t = n % period;
        if t >= on {
            return 0.0;
        }
        let envelope = (t.min(on - 1 - t) as f32 / ramp as f32).min(1.0);
        // The phase from the sample count within one second, so it stays exact however long
        // the call rings.
        let secs = (n % rate) as f32 / self.rate as f32;
        let tone: f32 = RING_TONES_HZ.iter().map(|f| (TAU * f * secs).sin()).sum();
        tone * RING_LEVEL * envelope
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The power of `x` at `hz` (Goertzel), per sample.
    fn power_at(x: &[f32], rate: f32, hz: f32) -> f32 {
        let w = TAU * hz / rate;
        let (mut s1, mut s2) = (0.0f32, 0.0f32);
        for &v in x {
            let s = v + 2.0 * w.cos() * s1 - s2;
            s2 = s1;
            s1 = s;
        }
        (s1 * s1 + s2 * s2 - 2.0 * w.cos() * s1 * s2) / (x.len() as f32).powi(2)
    }

    #[test]
    fn rings_in_bursts_of_both_tones_only_while_switched_on() {
        let rate = 48_000;
        let switch = RingSwitch::default();
        let mut tone = Ringtone::new(rate, switch.clone());
        let mut out = vec![0.0f32; rate as usize * 3];
        tone.add_to(&mut out);
        assert!(out.iter().all(|&s| s == 0.0), "silent while off");

        switch.set(true);
        for piece in out.chunks_mut(480) {
            tone.add_to(piece);
        }
        let second = rate as usize;
        let (burst, pause) = (&out[..second], &out[second..]);
        for hz in RING_TONES_HZ {
            assert!(power_at(burst, 48_000.0, hz) > 1e-3, "{hz} Hz in the burst");
        }
        assert!(power_at(burst, 48_000.0, 1000.0) < 1e-6);
        assert!(pause.iter().all(|&s| s == 0.0), "two seconds off");
        let peak = burst.iter().fold(0.0f32, |m, &s| m.max(s.abs()));
        assert!(
            peak <= 2.0 * RING_LEVEL + 1e-6 && peak > RING_LEVEL,
            "{peak}"
        );
        assert!(burst[0].abs() < 1e-3, "fades in");

        // Switched off mid-burst: the tone fades out over the next piece instead of stopping
        // with a click, and is silent after; then on again: the next ringing starts with a burst.
        let mut tone = Ringtone::new(rate, switch.clone());
        let mut ringing = vec![0.0f32; 4800];
        tone.add_to(&mut ringing);
        switch.set(false);
        let mut fading = vec![0.0f32; 480];
        tone.add_to(&mut fading);
        let last = ringing[ringing.len() - 1];
        let loud = |x: &[f32]| x.iter().fold(0.0f32, |m, &s| m.max(s.abs()));
        assert!(loud(&ringing[ringing.len() - 48..]) > 0.05, "mid-burst");
        assert!(
            loud(&fading[..48]) > 0.05,
            "the fade starts at the tone's level"
        );
        assert!(
            (fading[0] - last).abs() < 0.03,
            "{} after {last}: no step",
            fading[0]
        );
        assert!(
            fading[479].abs() < 1e-6 && fading[240].abs() < 0.11,
            "{fading:?}"
        );
        let mut again = vec![0.0f32; 480];
        tone.add_to(&mut again);
        assert!(again.iter().all(|&s| s == 0.0));
        switch.set(true);
        let mut again = vec![0.0f32; 4800];
        tone.add_to(&mut again);
        assert!(power_at(&again, 48_000.0, 440.0) > 1e-3);
    }
}
