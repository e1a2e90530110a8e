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
}

impl<'a> ModelAnimator<'a> {
    pub fn new(model: &'a Model) -> Self {
        Self {
            model,
            state: model.new_state(),
        }
    }
}

impl Animator for ModelAnimator<'_> {
    fn visemes(&self) -> &VisemeSet {
        &self.model.visemes
    }

    fn reset(&mut self) {
        self.model.reset(&mut self.state);
    }

    fn animate(&mut self, features: &FrameFeatures, weights: &mut [f32]) {
        self.model.step(&mut self.state, features, weights);
    }
}
