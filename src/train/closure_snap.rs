//! The closure snap, tuned after training: predictions on held-out speakers before the snap,
//! scored at every candidate threshold.

use super::dataset::Dataset;
use crate::lipsync::controls::{CONTROL_COUNT, Controls};
use crate::lipsync::mouth::VisemeShapes;
use crate::lipsync::network::{MIN_CLOSURE_SNAP, Model};
use crate::lipsync::viseme_controls::ControlDecomposer;
use crate::train::corpus::PreparedUtterance;
use crate::train::error::TrainError;
use crate::train::eval::{Scores, score};

/// How much a false-closure share costs against the closure share when the closure-snap
/// threshold is chosen: a closure elsewhere is a wrong cue, but a few frames of them (silences
/// within words, /f v/) are a smaller harm than missing the /p b m/ cue.
pub const FALSE_CLOSURE_COST: f64 = 3.0;

/// Closure-snap thresholds tried: 0 (off) and [`MIN_CLOSURE_SNAP`] to 0.95 in steps of 0.025
/// (with five or more shapes the closed one can lead well below 0.5).
pub fn snap_candidates() -> impl Iterator<Item = f32> {
    // In 40ths, so the thresholds print as the decimals they are.
    let first = (MIN_CLOSURE_SNAP * 40.0).round() as usize;
    std::iter::once(0.0).chain((first..=38).map(|step| step as f32 / 40.0))
}

/// Predictions on held-out utterances before the closure snap: the network runs once and
/// every threshold is scored on the same outputs (the snap changes no state).
#[derive(Debug, Clone)]
pub struct HeldOutPredictions {
    /// Decides the viseme set and the closed shape the snap drives.
    pub(super) model: Model,
    pub(super) utterances: Vec<PreparedUtterance>,
    pub(super) unsnapped: Vec<Vec<f32>>,
}

impl HeldOutPredictions {
    /// `model` on `utterances`.
    pub fn new(model: &Model, utterances: &[PreparedUtterance]) -> Self {
        let unsnapped = crate::train::eval::predict(
            &mut crate::lipsync::ModelAnimator::with_closure_snap(model, 0.0),
            utterances,
        );
        Self {
            model: model.clone(),
            utterances: utterances.to_vec(),
            unsnapped,
        }
    }

    /// Several models' predictions (each on its own utterances, same viseme set) as one set.
    pub fn pool(parts: &[HeldOutPredictions]) -> Result<Self, TrainError> {
        let first = parts.first().ok_or(TrainError::NoFrames)?;
        Ok(Self {
            model: first.model.clone(),
            utterances: parts
                .iter()
                .flat_map(|p| p.utterances.iter().cloned())
                .collect(),
            unsnapped: parts
                .iter()
                .flat_map(|p| p.unsnapped.iter().cloned())
                .collect(),
        })
    }

    /// The scores with the closure snap at `snap`.
    pub fn scores(&self, snap: f32, shapes: &VisemeShapes) -> Result<Scores, TrainError> {
        let k = self.model.visemes.len();
        let snapped: Vec<Vec<f32>> = self
            .unsnapped
            .iter()
            .map(|utt| {
                let mut utt = utt.clone();
                for weights in utt.chunks_exact_mut(k) {
                    self.model.snap_with(weights, snap);
                }
                utt
            })
            .collect();
        Ok(score(
            &self.model.visemes,
            shapes,
            &self.utterances,
            &snapped,
        )?)
    }

    /// The scores at every candidate closure-snap threshold: the trade-off between closing in
    /// /p b m/ and closing elsewhere.
    pub fn snap_curve(&self, shapes: &VisemeShapes) -> Result<Vec<(f32, Scores)>, TrainError> {
        snap_candidates()
            .map(|snap| Ok((snap, self.scores(snap, shapes)?)))
            .collect()
    }
}

/// The threshold of `curve` with the best `closure share - FALSE_CLOSURE_COST * false
/// closures` (0 = off, when nothing beats no rule).
pub fn best_snap(curve: &[(f32, Scores)]) -> f32 {
    let mut best = (f64::NEG_INFINITY, 0.0);
    for (snap, s) in curve {
        let value = s.closure_share() - FALSE_CLOSURE_COST * s.false_closure_rate;
        if value > best.0 + 1e-9 {
            best = (value, *snap);
        }
    }
    best.1
}

pub(super) fn predictions(model: &Model, data: &Dataset) -> Vec<Vec<f32>> {
    let mut hidden = vec![0.0; model.hidden];
    let mut out = vec![0.0; model.outputs()];
    // A control network's weights: its controls decomposed onto its set, frame after frame.
    let decomposer = model
        .has_control_outputs()
        .then(|| ControlDecomposer::new(&model.visemes).ok())
        .flatten();
    let mut weights = vec![0.0; model.visemes.len()];
    let mut start = 0;
    data.lengths
        .iter()
        .map(|&len| {
            let mut utt = Vec::with_capacity(len * weights.len());
            let even = 1.0 / weights.len() as f32;
            weights.fill(even);
            for n in start..start + len {
                model.output(data.input(n), &mut hidden, &mut out);
                match &decomposer {
                    Some(d) => {
                        let controls: [f32; CONTROL_COUNT] =
                            std::array::from_fn(|c| out.get(c).copied().unwrap_or(0.0));
                        d.fit(&Controls::from_array(controls), &mut weights);
                        utt.extend_from_slice(&weights);
                    }
                    None => {
                        model.snap(&mut out);
                        utt.extend_from_slice(&out);
                    }
                }
            }
            start += len;
            utt
        })
        .collect()
}
