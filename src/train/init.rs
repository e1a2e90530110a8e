//! A new network before training: input scaling fitted on the training frames, the per-speaker
//! normalisation prior, seeded initial weights.

use super::augment::Rng;
use crate::lipsync::network::{FEATURES_PER_FRAME, InputScaling, Model, SpeakerNorm};
use crate::train::config::TrainConfig;
use crate::train::corpus::PreparedUtterance;
use crate::vocab::LSP_COUNT;

pub(super) fn percentile(values: &mut [f32], q: f32) -> f32 {
    values.sort_by(f32::total_cmp);
    let i = ((values.len() - 1) as f32 * q).round() as usize;
    values[i]
}

/// Scaling fitted on the training frames: each of the 11 inputs maps its 2nd..98th percentile
/// onto [-1, 1]. Each LSP moves within a small part of [0, pi], so the paper's fixed
/// [0, pi] -> [-1, 1] would leave the inputs nearly constant.
pub(super) fn fitted_scaling(train: &[PreparedUtterance]) -> InputScaling {
    let mut scaling = InputScaling::new(-80.0, -10.0);
    for i in 0..FEATURES_PER_FRAME {
        let mut values: Vec<f32> = train
            .iter()
            .flat_map(|u| u.features.iter())
            .map(|f| if i < 10 { f.lsp[i] } else { f.energy_db })
            .filter(|v| v.is_finite())
            .collect();
        if values.is_empty() {
            continue;
        }
        let low = percentile(&mut values, 0.02);
        let high = percentile(&mut values, 0.98);
        if high > low {
            scaling.offset[i] = 0.5 * (low + high);
            scaling.scale[i] = 2.0 / (high - low);
        }
    }
    scaling
}

/// Mean LSPs of the training speakers' speech frames (the normalisation's prior).
pub(super) fn mean_speech_lsps(train: &[PreparedUtterance]) -> [f32; LSP_COUNT] {
    let mut sum = [0.0f64; LSP_COUNT];
    let mut count = 0usize;
    for f in train.iter().flat_map(|u| &u.features) {
        if f.energy_db > SPEECH_DB && f.lsp.iter().all(|l| l.is_finite()) {
            for (s, l) in sum.iter_mut().zip(&f.lsp) {
                *s += *l as f64;
            }
            count += 1;
        }
    }
    let mut mean = crate::vocab::FrameFeatures::silent().lsp;
    if count > 0 {
        for (m, s) in mean.iter_mut().zip(&sum) {
            *m = (*s / count as f64) as f32;
        }
    }
    mean
}

/// Frames louder than this count as speech for the normalisation's prior.
pub(super) const SPEECH_DB: f32 = -45.0;

pub(super) fn initial_model(
    config: &TrainConfig,
    train: &[PreparedUtterance],
    rng: &mut Rng,
) -> Model {
    let mut model = Model::zeros_with(
        config.visemes.clone(),
        fitted_scaling(train),
        config.context,
        config.dynamics,
        config.hidden,
    );
    if config.controls {
        model = model.with_control_outputs();
    }
    model.lookahead = config.lookahead;
    model.speaker_norm = config.speaker_norm_frames.map(|frames| SpeakerNorm {
        frames,
        prior: mean_speech_lsps(train),
    });
    let (inputs, outputs) = (model.inputs() as f32, model.outputs() as f32);
    let hidden = config.hidden as f32;
    let limit1 = (6.0 / (inputs + hidden)).sqrt();
    let limit2 = (6.0 / (hidden + outputs)).sqrt();
    for w in &mut model.w1 {
        *w = limit1 * (2.0 * rng.next_f32() - 1.0);
    }
    for w in &mut model.w2 {
        *w = limit2 * (2.0 * rng.next_f32() - 1.0);
    }
    model
}
