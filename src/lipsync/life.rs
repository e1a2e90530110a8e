//! The living face: blinks, small eye saccades and head motion driven by the voice, one
//! [`FacePose`] per 20 ms frame, from what a receiver has of that frame (its energy, from the
//! features, and its decoded samples, whose pitch a short autocorrelation finds) and a seeded
//! random generator.
//!
//! - **Blinks** start 2 to 6 s apart (2 to 4.5 s while the voice is on, as people blink more
//!   when they talk), the first within 5 s; each closes fast (50-70 ms), stays shut 30-40 ms and
//!   opens more slowly (80-130 ms).
//! - **Saccades**: every 0.5 to 3 s the eyes jump (in 40 ms) to a new point a few degrees from
//!   ahead, or back to ahead, and hold it.
//! - **Head motion** follows the voice: its level (energy above -55 dB) scales everything, a
//!   rising pitch lifts the chin and tilts the head, an accent (a jump in energy while voiced)
//!   gives a short nod, and a slow wander turns it a little; all through a critically damped
//!   spring (smooth, about 0.3 s), clamped to a few degrees. In silence the level falls to 0 and
//!   the head comes to rest at exactly 0.
//!
//! The mouth is not this module's business: the pose holds no viseme weight, and digital silence
//! leaves the mouth at rest ([`super::receiver::STILL_BELOW_DB`]).
//!
//! Deterministic: the same seed and the same frames give the same poses, in the app and in
//! `lipcall animate --frames`. Per frame the generator allocates nothing (it owns no heap memory
//! at all) and costs one autocorrelation of a voiced frame.

use glam::Vec2;

use crate::vocab::FacePose;
use crate::vocab::FrameFeatures;
use crate::vocab::pose::HEAD_MAX_RAD;
use crate::vocab::{FRAME_SIZE, SAMPLE_RATE};

/// Seconds per frame.
pub const FRAME_S: f32 = FRAME_SIZE as f32 / SAMPLE_RATE as f32;

/// The seed `lipcall animate` uses unless told otherwise.
pub const DEFAULT_SEED: u64 = 1;

/// Blinks start at least this far apart (seconds).
pub const BLINK_INTERVAL_MIN_S: f32 = 2.0;
/// ... and at most this far apart.
pub const BLINK_INTERVAL_MAX_S: f32 = 6.0;
/// The shortest interval's upper end while talking.
const BLINK_INTERVAL_TALKING_MAX_S: f32 = 4.5;
/// The first blink comes within this long of the start.
pub const FIRST_BLINK_MAX_S: f32 = 5.0;
/// Saccades come this far apart (seconds).
pub const SACCADE_INTERVAL_S: (f32, f32) = (0.5, 3.0);
const SACCADE_DURATION_S: f32 = 0.04;
/// Largest gaze offset a saccade aims at, in fractions of the full eye-look shapes (the default
/// head's full look is 20 degrees, so 0.3 is 6 degrees; most jumps are far smaller).
pub const GAZE_MAX: Vec2 = Vec2::new(0.3, 0.18);

const DEG: f32 = std::f32::consts::PI / 180.0;

/// Energy (dB re full scale) where the voice level starts, and the span to full level.
const LEVEL_FLOOR_DB: f32 = -55.0;
const LEVEL_SPAN_DB: f32 = 30.0;
/// The head spring: natural frequency (rad/s), critically damped.
const SPRING_OMEGA: f32 = 2.0 * std::f32::consts::PI * 1.0;
/// Pitch rise (one unit = 5 semitones above the speaker's running mean) to chin lift and tilt.
const PITCH_LIFT_RAD: f32 = 2.0 * DEG;
const PITCH_TILT_RAD: f32 = 1.5 * DEG;
/// Slow wander of each axis at full level (standard deviation, radians).
const WANDER_RAD: [f32; 3] = [1.0 * DEG, 1.8 * DEG, 0.8 * DEG];
const WANDER_TAU_S: f32 = 1.5;
/// An accent's nod: the chin target drops by this at full level and comes back with a 0.15 s
/// time constant, overshooting a little upwards for longer (0.45 s), so that nods add no lasting
/// tilt; through the spring that is a nod of about a degree.
const NOD_RAD: f32 = 3.0 * DEG;
const NOD_TAU_S: f32 = 0.15;
const NOD_RECOVERY_TAU_S: f32 = 0.45;
/// An accent: loudness this far above its slow average, while voiced, at most this often.
const ACCENT_JUMP: f32 = 0.25;
const ACCENT_REFRACTORY_S: f32 = 0.8;
/// Below this the head counts as at rest (radians, radians per second) once the voice is gone.
const REST_ANGLE: f32 = 1e-4;
const REST_SPEED: f32 = 1e-3;

/// PCG32 (O'Neill 2014; XSH-RR output on a 64-bit LCG), exactly the reference
/// `pcg32_random_r` seeded like `pcg32_srandom_r(seed, stream)`: tiny, fast and well known.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pcg32 {
    state: u64,
    inc: u64,
}

impl Pcg32 {
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut rng = Self {
            state: 0,
            inc: (stream << 1) | 1,
        };
        rng.next_u32();
        rng.state = rng.state.wrapping_add(seed);
        rng.next_u32();
        rng
    }

    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        xorshifted.rotate_right((old >> 59) as u32)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit()
    }

    /// Roughly standard normal (the sum of four uniforms, scaled to unit variance).
    pub fn normal(&mut self) -> f32 {
        let sum = self.unit() + self.unit() + self.unit() + self.unit();
        (sum - 2.0) * 3f32.sqrt()
    }
}

/// Shortest pitch lag looked at: 400 Hz at 8 kHz.
const MIN_LAG: usize = 20;
/// Longest: 60 Hz.
const MAX_LAG: usize = 133;
/// Normalised autocorrelation a frame needs to count as voiced.
const VOICED_CORRELATION: f32 = 0.5;

/// The fundamental frequency of 20 ms frames by normalised autocorrelation over the frame and
/// the 133 samples before it (lags 60-400 Hz), the shortest lag near the best one chosen against
/// octave errors. About 18,000 multiply-adds per voiced frame (vectorised); quiet frames stop
/// after 160.
#[derive(Debug, Clone)]
pub struct PitchTracker {
    /// The last `MAX_LAG` samples of the previous frames, then the current frame.
    history: [f32; MAX_LAG + FRAME_SIZE],
}

impl Default for PitchTracker {
    fn default() -> Self {
        Self {
            history: [0.0; MAX_LAG + FRAME_SIZE],
        }
    }
}

impl PitchTracker {
    /// Feeds the next frame (160 samples; anything else is taken as silence) and returns its
    /// pitch in Hz when it is voiced.
    pub fn push(&mut self, pcm: &[i16]) -> Option<f32> {
        self.history.copy_within(FRAME_SIZE.., 0);
        let frame = &mut self.history[MAX_LAG..];
        if pcm.len() == FRAME_SIZE {
            for (dst, &s) in frame.iter_mut().zip(pcm) {
                *dst = f32::from(s);
            }
        } else {
            frame.fill(0.0);
        }
        let h = &self.history;
        let x = &h[MAX_LAG..];
        let e0 = dot(x, x);
        // About -60 dB re full scale: nothing to find.
        if e0 < FRAME_SIZE as f32 * 32.0 * 32.0 {
            return None;
        }
        let mut r = [0.0f32; MAX_LAG + 1];
        // Energy of the lagged window, slid back one sample per lag.
        let start = MAX_LAG - MIN_LAG;
        let mut ey: f32 = h[start..start + FRAME_SIZE].iter().map(|v| v * v).sum();
        let mut best = 0.0f32;
        for (lag, r) in r.iter_mut().enumerate().skip(MIN_LAG) {
            let s = MAX_LAG - lag;
            if lag > MIN_LAG {
                ey += h[s] * h[s] - h[s + FRAME_SIZE] * h[s + FRAME_SIZE];
            }
            let c = dot(x, &h[s..s + FRAME_SIZE]);
            let denom = (e0 * ey.max(0.0)).sqrt();
            *r = if denom > 0.0 { c / denom } else { 0.0 };
            best = best.max(*r);
        }
        if best < VOICED_CORRELATION {
            return None;
        }
        // The first local peak close to the best: a multiple of the period is never preferred.
        let lag = (MIN_LAG..=MAX_LAG)
            .find(|&l| {
                r[l] >= 0.85 * best
                    && (l == MIN_LAG || r[l] >= r[l - 1])
                    && (l == MAX_LAG || r[l] >= r[l + 1])
            })
            .unwrap_or(MIN_LAG);
        // Parabolic refinement between the neighbours.
        let mut exact = lag as f32;
        if lag > MIN_LAG && lag < MAX_LAG {
            let (a, b, c) = (r[lag - 1], r[lag], r[lag + 1]);
            let d = a - 2.0 * b + c;
            if d < 0.0 {
                exact += (0.5 * (a - c) / d).clamp(-0.5, 0.5);
            }
        }
        Some(SAMPLE_RATE as f32 / exact)
    }
}

/// Dot product over eight running sums, which the compiler turns into vector instructions (a
/// single running sum must keep its order and stays scalar).
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    for (ca, cb) in a.chunks_exact(8).zip(b.chunks_exact(8)) {
        for k in 0..8 {
            acc[k] += ca[k] * cb[k];
        }
    }
    let tail: f32 = a
        .chunks_exact(8)
        .remainder()
        .iter()
        .zip(b.chunks_exact(8).remainder())
        .map(|(x, y)| x * y)
        .sum();
    acc.iter().sum::<f32>() + tail
}

/// Per-frame smoothing factor of a one-pole filter with time constant `tau` seconds.
fn smoothing(tau: f32) -> f32 {
    1.0 - (-FRAME_S / tau).exp()
}

/// The eyelid curve of a blink `age` seconds after it started: fast close, a short hold, slower
/// open; `None` once it is over.
fn blink_curve(age: f32, [close, hold, open]: [f32; 3]) -> Option<f32> {
    let ease = |x: f32| {
        let x = x.clamp(0.0, 1.0);
        x * x * (3.0 - 2.0 * x)
    };
    if age < 0.0 {
        None
    } else if age < close {
        Some(ease(age / close))
    } else if age < close + hold {
        Some(1.0)
    } else if age < close + hold + open {
        Some(1.0 - ease((age - close - hold) / open))
    } else {
        None
    }
}

/// One face's life: blinks, saccades and voice-driven head motion, stepped once per 20 ms frame.
#[derive(Debug, Clone)]
pub struct LifeGenerator {
    rng: Pcg32,
    /// Seconds from the current frame to the next blink's start (<= 0: it starts now, that
    /// long ago).
    to_next_blink: f32,
    /// Seconds since the current blink started, and its close/hold/open durations.
    blink: Option<(f32, [f32; 3])>,
    to_next_saccade: f32,
    gaze_from: Vec2,
    gaze_to: Vec2,
    saccade_age: f32,
    pitch: PitchTracker,
    /// Voice level 0..1: fast attack, slower release.
    level: f32,
    /// Loudness averaged over about 0.4 s, for accents.
    level_slow: f32,
    /// The speaker's running mean pitch in semitones above 100 Hz (NaN before the first voiced
    /// frame).
    pitch_mean: f32,
    /// Smoothed pitch above that mean, -1..1 (one unit: 5 semitones).
    pitch_rise: f32,
    since_accent: f32,
    /// The current nod's envelopes (set at the accent, decaying): the drop and the recovery.
    nod: f32,
    nod_recovery: f32,
    tilt_side: f32,
    wander: [f32; 3],
    angle: [f32; 3],
    speed: [f32; 3],
}

// The generator owns no heap memory, so stepping it cannot allocate.
const _: () = assert!(!std::mem::needs_drop::<LifeGenerator>());

impl LifeGenerator {
    /// A generator whose random choices all come from `seed`.
    pub fn new(seed: u64) -> Self {
        let mut rng = Pcg32::new(seed, 0x6c69_6665); // stream "life"
        let to_next_blink = rng.range(0.8, FIRST_BLINK_MAX_S);
        let to_next_saccade = rng.range(SACCADE_INTERVAL_S.0, SACCADE_INTERVAL_S.1);
        Self {
            rng,
            to_next_blink,
            blink: None,
            to_next_saccade,
            gaze_from: Vec2::ZERO,
            gaze_to: Vec2::ZERO,
            saccade_age: SACCADE_DURATION_S,
            pitch: PitchTracker::default(),
            level: 0.0,
            level_slow: 0.0,
            pitch_mean: f32::NAN,
            pitch_rise: 0.0,
            since_accent: ACCENT_REFRACTORY_S,
            nod: 0.0,
            nod_recovery: 0.0,
            tilt_side: 1.0,
            wander: [0.0; 3],
            angle: [0.0; 3],
            speed: [0.0; 3],
        }
    }

    /// Brings the face to rest at once (eyes ahead and open, head still, voice forgotten),
    /// keeping the random sequence and the blink and saccade timers: for a face switched back on.
    pub fn settle(&mut self) {
        self.blink = None;
        self.gaze_from = Vec2::ZERO;
        self.gaze_to = Vec2::ZERO;
        self.saccade_age = SACCADE_DURATION_S;
        self.pitch = PitchTracker::default();
        self.level = 0.0;
        self.level_slow = 0.0;
        self.pitch_rise = 0.0;
        self.nod = 0.0;
        self.nod_recovery = 0.0;
        self.wander = [0.0; 3];
        self.angle = [0.0; 3];
        self.speed = [0.0; 3];
    }

    /// The voice level now, 0 (silence) .. 1.
    pub fn voice_level(&self) -> f32 {
        self.level
    }

    /// [`LifeGenerator::step`] with the energy from the frame's features.
    pub fn step_frame(&mut self, features: &FrameFeatures, pcm: &[i16]) -> FacePose {
        self.step(features.energy_db, pcm)
    }

    /// The pose for the next 20 ms frame, given its energy (dB re full scale, as in the
    /// features) and its decoded samples (160; an empty slice gives no pitch).
    pub fn step(&mut self, energy_db: f32, pcm: &[i16]) -> FacePose {
        let voice = self.voice(energy_db, pcm);
        let blink = self.blink();
        let gaze = self.gaze();
        self.head(voice);
        FacePose {
            blink,
            gaze,
            pitch: self.angle[0],
            yaw: self.angle[1],
            roll: self.angle[2],
        }
    }

    fn blink(&mut self) -> f32 {
        if self.blink.is_none() && self.to_next_blink <= 0.0 {
            let shape = [
                self.rng.range(0.05, 0.07),
                self.rng.range(0.03, 0.04),
                self.rng.range(0.08, 0.13),
            ];
            self.blink = Some((-self.to_next_blink, shape));
            let most = if self.level > 0.3 {
                BLINK_INTERVAL_TALKING_MAX_S
            } else {
                BLINK_INTERVAL_MAX_S
            };
            self.to_next_blink += self.rng.range(BLINK_INTERVAL_MIN_S, most);
        }
        self.to_next_blink -= FRAME_S;
        let Some((age, shape)) = self.blink else {
            return 0.0;
        };
        match blink_curve(age, shape) {
            Some(v) => {
                self.blink = Some((age + FRAME_S, shape));
                v
            }
            None => {
                self.blink = None;
                0.0
            }
        }
    }

    fn gaze(&mut self) -> Vec2 {
        if self.to_next_saccade <= 0.0 {
            self.gaze_from = self.gaze_now();
            self.gaze_to = if self.rng.unit() < 0.4 {
                // Back to ahead, give or take a little.
                Vec2::new(0.03 * self.rng.normal(), 0.02 * self.rng.normal())
            } else {
                Vec2::new(0.12 * self.rng.normal(), 0.07 * self.rng.normal())
            }
            .clamp(-GAZE_MAX, GAZE_MAX);
            self.saccade_age = -self.to_next_saccade;
            self.to_next_saccade += self.rng.range(SACCADE_INTERVAL_S.0, SACCADE_INTERVAL_S.1);
        }
        self.to_next_saccade -= FRAME_S;
        let gaze = self.gaze_now();
        self.saccade_age += FRAME_S;
        gaze
    }

    fn gaze_now(&self) -> Vec2 {
        if self.saccade_age >= SACCADE_DURATION_S {
            return self.gaze_to;
        }
        let x = (self.saccade_age / SACCADE_DURATION_S).clamp(0.0, 1.0);
        self.gaze_from.lerp(self.gaze_to, x * x * (3.0 - 2.0 * x))
    }

    /// Updates the voice level, the pitch rise and the accents; returns whether this frame
    /// has an accent.
    fn voice(&mut self, energy_db: f32, pcm: &[i16]) -> bool {
        let loud = if energy_db.is_finite() {
            ((energy_db - LEVEL_FLOOR_DB) / LEVEL_SPAN_DB).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let tau = if loud > self.level { 0.08 } else { 0.4 };
        self.level += (loud - self.level) * smoothing(tau);
        self.level_slow += (loud - self.level_slow) * smoothing(0.4);
        if loud == 0.0 && self.level < 1e-3 {
            self.level = 0.0;
        }
        if loud == 0.0 && self.level_slow < 1e-3 {
            self.level_slow = 0.0;
        }
        let f0 = self.pitch.push(pcm).filter(|_| loud > 0.0);
        match f0 {
            Some(f0) => {
                let semitones = 12.0 * (f0 / 100.0).log2();
                if self.pitch_mean.is_nan() {
                    self.pitch_mean = semitones;
                } else {
                    self.pitch_mean += (semitones - self.pitch_mean) * smoothing(1.5);
                }
                let rise = ((semitones - self.pitch_mean) / 5.0).clamp(-1.0, 1.0);
                self.pitch_rise += (rise - self.pitch_rise) * smoothing(0.12);
            }
            None => self.pitch_rise -= self.pitch_rise * smoothing(0.3),
        }
        self.since_accent += FRAME_S;
        let accent = f0.is_some()
            && loud - self.level_slow > ACCENT_JUMP
            && self.since_accent >= ACCENT_REFRACTORY_S;
        if accent {
            self.since_accent = 0.0;
        }
        accent
    }

    fn head(&mut self, accent: bool) {
        // The wander runs in silence too, so the random sequence does not depend on the voice.
        let drift = (2.0 * FRAME_S / WANDER_TAU_S).sqrt();
        for w in &mut self.wander {
            *w += -*w * FRAME_S / WANDER_TAU_S + drift * self.rng.normal();
        }
        self.nod -= self.nod * smoothing(NOD_TAU_S);
        self.nod_recovery -= self.nod_recovery * smoothing(NOD_RECOVERY_TAU_S);
        if self.nod_recovery < 1e-3 {
            self.nod = 0.0;
            self.nod_recovery = 0.0;
        }
        if accent {
            let strength = self.rng.range(0.6, 1.0);
            self.nod += strength;
            self.nod_recovery += strength;
            self.tilt_side = if self.rng.unit() < 0.5 { -1.0 } else { 1.0 };
        }
        // Drop minus recovery: equal areas, so a nod leaves no lasting tilt.
        let nod = self.nod - (NOD_TAU_S / NOD_RECOVERY_TAU_S) * self.nod_recovery;
        let level = self.level;
        let target = [
            level
                * (NOD_RAD * nod - PITCH_LIFT_RAD * self.pitch_rise
                    + WANDER_RAD[0] * self.wander[0]),
            level * WANDER_RAD[1] * self.wander[1],
            level
                * (PITCH_TILT_RAD * self.tilt_side * self.pitch_rise
                    + WANDER_RAD[2] * self.wander[2]),
        ];
        let w2 = SPRING_OMEGA * SPRING_OMEGA;
        for i in 0..3 {
            let a = w2 * (target[i] - self.angle[i]) - 2.0 * SPRING_OMEGA * self.speed[i];
            self.speed[i] += a * FRAME_S;
            self.angle[i] += self.speed[i] * FRAME_S;
            let max = HEAD_MAX_RAD[i];
            if self.angle[i].abs() > max {
                self.angle[i] = self.angle[i].clamp(-max, max);
                self.speed[i] = 0.0;
            }
            if level == 0.0 && self.angle[i].abs() < REST_ANGLE && self.speed[i].abs() < REST_SPEED
            {
                self.angle[i] = 0.0;
                self.speed[i] = 0.0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SILENCE: [i16; FRAME_SIZE] = [0; FRAME_SIZE];

    /// A voiced frame: a buzz at `f0` Hz (a few harmonics) of the given level, continuing the
    /// phase from frame `n`.
    fn buzz(n: usize, f0: f32, amplitude: f32) -> [i16; FRAME_SIZE] {
        std::array::from_fn(|i| {
            let t = (n * FRAME_SIZE + i) as f32 / SAMPLE_RATE as f32;
            let p = 2.0 * std::f32::consts::PI * f0 * t;
            let v = p.sin() + 0.5 * (2.0 * p).sin() + 0.3 * (3.0 * p).sin();
            (amplitude * v / 1.8) as i16
        })
    }

    fn energy(pcm: &[i16]) -> f32 {
        crate::vocab::energy_db(pcm)
    }

    /// Talking: syllables of ~200 ms with rising and falling pitch, short pauses between words.
    fn speech_frame(n: usize) -> [i16; FRAME_SIZE] {
        let syllable = n % 12;
        if n % 60 >= 50 || syllable >= 10 {
            return SILENCE;
        }
        let f0 = 110.0 + 30.0 * ((n as f32) * 0.07).sin() + 4.0 * syllable as f32;
        let amp = 3000.0 + 5000.0 * (syllable as f32 / 10.0 * std::f32::consts::PI).sin();
        buzz(n, f0, amp)
    }

    fn run(
        life: &mut LifeGenerator,
        frames: usize,
        frame: impl Fn(usize) -> [i16; FRAME_SIZE],
    ) -> Vec<FacePose> {
        (0..frames)
            .map(|n| {
                let pcm = frame(n);
                life.step(energy(&pcm), &pcm)
            })
            .collect()
    }

    /// Start times (seconds) of the blinks in a pose sequence.
    fn blink_starts(poses: &[FacePose]) -> Vec<f32> {
        let mut starts = Vec::new();
        let mut prev = 0.0;
        for (n, p) in poses.iter().enumerate() {
            if p.blink > 0.0 && prev == 0.0 {
                starts.push(n as f32 * FRAME_S);
            }
            prev = p.blink;
        }
        starts
    }

    #[test]
    fn pcg32_matches_the_reference_generator() {
        // pcg32-global-demo / pcg_basic: pcg32_srandom_r(&rng, 42u, 54u).
        let mut rng = Pcg32::new(42, 54);
        let first: Vec<u32> = (0..6).map(|_| rng.next_u32()).collect();
        assert_eq!(
            first,
            [
                0xa15c02b7, 0x7b47f409, 0xba1d3330, 0x83d2f293, 0xbfa4784b, 0xcbed606e
            ]
        );
    }

    #[test]
    fn the_pitch_tracker_finds_the_fundamental_and_ignores_noise() {
        for f0 in [85.0f32, 120.0, 210.0, 330.0] {
            let mut tracker = PitchTracker::default();
            let mut found = None;
            for n in 0..4 {
                found = tracker.push(&buzz(n, f0, 8000.0));
            }
            let found = found.expect("voiced");
            assert!((found / f0 - 1.0).abs() < 0.03, "{f0} Hz read as {found}");
        }
        let mut tracker = PitchTracker::default();
        let mut rng = Pcg32::new(7, 7);
        for _ in 0..6 {
            let noise: [i16; FRAME_SIZE] = std::array::from_fn(|_| (rng.normal() * 4000.0) as i16);
            assert_eq!(tracker.push(&noise), None);
        }
        assert_eq!(tracker.push(&SILENCE), None);
        assert_eq!(tracker.push(&[]), None);
    }

    #[test]
    fn the_same_seed_gives_the_same_face_and_another_seed_another() {
        let poses = |seed| run(&mut LifeGenerator::new(seed), 1500, speech_frame);
        assert_eq!(poses(3), poses(3));
        assert_ne!(poses(3), poses(4));
    }

    #[test]
    fn blinks_come_every_two_to_six_seconds_and_last_about_200_ms() {
        for seed in 0..4 {
            let mut life = LifeGenerator::new(seed);
            // Four minutes: talking, then silence, then talking again.
            let poses = run(&mut life, 12_000, |n| {
                if (4_000..8_000).contains(&n) {
                    SILENCE
                } else {
                    speech_frame(n)
                }
            });
            let starts = blink_starts(&poses);
            assert!(
                starts[0] <= FIRST_BLINK_MAX_S,
                "first blink at {}",
                starts[0]
            );
            assert!(
                starts.len() >= 240 / 6,
                "{} blinks in 4 minutes",
                starts.len()
            );
            for pair in starts.windows(2) {
                let gap = pair[1] - pair[0];
                assert!(
                    (BLINK_INTERVAL_MIN_S - FRAME_S..=BLINK_INTERVAL_MAX_S + FRAME_S)
                        .contains(&gap),
                    "seed {seed}: blinks {gap} s apart at {}",
                    pair[0]
                );
            }
            let mut n = 0;
            while n < poses.len() {
                if poses[n].blink > 0.0 {
                    let len = poses[n..].iter().take_while(|p| p.blink > 0.0).count();
                    let secs = len as f32 * FRAME_S;
                    assert!((0.14..=0.26).contains(&secs), "a blink of {secs} s");
                    let peak = poses[n..n + len]
                        .iter()
                        .map(|p| p.blink)
                        .fold(0.0, f32::max);
                    assert!(peak > 0.99, "a blink that does not shut: {peak}");
                    // Fast close, slower open.
                    let to_peak = poses[n..].iter().position(|p| p.blink == peak).unwrap();
                    assert!(to_peak * 2 < len, "closing {to_peak} of {len} frames");
                    n += len;
                }
                n += 1;
            }
        }
    }

    #[test]
    fn the_eyes_jump_a_few_degrees_and_hold() {
        let poses = run(&mut LifeGenerator::new(5), 3000, |_| SILENCE);
        let mut jumps = 0;
        let mut held = 0;
        for pair in poses.windows(2) {
            let step = (pair[1].gaze - pair[0].gaze).length();
            if step > 1e-6 {
                jumps += 1;
            } else {
                held += 1;
            }
        }
        for p in &poses {
            assert!(p.gaze.abs().cmple(GAZE_MAX).all(), "{:?}", p.gaze);
        }
        // 60 s: one saccade every 0.5-3 s, each two or three frames of motion.
        assert!((20 * 2..=120 * 3).contains(&jumps), "{jumps} moving frames");
        assert!(held > 2500, "{held} held frames");
        let moved = poses.iter().filter(|p| p.gaze.length() > 0.02).count();
        assert!(moved > 300, "the eyes hardly leave the centre");
    }

    #[test]
    fn silence_brings_the_head_to_rest_and_keeps_it_there() {
        // Digital silence from the start: not the least motion, ever.
        let mut life = LifeGenerator::new(9);
        for pose in run(&mut life, 2000, |_| SILENCE) {
            assert!(pose.head_is_still(), "{pose:?}");
        }
        // Talking, then silence: the head comes to rest within 5 s and stays there.
        let mut life = LifeGenerator::new(9);
        let talk = run(&mut life, 500, speech_frame);
        assert!(talk.iter().any(|p| !p.head_is_still()));
        let quiet = run(&mut life, 1000, |_| SILENCE);
        let rest = quiet.iter().position(|p| p.head_is_still()).unwrap();
        assert!(rest * 20 <= 5000, "still after {} ms", rest * 20);
        assert!(quiet[rest..].iter().all(FacePose::head_is_still));
        // The angles only shrink on the way there (no new motion).
        let size = |p: &FacePose| p.pitch.abs() + p.yaw.abs() + p.roll.abs();
        assert!(size(&quiet[50]) < 0.5 * size(&quiet[0]).max(1e-3));
        // Eyes keep living in silence.
        assert!(quiet.iter().any(|p| p.blink > 0.5));
    }

    #[test]
    fn talking_nods_and_tilts_the_head_smoothly_within_a_few_degrees() {
        let poses = run(&mut LifeGenerator::new(2), 3000, speech_frame);
        let angles = |p: &FacePose| [p.pitch, p.yaw, p.roll];
        for (axis, &limit) in HEAD_MAX_RAD.iter().enumerate() {
            let values: Vec<f32> = poses.iter().map(|p| angles(p)[axis]).collect();
            let max = values.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            assert!(max <= limit + 1e-6, "axis {axis}: {max}");
            assert!(
                max > 0.5 * DEG,
                "axis {axis} hardly moves: {} deg",
                max / DEG
            );
            let mean = values.iter().sum::<f32>() / values.len() as f32;
            let spread =
                values.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / values.len() as f32;
            assert!(
                spread.sqrt() > 0.2 * DEG,
                "axis {axis}: sd {} deg",
                spread.sqrt() / DEG
            );
            // Smooth: no jump of more than a third of a degree between frames.
            for pair in values.windows(2) {
                assert!((pair[1] - pair[0]).abs() < DEG / 3.0, "{pair:?}");
            }
        }
        // Louder, more varied speech moves the head more than quiet speech.
        let quiet = run(&mut LifeGenerator::new(2), 3000, |n| {
            let mut f = speech_frame(n);
            f.iter_mut().for_each(|s| *s /= 20);
            f
        });
        let motion = |poses: &[FacePose]| {
            poses
                .iter()
                .map(|p| p.pitch.abs() + p.yaw.abs() + p.roll.abs())
                .sum::<f32>()
        };
        assert!(motion(&quiet) < 0.5 * motion(&poses));
    }

    #[test]
    fn a_rising_pitch_lifts_the_chin_and_a_falling_one_lowers_it() {
        // The same loudness (so the same accents and random draws), three melodies: steady
        // for a second, then a glide up, none, or down by four semitones.
        let melody = |glide: f32| {
            let mut life = LifeGenerator::new(11);
            let mut phase = 0.0f32;
            let poses: Vec<FacePose> = (0..100)
                .map(|n| {
                    let rise = (n as f32 - 50.0).max(0.0) / 50.0;
                    let f0 = 120.0 * 2f32.powf(glide * rise * 4.0 / 12.0);
                    let pcm: [i16; FRAME_SIZE] = std::array::from_fn(|_| {
                        phase += std::f32::consts::TAU * f0 / SAMPLE_RATE as f32;
                        (5000.0 * (phase.sin() + 0.5 * (2.0 * phase).sin())) as i16
                    });
                    life.step(-25.0, &pcm)
                })
                .collect();
            poses[80..].iter().map(|p| p.pitch).sum::<f32>() / 20.0
        };
        let (up, level, down) = (melody(1.0), melody(0.0), melody(-1.0));
        assert!(
            up + 0.3 * DEG < level && level + 0.3 * DEG < down,
            "chin: {} (up), {} (level), {} (down) degrees",
            up / DEG,
            level / DEG,
            down / DEG
        );
    }

    #[test]
    fn a_settled_face_is_at_rest() {
        let mut life = LifeGenerator::new(1);
        run(&mut life, 400, speech_frame);
        life.settle();
        assert_eq!(life.voice_level(), 0.0);
        let pose = life.step(-100.0, &SILENCE);
        assert!(pose.head_is_still(), "{pose:?}");
    }
}
