//! Viseme targets over time from timed phones, with a Cohen-Massaro style dominance model.
//!
//! Every segment pulls the mouth towards its viseme with a dominance that is `strength` inside
//! the segment and decays as `strength * exp(-d / reach)` at a distance `d` outside it, with its
//! own reach before the segment (anticipation) and after it (carry-over). The target at time t
//! is the dominance-weighted mean of the segments' one-hot visemes, so it is convex by
//! construction and moves smoothly across boundaries.
//!
//! Bilabials get a high strength and a short reach: inside a /p b m/ the closed shape wins
//! clearly (the lips do shut), while its influence on the neighbours fades within ~20 ms. A plain
//! symmetric blend would average every closure with its open neighbours and never close.

use super::phones::PhoneTarget;
use crate::vocab::{FullWeights, VISEME_COUNT, Viseme};

/// Length of a frame, in seconds (one Speex narrowband frame).
pub const FRAME_SECONDS: f64 = 0.02;

/// Points averaged inside each frame `[n*20 ms, n*20 ms + 20 ms)`.
const SAMPLES_PER_FRAME: usize = 4;

/// A phone's target over `[start_s, end_s)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimedTarget {
    pub start_s: f64,
    pub end_s: f64,
    pub target: PhoneTarget,
}

/// How strongly and how far a viseme's segments reach.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dominance {
    pub strength: f64,
    /// Decay length before the segment starts, in seconds.
    pub anticipation_s: f64,
    /// Decay length after the segment ends, in seconds.
    pub carry_over_s: f64,
}

/// The default dominance of each viseme.
pub fn dominance(viseme: Viseme) -> Dominance {
    let (strength, anticipation_s, carry_over_s) = match viseme {
        Viseme::Sil => (0.5, 0.03, 0.03),
        Viseme::PP => (20.0, 0.01, 0.008),
        Viseme::FF => (3.0, 0.02, 0.015),
        // Tongue consonants leave the lips to the vowels around them.
        Viseme::TH | Viseme::DD | Viseme::Kk | Viseme::Nn | Viseme::SS => (0.6, 0.03, 0.03),
        Viseme::CH => (2.0, 0.04, 0.03),
        Viseme::RR => (1.5, 0.04, 0.03),
        Viseme::Aa | Viseme::E | Viseme::I => (1.0, 0.04, 0.05),
        // Rounding is anticipated far ahead.
        Viseme::O | Viseme::U => (1.5, 0.08, 0.05),
    };
    Dominance {
        strength,
        anticipation_s,
        carry_over_s,
    }
}

struct Pull {
    start_s: f64,
    end_s: f64,
    viseme: Viseme,
    dominance: Dominance,
}

impl Pull {
    fn at(&self, t: f64) -> f64 {
        let d = &self.dominance;
        if t < self.start_s {
            d.strength * (-(self.start_s - t) / d.anticipation_s).exp()
        } else if t > self.end_s {
            d.strength * (-(t - self.end_s) / d.carry_over_s).exp()
        } else {
            d.strength
        }
    }
}

fn pulls(segments: &[TimedTarget]) -> Vec<Pull> {
    let mut pulls = Vec::with_capacity(segments.len() + 4);
    let mut push = |start_s, end_s, viseme| {
        pulls.push(Pull {
            start_s,
            end_s,
            viseme,
            dominance: dominance(viseme),
        })
    };
    for seg in segments {
        match seg.target {
            PhoneTarget::Single(v) => push(seg.start_s, seg.end_s, v),
            PhoneTarget::Glide(first, second) => {
                let mid = 0.5 * (seg.start_s + seg.end_s);
                push(seg.start_s, mid, first);
                push(mid, seg.end_s, second);
            }
            PhoneTarget::Transparent => {}
        }
    }
    pulls
}

/// Coarticulated weights over the 15 visemes at one instant.
fn weights_at(pulls: &[Pull], t: f64) -> [f64; VISEME_COUNT] {
    let mut acc = [0.0f64; VISEME_COUNT];
    for pull in pulls {
        acc[pull.viseme.index()] += pull.at(t);
    }
    let total: f64 = acc.iter().sum();
    if total < 1e-12 {
        let mut rest = [0.0; VISEME_COUNT];
        rest[Viseme::Sil.index()] = 1.0;
        return rest;
    }
    acc.map(|a| a / total)
}

/// Target weights for `frame_count` frames of 20 ms, frame n covering `[n*20 ms, n*20 ms + 20 ms)`.
pub fn frame_targets(segments: &[TimedTarget], frame_count: usize) -> Vec<FullWeights> {
    let pulls = pulls(segments);
    (0..frame_count)
        .map(|n| {
            let mut frame = [0.0f64; VISEME_COUNT];
            for k in 0..SAMPLES_PER_FRAME {
                let t = (n as f64 + (k as f64 + 0.5) / SAMPLES_PER_FRAME as f64) * FRAME_SECONDS;
                for (f, w) in frame.iter_mut().zip(weights_at(&pulls, t)) {
                    *f += w / SAMPLES_PER_FRAME as f64;
                }
            }
            frame.map(|w| w as f32)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seg(start_s: f64, end_s: f64, target: PhoneTarget) -> TimedTarget {
        TimedTarget {
            start_s,
            end_s,
            target,
        }
    }

    // "a b a" with silence around: 0.1 s sil, 0.15 s aa, 0.08 s b closure, 0.15 s aa, 0.1 s sil.
    fn aba() -> Vec<TimedTarget> {
        use PhoneTarget::Single;
        vec![
            seg(0.0, 0.1, Single(Viseme::Sil)),
            seg(0.1, 0.25, Single(Viseme::Aa)),
            seg(0.25, 0.33, Single(Viseme::PP)),
            seg(0.33, 0.48, Single(Viseme::Aa)),
            seg(0.48, 0.58, Single(Viseme::Sil)),
        ]
    }

    #[test]
    fn targets_are_convex() {
        for frame in frame_targets(&aba(), 29) {
            assert!(frame.iter().all(|&w| (0.0..=1.0).contains(&w)));
            assert!((frame.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn targets_are_smooth_not_steps() {
        let frames = frame_targets(&aba(), 29);
        let aa = Viseme::Aa.index();
        // The vowel onset after silence is spread over several frames.
        let rising: Vec<f32> = frames[3..8].iter().map(|f| f[aa]).collect();
        assert!(rising.windows(2).all(|w| w[1] >= w[0]));
        assert!(rising.iter().filter(|&&w| w > 0.05 && w < 0.95).count() >= 2);
        for pair in frames.windows(2) {
            let jump = pair[0]
                .iter()
                .zip(&pair[1])
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(jump < 0.8, "jump {jump}");
        }
    }

    #[test]
    fn bilabial_closure_is_reached_between_open_vowels() {
        let frames = frame_targets(&aba(), 29);
        let pp = Viseme::PP.index();
        // Frames 13..16 lie inside the closure (0.26 .. 0.32 s).
        let peak = frames[12..17].iter().map(|f| f[pp]).fold(0.0f32, f32::max);
        assert!(peak > 0.93, "peak closure weight {peak}");
        // Mid-vowel frames are not pulled shut.
        assert!(frames[8][pp] < 0.1 && frames[20][pp] < 0.1);
    }

    #[test]
    fn transparent_phones_borrow_their_neighbours_and_glides_move() {
        use PhoneTarget::{Glide, Single, Transparent};
        let segments = vec![
            seg(0.0, 0.1, Single(Viseme::U)),
            seg(0.1, 0.2, Transparent),
            seg(0.2, 0.4, Glide(Viseme::Aa, Viseme::I)),
        ];
        let frames = frame_targets(&segments, 20);
        let f = &frames[7];
        assert!(f[Viseme::U.index()] + f[Viseme::Aa.index()] > 0.95);
        assert!(frames[11][Viseme::Aa.index()] > 0.7);
        assert!(frames[19][Viseme::I.index()] > 0.8);
        // No segments at all: the rest shape.
        assert_eq!(frame_targets(&[], 1)[0], Viseme::Sil.one_hot());
    }
}
