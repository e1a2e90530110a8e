//! Lip sync: viseme sets, phone-derived targets, mouth geometry, the paper's decomposition, the
//! per-frame network and the jaw-from-energy baseline.

pub mod builtin;
pub mod coarticulation;
pub mod decompose;
pub mod jaw;
pub mod life;
pub mod markers;
pub mod mouth;
pub mod network;
pub mod phones;
pub mod receiver;
pub mod recipe;
pub mod reproject;
pub mod visemes;

pub use builtin::default_model;
pub use receiver::{LipSync, LipSyncOptions};

use crate::codec::speex::features::FrameFeatures;
use network::{InferenceState, Model};
use visemes::VisemeSet;

/// Anything that turns a stream of decoded frames into convex viseme weights.
pub trait Animator {
    fn visemes(&self) -> &VisemeSet;
    /// Starts a new stream (forget the past frames).
    fn reset(&mut self);
    /// Feeds the next frame and writes weights over `self.visemes()` into `weights`: those of
    /// the frame fed `self.lookahead()` calls ago.
    fn animate(&mut self, features: &FrameFeatures, weights: &mut [f32]);
    /// Frames the output lags the input (the future frames it looks at).
    fn lookahead(&self) -> usize {
        0
    }
    /// The weights [`Animator::animate`] would write if `extra` more frames, each a repeat of
    /// the last one fed, were fed now; changes no state. The fallback for a frame whose future
    /// has not arrived in time.
    fn peek(&mut self, extra: usize, weights: &mut [f32]) {
        let _ = (extra, weights);
    }
}

/// A trained model with its per-stream state.
#[derive(Debug, Clone)]
pub struct ModelAnimator<'a> {
    model: &'a Model,
    state: InferenceState,
    /// Scratch for [`Animator::peek`], so the fallback allocates nothing.
    scratch: InferenceState,
    last: FrameFeatures,
    closure_snap: f32,
}

impl<'a> ModelAnimator<'a> {
    pub fn new(model: &'a Model) -> Self {
        Self::with_closure_snap(model, model.closure_snap)
    }

    /// With another closure-snap threshold than the model's (0 = no snapping).
    pub fn with_closure_snap(model: &'a Model, closure_snap: f32) -> Self {
        let state = model.new_state();
        Self {
            model,
            scratch: state.clone(),
            state,
            last: network::silence_features(),
            closure_snap,
        }
    }

    /// With the model's closure snap moved by `bias` ([`Model::closure_snap_with_bias`]).
    pub fn with_closure_bias(model: &'a Model, bias: f32) -> Self {
        Self::with_closure_snap(model, model.closure_snap_with_bias(bias))
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

impl Animator for ModelAnimator<'_> {
    fn visemes(&self) -> &VisemeSet {
        &self.model.visemes
    }

    fn reset(&mut self) {
        self.model.reset(&mut self.state);
        self.last = network::silence_features();
    }

    fn animate(&mut self, features: &FrameFeatures, weights: &mut [f32]) {
        self.last = *features;
        self.model
            .step_with_snap(&mut self.state, features, weights, self.closure_snap);
    }

    fn lookahead(&self) -> usize {
        self.model.lookahead
    }

    fn peek(&mut self, extra: usize, weights: &mut [f32]) {
        self.scratch.copy_from(&self.state);
        for _ in 0..extra {
            self.model.push_frame(&mut self.scratch, &self.last);
        }
        self.model
            .infer(&mut self.scratch, weights, self.closure_snap);
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
        assert!((snap(&model, 1.0) - (1.0 - network::CLOSURE_BIAS_SPAN)).abs() < 1e-6);
        assert!(parse_closure_bias("-0.5").is_ok() && parse_closure_bias("1.5").is_err());
    }
}
