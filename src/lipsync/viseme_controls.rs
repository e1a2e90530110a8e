//! Each viseme as [`Controls`], and back: the per-viseme control vectors that teach the network
//! from phones, show a viseme network's weights as controls, and turn a control network's output
//! into a head's viseme weights by the paper's decomposition (Eq. 1, in control space).
//!
//! Aperture and width are s1's measured lips at each viseme's phone centres (the means of
//! `decompose --viseme-lips`, docs/model.md "s1's lips per viseme"; eye widths above his rest),
//! jaw follows the aperture ([`jaw_from_aperture`]); rounding is the design table's protrusion,
//! closure belongs to /p b m/ and the lower lip's tuck to /f v/.

use super::controls::{CONTROL_COUNT, Controls};
use super::decompose::{DecomposeError, Decomposer};
use super::mouth::{Articulation, VisemeShapes};
use crate::vocab::{FullWeights, VISEME_COUNT, Viseme, VisemeSet};

/// s1's mean (aperture, width) above his rest at each viseme's phone centres, in
/// [`Viseme::ALL`] order (silence is the rest itself).
#[rustfmt::skip]
const S1_LIPS: [(f32, f32); VISEME_COUNT] = [
    (0.0, 0.0),       // sil
    (-0.003, -0.011), // PP
    (0.026, -0.003),  // FF
    (0.008, -0.014),  // TH
    (0.066, 0.0),     // DD
    (0.072, 0.0),     // kk
    (0.096, -0.003),  // CH
    (0.070, 0.003),   // SS
    (0.054, -0.001),  // nn
    (0.020, -0.017),  // RR
    (0.085, -0.006),  // aa
    (0.109, 0.010),   // E
    (0.089, 0.007),   // I
    (0.040, -0.028),  // O
    (0.025, -0.024),  // U
];

/// The aperture (eye widths above rest) at which the jaw counts as fully open: about s1's
/// clearest open vowels (0.13-0.14).
pub const FULL_JAW_APERTURE: f32 = 0.14;

/// How far each control typically moves in speech (the spread of the phone-derived targets over
/// TIMIT's six standard training speakers, rounded): the unit each control's error is measured
/// in, in the decomposition as in training.
pub const CONTROL_SPREAD: [f32; CONTROL_COUNT] = [0.028, 0.008, 0.2, 0.23, 0.24, 0.14];

/// The jaw activation a lip aperture shows (0 at rest or closed, 1 at [`FULL_JAW_APERTURE`]).
pub fn jaw_from_aperture(aperture: f32) -> f32 {
    if aperture.is_finite() {
        (aperture / FULL_JAW_APERTURE).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// One viseme's controls.
pub fn of(viseme: Viseme) -> Controls {
    let (aperture, width) = S1_LIPS[viseme.index()];
    Controls {
        aperture,
        width,
        jaw: jaw_from_aperture(aperture),
        rounding: Articulation::of(viseme).protrusion,
        closure: if viseme == Viseme::PP { 1.0 } else { 0.0 },
        lower_lip_tuck: if viseme == Viseme::FF { 1.0 } else { 0.0 },
    }
}

/// The controls of a blend over all 15 visemes (the weighted sum of theirs).
pub fn from_full(weights: &FullWeights) -> Controls {
    from_weights(&VisemeSet::full(), weights)
}

/// The controls of convex `weights` over `set`.
pub fn from_weights(set: &VisemeSet, weights: &[f32]) -> Controls {
    let mut sum = [0.0f32; CONTROL_COUNT];
    for (&viseme, &w) in set.members().iter().zip(weights) {
        for (s, c) in sum.iter_mut().zip(of(viseme).to_array()) {
            *s += w * c;
        }
    }
    Controls::from_array(sum)
}

/// Points of two coordinates: the decomposer's shapes hold the six controls as three points.
const POINT_DIM: usize = 2;

/// Convex weights over a viseme set whose controls best reproduce a frame's controls (each
/// control's error in units of its [`CONTROL_SPREAD`]), warm-started from the previous frame's.
#[derive(Debug, Clone)]
pub struct ControlDecomposer {
    decomposer: Decomposer,
}

impl ControlDecomposer {
    pub fn new(set: &VisemeSet) -> Result<Self, DecomposeError> {
        let shapes = VisemeShapes::new(
            POINT_DIM,
            Viseme::ALL
                .iter()
                .map(|&v| (v, scaled(&of(v)).to_vec()))
                .collect(),
        )
        .map_err(DecomposeError::from)?;
        let sigmas = [1.0; CONTROL_COUNT / POINT_DIM];
        Ok(Self {
            decomposer: Decomposer::new(&shapes, set, &sigmas)?,
        })
    }

    /// Improves `weights` (the previous frame's; convex) until their controls fit `controls`.
    pub fn fit(&self, controls: &Controls, weights: &mut [f32]) {
        self.decomposer.fit(&scaled(controls), weights);
    }
}

fn scaled(controls: &Controls) -> [f32; CONTROL_COUNT] {
    let mut values = controls.to_array();
    for (v, s) in values.iter_mut().zip(CONTROL_SPREAD) {
        *v /= s;
    }
    values
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn visemes_move_the_controls_a_phonetician_expects() {
        let [pp, ff, aa, i, u] = [Viseme::PP, Viseme::FF, Viseme::Aa, Viseme::I, Viseme::U].map(of);
        assert_eq!(pp.closure, 1.0);
        assert_eq!(ff.lower_lip_tuck, 1.0);
        assert!(aa.aperture > 0.08 && aa.jaw > 0.5 && pp.jaw == 0.0);
        assert!(u.rounding > 0.9 && u.width < i.width && i.width > 0.0);
        assert_eq!(of(Viseme::Sil), Controls::default());
        assert_eq!(jaw_from_aperture(f32::NAN), 0.0);
        assert_eq!(jaw_from_aperture(1.0), 1.0);
    }

    #[test]
    fn a_blends_controls_are_the_blend_of_its_visemes() {
        let mut w = [0.0; VISEME_COUNT];
        w[Viseme::Aa.index()] = 0.25;
        w[Viseme::U.index()] = 0.75;
        let c = from_full(&w);
        let (aa, u) = (of(Viseme::Aa), of(Viseme::U));
        assert!((c.aperture - (0.25 * aa.aperture + 0.75 * u.aperture)).abs() < 1e-6);
        assert!((c.rounding - 0.75 * u.rounding).abs() < 1e-6);
    }

    #[test]
    fn decomposition_recovers_the_visemes_behind_controls() {
        let set = VisemeSet::parse("PP,FF,aa,I,U").unwrap();
        let decomposer = ControlDecomposer::new(&set).unwrap();
        let truth = [0.0, 0.0, 0.6, 0.0, 0.4];
        let controls = from_weights(&set, &truth);
        let mut weights = vec![0.2; 5];
        decomposer.fit(&controls, &mut weights);
        for (w, t) in weights.iter().zip(truth) {
            assert!((w - t).abs() < 0.02, "{weights:?}");
        }
        // A closure is PP, however it was reached; junk gives convex weights, not a panic.
        decomposer.fit(&of(Viseme::PP), &mut weights);
        assert!(weights[0] > 0.95, "{weights:?}");
        decomposer.fit(
            &Controls::from_array([f32::NAN; CONTROL_COUNT]),
            &mut weights,
        );
        assert!((weights.iter().sum::<f32>() - 1.0).abs() < 1e-4);
    }
}
