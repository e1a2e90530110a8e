//! A head's drive: articulatory [`Controls`] (lip-sync v4, issue 47) to the weights of this
//! head's own shapes. Each viseme's control signature is what it does on this head: its lip gap
//! and mouth width above the head's rest as [`MouthGauge`] measures them on the head's own
//! geometry (after the loader's calibration, so what its renders show), and the activations
//! (jaw, rounding, closure, lower lip tuck) of the viseme it is
//! ([`crate::lipsync::viseme_controls`]). A frame's weights are the convex combination of the
//! head's visemes (`sil` takes what the others leave, as Eq. 1) whose signatures best reproduce
//! the controls, in least squares with each control in units of how far speakers move it; so a
//! head whose `I` spreads more than a speaker's, or whose `U` barely parts the lips, still
//! shows the speaker's width and gap.
//!
//! The renderer blends 15 viseme slots, so an ARKit head is driven through the visemes its
//! ARKit shapes were combined into at load ([`crate::render::arkit`]), measured the same way.

use super::head::HeadModel;
use super::mouth_gauge::MouthGauge;
use crate::lipsync::controls::{CONTROL_COUNT, Controls};
use crate::lipsync::viseme_controls;
use crate::vocab::{VISEME_COUNT, Viseme, VisemeWeights};

/// The visemes the fit weighs: all but `sil`, the rest pose.
const DRIVEN: usize = VISEME_COUNT - 1;

/// Each control's weight in the fit, per unit: aperture and width over about a speaker's spread
/// at one viseme (s1: 0.03-0.05 and 0.015-0.028 eye widths), the activations as they are, the
/// closure and the tuck a little more (shut lips and /f v/ are what lipreaders look for).
const CONTROL_SCALE: [f32; CONTROL_COUNT] = [1.0 / 0.03, 1.0 / 0.015, 1.0, 1.0, 1.5, 1.5];
/// A little ridge keeps the fit unique where visemes look alike on a head.
const RIDGE: f32 = 1e-3;
/// Projected-gradient steps per frame (accelerated): enough for 14 unknowns to settle to well
/// under a hundredth of a weight (the unit tests check it).
const ITERATIONS: usize = 200;

/// Controls to this head's viseme weights.
#[derive(Debug, Clone, PartialEq)]
pub struct HeadDrive {
    signatures: [[f32; CONTROL_COUNT]; VISEME_COUNT],
    /// The fit's normal equations over the driven visemes: `(S A)^T (S A) + ridge`, and the
    /// scaled signatures `S a_v` that form its right-hand side.
    gram: [[f32; DRIVEN]; DRIVEN],
    scaled: [[f32; CONTROL_COUNT]; DRIVEN],
    step: f32,
}

impl HeadDrive {
    /// Measures the head's visemes; `None` where [`MouthGauge`] cannot measure its mouth.
    pub fn new(head: &HeadModel) -> Option<Self> {
        let gauge = MouthGauge::new(head)?;
        let opening = gauge.visemes(head);
        let rest = opening[0];
        let signatures = std::array::from_fn(|v| {
            let moves = head
                .primitives
                .iter()
                .any(|p| p.targets.get(v).is_some_and(|t| !t.is_empty()));
            if v == 0 || !moves {
                return [0.0; CONTROL_COUNT];
            }
            let mut s = viseme_controls::of(Viseme::ALL[v]);
            s.aperture = opening[v].gap - rest.gap;
            s.width = opening[v].width - rest.width;
            s.to_array()
        });
        Some(Self::from_signatures(signatures))
    }

    /// A drive over given signatures (viseme order; `sil`'s is ignored: it is the rest).
    pub fn from_signatures(signatures: [[f32; CONTROL_COUNT]; VISEME_COUNT]) -> Self {
        let scaled: [[f32; CONTROL_COUNT]; DRIVEN] = std::array::from_fn(|i| {
            std::array::from_fn(|k| {
                let s = signatures[i + 1][k] * CONTROL_SCALE[k];
                if s.is_finite() { s } else { 0.0 }
            })
        });
        let gram: [[f32; DRIVEN]; DRIVEN] = std::array::from_fn(|i| {
            std::array::from_fn(|j| {
                let dot: f32 = (0..CONTROL_COUNT)
                    .map(|k| scaled[i][k] * scaled[j][k])
                    .sum();
                dot + if i == j { RIDGE } else { 0.0 }
            })
        });
        // Gershgorin's bound on the largest eigenvalue: a step that never overshoots.
        let lipschitz = gram
            .iter()
            .map(|row| row.iter().map(|x| x.abs()).sum::<f32>())
            .fold(RIDGE, f32::max);
        Self {
            signatures,
            gram,
            scaled,
            step: 1.0 / lipschitz,
        }
    }

    /// What each viseme does on this head, in [`Controls::to_array`] order.
    pub fn signatures(&self) -> &[[f32; CONTROL_COUNT]; VISEME_COUNT] {
        &self.signatures
    }

    /// The controls this head shows at `weights` by its signatures (linear in the weights).
    pub fn controls_of(&self, weights: &VisemeWeights) -> Controls {
        let mut out = [0.0; CONTROL_COUNT];
        for (sig, &w) in self.signatures.iter().zip(weights.0.iter()).skip(1) {
            for (o, s) in out.iter_mut().zip(sig) {
                *o += w * s;
            }
        }
        Controls::from_array(out)
    }

    /// The head's viseme weights for `controls`: non-negative, summing to one with `sil`, the
    /// least-squares fit of the controls. Non-finite controls count as 0.
    pub fn weights(&self, controls: &Controls) -> VisemeWeights {
        let target = controls
            .to_array()
            .map(|c| if c.is_finite() { c } else { 0.0 });
        let rhs: [f32; DRIVEN] = std::array::from_fn(|i| {
            (0..CONTROL_COUNT)
                .map(|k| self.scaled[i][k] * CONTROL_SCALE[k] * target[k])
                .sum()
        });
        let mut w = [0.0f32; DRIVEN];
        let mut y = w;
        let mut t = 1.0f32;
        for _ in 0..ITERATIONS {
            let mut next = [0.0f32; DRIVEN];
            for (i, n) in next.iter_mut().enumerate() {
                let grad: f32 =
                    self.gram[i].iter().zip(&y).map(|(g, y)| g * y).sum::<f32>() - rhs[i];
                *n = y[i] - self.step * grad;
            }
            let next = project_to_capped_simplex(next);
            let t_next = 0.5 * (1.0 + (1.0 + 4.0 * t * t).sqrt());
            let momentum = (t - 1.0) / t_next;
            for ((y, n), w) in y.iter_mut().zip(&next).zip(&w) {
                *y = n + momentum * (n - w);
            }
            w = next;
            t = t_next;
        }
        let mut out = [0.0; VISEME_COUNT];
        out[1..].copy_from_slice(&w);
        out[0] = (1.0 - w.iter().sum::<f32>()).max(0.0);
        VisemeWeights(out)
    }
}

/// The nearest point with every entry at least 0 and their sum at most 1.
fn project_to_capped_simplex(v: [f32; DRIVEN]) -> [f32; DRIVEN] {
    let clipped = v.map(|x| x.max(0.0));
    if clipped.iter().sum::<f32>() <= 1.0 {
        return clipped;
    }
    // Onto the simplex: subtract the threshold that leaves a sum of one.
    let mut sorted = v;
    sorted.sort_by(|a, b| b.total_cmp(a));
    let mut cumulative = 0.0;
    let mut threshold = 0.0;
    for (k, &x) in sorted.iter().enumerate() {
        cumulative += x;
        let candidate = (cumulative - 1.0) / (k + 1) as f32;
        if x - candidate > 0.0 {
            threshold = candidate;
        }
    }
    v.map(|x| (x - threshold).max(0.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lipsync::viseme_controls::from_full;

    fn s1_drive() -> HeadDrive {
        HeadDrive::from_signatures(std::array::from_fn(|v| {
            viseme_controls::of(Viseme::ALL[v]).to_array()
        }))
    }

    #[test]
    fn a_head_like_the_speaker_shows_the_speakers_controls() {
        // 14 visemes in 6 controls: a viseme may come back as a mix of others that shows the
        // same, so what is checked is what the weights show.
        let drive = s1_drive();
        for v in 1..VISEME_COUNT {
            let wanted = from_full(&VisemeWeights::one_hot(v).0);
            let w = drive.weights(&wanted);
            assert!((w.0.iter().sum::<f32>() - 1.0).abs() < 1e-4);
            let shown = drive.controls_of(&w);
            assert!(
                (shown.aperture - wanted.aperture).abs() < 0.005
                    && (shown.width - wanted.width).abs() < 0.003,
                "{}: {shown:?} vs {wanted:?}",
                Viseme::ALL[v].name()
            );
        }
        let mut mix = [0.0; VISEME_COUNT];
        mix[Viseme::from_name("E").unwrap().index()] = 0.6;
        mix[Viseme::from_name("PP").unwrap().index()] = 0.3;
        mix[0] = 0.1;
        let wanted = from_full(&mix);
        let shown = drive.controls_of(&drive.weights(&wanted));
        // The gap and width closely; the activations, weighed less, within a few hundredths.
        for (k, (a, b)) in shown.to_array().iter().zip(wanted.to_array()).enumerate() {
            let tolerance = if k < 2 { 0.003 } else { 0.03 };
            assert!((a - b).abs() < tolerance, "{shown:?} vs {wanted:?}");
        }
    }

    #[test]
    fn a_wider_head_spreads_less_to_show_the_same_width() {
        // A head whose I spreads three times s1's and opens half as far: it reaches s1's I width
        // with less of its I, and makes up the gap with an opener viseme.
        let mut signatures: [[f32; CONTROL_COUNT]; VISEME_COUNT] =
            std::array::from_fn(|v| viseme_controls::of(Viseme::ALL[v]).to_array());
        let i = Viseme::from_name("I").unwrap().index();
        signatures[i][1] *= 3.0;
        signatures[i][0] *= 0.5;
        let drive = HeadDrive::from_signatures(signatures);
        let wanted = from_full(&VisemeWeights::one_hot(i).0);
        let w = drive.weights(&wanted);
        assert!(w.0[i] < 0.8, "{:?}", w.0);
        let shown = drive.controls_of(&w);
        assert!((shown.width - wanted.width).abs() < 0.004, "{shown:?}");
        assert!((shown.aperture - wanted.aperture).abs() < 0.02, "{shown:?}");
    }

    #[test]
    fn bad_controls_give_the_rest_or_valid_weights() {
        let drive = s1_drive();
        let rest = drive.weights(&Controls::default());
        assert!(rest.0[0] > 0.99, "{:?}", rest.0);
        let wild = Controls {
            aperture: f32::NAN,
            width: 1e6,
            jaw: f32::INFINITY,
            rounding: -5.0,
            closure: 2.0,
            lower_lip_tuck: 0.0,
        };
        let w = drive.weights(&wild);
        assert!(w.0.iter().all(|x| x.is_finite() && *x >= 0.0));
        assert!((w.0.iter().sum::<f32>() - 1.0).abs() < 1e-3);
    }

    #[test]
    fn projection_keeps_the_capped_simplex() {
        let mut v = [0.0; DRIVEN];
        v[0] = 0.9;
        v[1] = 0.6;
        v[2] = -0.4;
        let p = project_to_capped_simplex(v);
        assert!((p.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        assert!((p[0] - 0.65).abs() < 1e-6 && (p[1] - 0.35).abs() < 1e-6 && p[2] == 0.0);
        v[0] = 0.2;
        v[1] = 0.3;
        assert_eq!(project_to_capped_simplex(v)[..2], [0.2, 0.3]);
    }
}
