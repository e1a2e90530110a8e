//! Lip sync: viseme sets, phone-derived targets, mouth geometry, the paper's decomposition, the
//! per-frame network and the jaw-from-energy baseline.

pub mod builtin;
pub mod coarticulation;
pub mod decompose;
pub mod jaw;
pub mod markers;
pub mod mouth;
pub mod network;
pub mod phones;
pub mod recipe;
pub mod reproject;
pub mod visemes;

pub use builtin::default_model;

use crate::speex::features::FrameFeatures;
use network::{InferenceState, Model};
use visemes::VisemeSet;

/// Anything that turns a stream of decoded frames into convex viseme weights.
pub trait Animator {
    fn visemes(&self) -> &VisemeSet;
    /// Starts a new stream (forget the past frames).
    fn reset(&mut self);
    /// Writes weights over `self.visemes()` for the next frame into `weights`.
    fn animate(&mut self, features: &FrameFeatures, weights: &mut [f32]);
}

/// A trained model with its per-stream state.
#[derive(Debug, Clone)]
pub struct ModelAnimator<'a> {
    model: &'a Model,
    state: InferenceState,
    closure_snap: f32,
}

impl<'a> ModelAnimator<'a> {
    pub fn new(model: &'a Model) -> Self {
        Self::with_closure_snap(model, model.closure_snap)
    }

    /// With another closure-snap threshold than the model's (0 = no snapping).
    pub fn with_closure_snap(model: &'a Model, closure_snap: f32) -> Self {
        Self {
            model,
            state: model.new_state(),
            closure_snap,
        }
    }

    /// The model's closure snap moved by `bias` in [-1, 1]: positive closes the lips more
    /// readily (every /p b m/, and more often elsewhere), negative less; 0 is the model's own
    /// balance, chosen in training. A model without the rule keeps it off at 0 and below.
    pub fn with_closure_bias(model: &'a Model, bias: f32) -> Self {
        let bias = if bias.is_finite() {
            bias.clamp(-1.0, 1.0)
        } else {
            0.0
        };
        let own = model.closure_snap;
        let snap = if own <= 0.0 && bias <= 0.0 {
            0.0
        } else {
            let from = if own > 0.0 { own } else { 1.0 };
            (from - CLOSURE_BIAS_SPAN * bias).clamp(0.5, 1.0)
        };
        Self::with_closure_snap(model, snap)
    }

    pub fn closure_snap(&self) -> f32 {
        self.closure_snap
    }
}

/// Parses a closure bias for the command line: a number from -1 to 1.
pub fn parse_closure_bias(text: &str) -> Result<f32, String> {
    match text.parse::<f32>() {
        Ok(b) if (-1.0..=1.0).contains(&b) => Ok(b),
        _ => Err(format!("{text:?} is not a number from -1 to 1")),
    }
}

/// How far a full closure bias moves the closure-snap threshold. On the shipped model's
/// cross-validation a move of 0.05 trades about 14 points of /p b m/ closures against 6 of
/// false closures (docs/model.md).
pub const CLOSURE_BIAS_SPAN: f32 = 0.1;

impl Animator for ModelAnimator<'_> {
    fn visemes(&self) -> &VisemeSet {
        &self.model.visemes
    }

    fn reset(&mut self) {
        self.model.reset(&mut self.state);
    }

    fn animate(&mut self, features: &FrameFeatures, weights: &mut [f32]) {
        self.model
            .step_with_snap(&mut self.state, features, weights, self.closure_snap);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closure_bias_moves_the_snap_around_the_models_own() {
        let mut model = default_model();
        let own = model.closure_snap;
        assert!(own > 0.5 && own < 1.0);
        let snap = |m: &Model, b: f32| ModelAnimator::with_closure_bias(m, b).closure_snap();
        assert_eq!(snap(&model, 0.0), own);
        assert!(snap(&model, 1.0) < own && snap(&model, -1.0) > own);
        assert_eq!(snap(&model, f32::NAN), own);
        assert_eq!(snap(&model, 7.0), snap(&model, 1.0));
        model.closure_snap = 0.0;
        assert_eq!(snap(&model, 0.0), 0.0);
        assert_eq!(snap(&model, -1.0), 0.0);
        assert!((snap(&model, 1.0) - (1.0 - CLOSURE_BIAS_SPAN)).abs() < 1e-6);
        assert!(parse_closure_bias("-0.5").is_ok() && parse_closure_bias("1.5").is_err());
    }
}
