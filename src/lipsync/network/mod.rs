//! The per-frame network: 11 decoder features (10 LSPs + energy) of the current frame and a few
//! past ones, scaled to [-1, 1], one tanh hidden layer, and a softmax over the viseme set so the
//! output weights are convex. Inference allocates nothing.
//!
//! Here the network's shape ([`Model`]); beside it the model file (`model_file`: versions 1 to
//! 3 read, 3 written, [`ModelError`]), the inference (`inference`: the step through both layers,
//! the input history that carries the look-ahead, sharpness and the closure snap) and the input
//! normalisation (`normalise`: [`InputScaling`], [`SpeakerNorm`] and the energy-derived inputs,
//! [`Dynamics`]).
//!
//! Inputs are ordered frame by frame, newest first: the current frame's values (11 raw, or 13
//! with dynamics: the raw ones, the energy relative to a running peak and the energy change from
//! the previous frame), then the frame before, and so on; with dynamics, `energy_context` more
//! past frames' peak-relative energies follow (older frames, newest first).

mod inference;
mod model;
mod model_file;
mod normalise;

pub use inference::{
    CLOSURE_BIAS_SPAN, InferenceState, LINEAR_CONTROLS, MAX_SHARPNESS, MAX_SMOOTHING,
    MIN_CLOSURE_SNAP, MIN_SHARPNESS, activate_controls, sharpen,
};
pub use model::{
    CONTROL_MULTIPLY_ADD_BUDGET, MAX_LOOKAHEAD, MULTIPLY_ADD_BUDGET, Model, OutputKind,
    input_count, multiply_adds,
};
pub use model_file::ModelError;
pub use normalise::{
    Dynamics, FEATURES_PER_FRAME, InputScaling, PEAK_FLOOR_DB, SpeakerNorm, frame_width,
};

#[cfg(test)]
mod fixtures {
    use super::*;
    use crate::vocab::{FrameFeatures, VisemeSet};

    pub(super) fn sample_model() -> Model {
        let mut model = Model::zeros(
            VisemeSet::reduced(3).unwrap(),
            InputScaling::new(-70.0, -10.0),
            2,
            4,
        );
        let mut x = 0.37f32;
        for w in model
            .w1
            .iter_mut()
            .chain(&mut model.b1)
            .chain(&mut model.w2)
            .chain(&mut model.b2)
        {
            x = (x * 3.7 + 0.11).fract();
            *w = (x - 0.5) * 1.3e-3 / (x + 0.01);
        }
        model.notes.push("test weights".into());
        model
    }

    pub(super) fn frame(energy_db: f32) -> FrameFeatures {
        let mut f = FrameFeatures::silent();
        f.energy_db = energy_db;
        f.lsp[0] = 0.2;
        f
    }
}
