//! Controls from viseme weights: until the network outputs [`Controls`] itself (issue 47), a
//! frame's controls are its weights' mix of each viseme's controls, taken from GRID speaker s1's
//! measured lips per viseme, so that heads are driven by controls today and the switch to the
//! network's own is one line in the pipeline.

use super::controls::Controls;
use super::mouth::Articulation;
use crate::vocab::{VISEME_COUNT, Viseme, VisemeWeights};

/// s1's mean inner-lip gap and mouth width at each viseme's phone centres, above his rest, in
/// eye widths (`lipcall decompose --grid ../shared/data/grid --viseme-lips FILE`, the table in
/// docs/model.md, "s1's lips per viseme"), in viseme order; `sil` is his rest. The means, not
/// the clearest quarter: a frame's weights mix visemes as his coarticulated frames do.
#[rustfmt::skip]
const S1_APERTURE_WIDTH: [(f32, f32); VISEME_COUNT] = [
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

/// One viseme's controls: aperture and width as s1's lips show it; the jaw and rounding from the
/// design table (src/lipsync/mouth.rs: s1's tracked depth does not tell rounding, docs/model.md);
/// closure for /p b m/ and the lower lip's tuck for /f v/.
pub fn viseme_controls(viseme: Viseme) -> Controls {
    let (aperture, width) = S1_APERTURE_WIDTH[viseme.index()];
    let articulation = Articulation::of(viseme);
    let is = |name: &str| f32::from(u8::from(viseme.name() == name));
    Controls {
        aperture,
        width,
        jaw: if viseme.name() == "sil" {
            0.0
        } else {
            articulation.jaw
        },
        rounding: articulation.protrusion,
        closure: is("PP"),
        lower_lip_tuck: is("FF"),
    }
}

/// A frame's controls: its weights' mix of the visemes' (non-finite weights count as 0).
pub fn controls_of_visemes(weights: &VisemeWeights) -> Controls {
    let mut out = [0.0; crate::lipsync::controls::CONTROL_COUNT];
    for (viseme, &w) in Viseme::ALL.iter().zip(weights.0.iter()) {
        if !w.is_finite() || w == 0.0 {
            continue;
        }
        for (o, c) in out.iter_mut().zip(viseme_controls(*viseme).to_array()) {
            *o += w * c;
        }
    }
    Controls::from_array(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rest_is_no_control_and_each_viseme_is_its_own() {
        assert_eq!(
            controls_of_visemes(&VisemeWeights::neutral()),
            Controls::default()
        );
        let e = controls_of_visemes(&VisemeWeights::single("E").unwrap());
        assert_eq!(e.aperture, 0.109);
        assert!(e.width > 0.0 && e.rounding == 0.0);
        let u = controls_of_visemes(&VisemeWeights::single("U").unwrap());
        assert!(u.width < 0.0 && u.rounding == 1.0);
        assert_eq!(
            controls_of_visemes(&VisemeWeights::single("PP").unwrap()).closure,
            1.0
        );
        assert_eq!(
            controls_of_visemes(&VisemeWeights::single("FF").unwrap()).lower_lip_tuck,
            1.0
        );
    }

    #[test]
    fn a_mix_is_the_mix_of_its_visemes() {
        let mut w = VisemeWeights::neutral();
        w.0 = [0.0; VISEME_COUNT];
        w.0[Viseme::from_name("aa").unwrap().index()] = 0.5;
        w.0[Viseme::from_name("U").unwrap().index()] = 0.5;
        w.0[0] = f32::NAN;
        let c = controls_of_visemes(&w);
        assert!((c.aperture - 0.5 * (0.085 + 0.025)).abs() < 1e-6);
        assert!((c.rounding - 0.5).abs() < 1e-6);
    }
}
