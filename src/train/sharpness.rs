//! The output sharpness ([`Model::sharpness`]), tuned after training together with the closure
//! snap on held-out predictions, without retraining: a network trained on coarticulated
//! (blended) targets hedges between shapes and under-opens open vowels; raising its convex
//! weights to a power and renormalising lets the leading shape show more fully.
//!
//! The rule, fixed before any result was seen (docs/model.md): the reference is sharpness 1
//! with today's snap (`closure share - 3 x false closures`). Each candidate sharpness takes the
//! snap with the best value of that rule among those that close at least the reference's share
//! of /p b m/ segments with no more false closures; it qualifies if openness r and rounding r
//! stay within [`R_TOLERANCE`] of the reference's. The qualifying one with the most open-vowel
//! plus rounded segments shown wins, if it beats the reference by [`MIN_GAIN`]; otherwise the
//! reference stays.
//!
//! [`Model::sharpness`]: crate::lipsync::network::Model::sharpness

use std::fmt;

use super::closure_snap::{FALSE_CLOSURE_COST, HeldOutPredictions, best_snap};
use crate::lipsync::mouth::VisemeShapes;
use crate::lipsync::network::sharpen;
use crate::lipsync::phones::CueClass;
use crate::train::error::TrainError;
use crate::train::eval::Scores;

/// How far openness r and rounding r may fall below the reference's.
pub const R_TOLERANCE: f64 = 0.005;
/// The gain in open-vowel share plus rounded share a sharpness must bring to be chosen (on the
/// same predictions as the reference, so no seed spread enters).
pub const MIN_GAIN: f64 = 0.02;

/// Sharpness values tried: 1 to 3 in steps of 0.1.
pub fn sharpness_candidates() -> impl Iterator<Item = f32> {
    (10..=30).map(|tenths| tenths as f32 / 10.0)
}

impl HeldOutPredictions {
    /// The same predictions with the outputs sharpened by `sharpness` in `form` (on top of
    /// the model's own, which is taken to be 1).
    pub fn sharpened(&self, sharpness: f32, form: Form) -> Self {
        let k = self.model.visemes.len();
        let mut out = self.clone();
        out.model.sharpness = sharpness;
        out.model.sharpen_open_shapes_only = form == Form::OpenShapes;
        let spared = out.model.spared_shape();
        for utt in &mut out.unsnapped {
            for weights in utt.chunks_exact_mut(k) {
                sharpen(weights, sharpness, spared);
            }
        }
        out
    }
}

/// Which shapes the sharpness acts on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Form {
    /// All of them: a leading closed shape closes further too.
    AllShapes,
    /// All but the closed one, which keeps its weight (the closures stay the snap's).
    OpenShapes,
}

impl Form {
    pub const ALL: [Form; 2] = [Form::AllShapes, Form::OpenShapes];

    fn label(self) -> &'static str {
        match self {
            Form::AllShapes => "all shapes ",
            Form::OpenShapes => "open shapes",
        }
    }
}

/// One candidate sharpness with its best snap under the closure constraints.
#[derive(Debug, Clone)]
pub struct SharpnessRow {
    pub sharpness: f32,
    pub form: Form,
    /// `None`: no snap closes as many /p b m/ segments with as few false closures as the
    /// reference.
    pub best: Option<(f32, Scores)>,
    /// Where `best` is `None`, what comes closest: the snap that closes the most /p b m/
    /// segments with no more false closures than the reference (for the log).
    pub nearest: Option<(f32, Scores)>,
    /// Openness r and rounding r within [`R_TOLERANCE`] of the reference's.
    pub qualifies: bool,
}

/// What the tuning chose and what it saw.
#[derive(Debug, Clone)]
pub struct Calibration {
    pub sharpness: f32,
    pub form: Form,
    pub closure_snap: f32,
    /// The predictions' scores at the chosen sharpness and snap.
    pub scores: Scores,
    /// The scores at every snap, at the chosen sharpness.
    pub snap_curve: Vec<(f32, Scores)>,
    /// Every candidate (the first is the reference, sharpness 1).
    pub rows: Vec<SharpnessRow>,
}

impl Calibration {
    /// Sets the chosen sharpness on a model.
    pub fn apply(&self, model: &mut crate::lipsync::network::Model) {
        model.sharpness = self.sharpness;
        model.sharpen_open_shapes_only = self.sharpness != 1.0 && self.form == Form::OpenShapes;
    }
}

/// Open-vowel share plus rounded share: what sharpening is for.
pub fn objective(s: &Scores) -> f64 {
    s.cue_share(CueClass::OpenVowel) + s.cue_share(CueClass::Rounded)
}

/// The snap with the best `closure share - FALSE_CLOSURE_COST x false closures` among those of
/// `curve` that close at least `reference`'s share with no more false closures.
fn constrained_snap(curve: &[(f32, Scores)], reference: &Scores) -> Option<(f32, Scores)> {
    let value = |s: &Scores| s.closure_share() - FALSE_CLOSURE_COST * s.false_closure_rate;
    curve
        .iter()
        .filter(|(_, s)| {
            s.closed_segments >= reference.closed_segments
                && s.false_closure_rate <= reference.false_closure_rate
        })
        .fold(None, |best: Option<&(f32, Scores)>, row| match best {
            Some(b) if value(&b.1) >= value(&row.1) - 1e-9 => Some(b),
            _ => Some(row),
        })
        .cloned()
}

/// The snap of `curve` closing the most /p b m/ segments with no more false closures than
/// `reference` (the fewest false closures among equals).
fn most_closures_within(curve: &[(f32, Scores)], reference: &Scores) -> Option<(f32, Scores)> {
    curve
        .iter()
        .filter(|(_, s)| s.false_closure_rate <= reference.false_closure_rate)
        .max_by(|a, b| {
            a.1.closed_segments
                .cmp(&b.1.closed_segments)
                .then(b.1.false_closure_rate.total_cmp(&a.1.false_closure_rate))
        })
        .cloned()
}

/// Tunes the sharpness (both forms) and the closure snap on `predictions` (held out by
/// construction, made at sharpness 1). A fixed `snap` is kept as given; a fixed `sharpness`
/// (all shapes) too, with the snap tuned at it by today's rule.
pub fn calibrate(
    predictions: &HeldOutPredictions,
    snap: Option<f32>,
    sharpness: Option<f32>,
    shapes: &VisemeShapes,
) -> Result<Calibration, TrainError> {
    let curve_of = |p: &HeldOutPredictions| -> Result<Vec<(f32, Scores)>, TrainError> {
        match snap {
            Some(s) => Ok(vec![(s, p.scores(s, shapes)?)]),
            None => p.snap_curve(shapes),
        }
    };
    if let Some(g) = sharpness {
        let sharpened = predictions.sharpened(g, Form::AllShapes);
        let snap_curve = curve_of(&sharpened)?;
        let closure_snap = snap.unwrap_or_else(|| best_snap(&snap_curve));
        return Ok(Calibration {
            sharpness: g,
            form: Form::AllShapes,
            closure_snap,
            scores: sharpened.scores(closure_snap, shapes)?,
            snap_curve,
            rows: Vec::new(),
        });
    }
    let reference_curve = curve_of(predictions)?;
    let reference_snap = snap.unwrap_or_else(|| best_snap(&reference_curve));
    let reference = predictions.scores(reference_snap, shapes)?;
    let mut rows = vec![SharpnessRow {
        sharpness: 1.0,
        form: Form::AllShapes,
        best: Some((reference_snap, reference.clone())),
        nearest: None,
        qualifies: true,
    }];
    let mut chosen: Option<(f32, Form, f32, Scores)> = None;
    for form in Form::ALL {
        for g in sharpness_candidates().filter(|&g| g != 1.0) {
            let curve = curve_of(&predictions.sharpened(g, form))?;
            let (best, nearest) = match constrained_snap(&curve, &reference) {
                Some(best) => (Some(best), None),
                None => (None, most_closures_within(&curve, &reference)),
            };
            let qualifies = best.as_ref().is_some_and(|(_, s)| {
                s.openness_r >= reference.openness_r - R_TOLERANCE
                    && s.rounding_r >= reference.rounding_r - R_TOLERANCE
            });
            if qualifies && let Some((snap, scores)) = &best {
                let better = chosen
                    .as_ref()
                    .is_none_or(|(_, _, _, c)| objective(scores) > objective(c) + 1e-9);
                if better {
                    chosen = Some((g, form, *snap, scores.clone()));
                }
            }
            rows.push(SharpnessRow {
                sharpness: g,
                form,
                best,
                nearest,
                qualifies,
            });
        }
    }
    match chosen {
        Some((g, form, closure_snap, scores))
            if objective(&scores) >= objective(&reference) + MIN_GAIN =>
        {
            Ok(Calibration {
                sharpness: g,
                form,
                closure_snap,
                scores,
                snap_curve: predictions.sharpened(g, form).snap_curve(shapes)?,
                rows,
            })
        }
        _ => Ok(Calibration {
            sharpness: 1.0,
            form: Form::AllShapes,
            closure_snap: reference_snap,
            scores: reference,
            snap_curve: reference_curve,
            rows,
        }),
    }
}

impl fmt::Display for Calibration {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.rows.is_empty() {
            return write!(f, "sharpness {} (fixed)", self.sharpness);
        }
        writeln!(
            f,
            "output sharpness on the pooled folds (each with its best snap that closes as many \
             /p b m/ with no more false closures than sharpness 1):"
        )?;
        for row in &self.rows {
            let (shown, verdict) = match (&row.best, &row.nearest) {
                (Some(best), _) => (Some(best), if row.qualifies { "" } else { "  (r falls)" }),
                (None, nearest) => (nearest.as_ref(), "  (fewer closures: out)"),
            };
            match shown {
                Some((snap, s)) => writeln!(
                    f,
                    "  {} {:.1} snap {snap:.3} closed {:>5.1}% false {:>4.1}% openness r {:.3} \
                     rounding r {:.3} open vowels {:>5.1}% rounded {:>5.1}% /f v/ \
                     {:>5.1}%{verdict}",
                    row.form.label(),
                    row.sharpness,
                    100.0 * s.closure_share(),
                    100.0 * s.false_closure_rate,
                    s.openness_r,
                    s.rounding_r,
                    100.0 * s.cue_share(CueClass::OpenVowel),
                    100.0 * s.cue_share(CueClass::Rounded),
                    100.0 * s.cue_share(CueClass::Labiodental),
                )?,
                None => writeln!(
                    f,
                    "  {} {:.1} no snap has as few false closures",
                    row.form.label(),
                    row.sharpness
                )?,
            }
        }
        write!(
            f,
            "sharpness {} ({}) with closure snap {} (open vowels + rounded must gain {} points)",
            self.sharpness,
            self.form.label().trim(),
            self.closure_snap,
            100.0 * MIN_GAIN
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::train::eval::Scores;

    fn closures(closed: usize, false_rate: f64) -> Scores {
        Scores {
            frames: 100,
            eq1_error: 0.0,
            frame_accuracy: 0.0,
            openness_r: 0.7,
            bilabial_segments: 10,
            closed_segments: closed,
            false_closure_rate: false_rate,
            width_r: 0.5,
            rounding_r: 0.4,
            cue_segments: [10; 3],
            cue_shown: [8; 3],
            false_labiodental_rate: 0.0,
        }
    }

    #[test]
    fn the_snap_must_keep_the_closures_without_more_false_ones() {
        let reference = closures(8, 0.07);
        let curve = vec![
            (0.5, closures(10, 0.12)),
            (0.6, closures(9, 0.07)),
            (0.65, closures(8, 0.05)),
            (0.7, closures(6, 0.03)),
        ];
        // 0.6: 0.9 - 0.21 beats 0.65: 0.8 - 0.15; 0.5 closes more, and more elsewhere.
        assert_eq!(constrained_snap(&curve, &reference).map(|c| c.0), Some(0.6));
        let fewer = [curve[0].clone(), curve[3].clone()];
        assert!(constrained_snap(&fewer, &reference).is_none());
        assert_eq!(
            most_closures_within(&fewer, &reference).map(|c| c.0),
            Some(0.7)
        );
    }

    #[test]
    fn candidates_start_at_the_network_as_trained() {
        let all: Vec<f32> = sharpness_candidates().collect();
        assert_eq!(all.first(), Some(&1.0));
        assert_eq!(all.last(), Some(&3.0));
        assert!(all.windows(2).all(|w| w[1] > w[0]));
    }
}
