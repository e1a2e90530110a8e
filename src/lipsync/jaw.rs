//! The classic baseline: the jaw follows the frame energy (as in Counter-Strike Source).
//! Openness is the energy scaled from `[closed_db, open_db]` onto [0, 1] and clamped; the
//! weights are `[1 - openness, openness]` over {PP, aa}.

use super::animator::Animator;
use super::network::Model;
use crate::vocab::FrameFeatures;
use crate::vocab::{Viseme, VisemeSet};

#[derive(Debug, Clone, PartialEq)]
pub struct JawBaseline {
    visemes: VisemeSet,
    pub closed_db: f32,
    pub open_db: f32,
}

impl JawBaseline {
    pub fn new(closed_db: f32, open_db: f32) -> Self {
        let visemes = VisemeSet::new(vec![Viseme::PP, Viseme::Aa]).expect("two distinct visemes");
        Self {
            visemes,
            closed_db,
            open_db,
        }
    }

    /// Uses the energy range a trained model scales onto [-1, 1] (fitted on its training speakers).
    pub fn from_model(model: &Model) -> Self {
        Self::new(
            model.scaling.energy_db_at(-1.0),
            model.scaling.energy_db_at(1.0),
        )
    }

    pub fn openness(&self, energy_db: f32) -> f32 {
        let span = (self.open_db - self.closed_db).max(1e-3);
        let o = (energy_db - self.closed_db) / span;
        if o.is_nan() { 0.0 } else { o.clamp(0.0, 1.0) }
    }
}

impl Animator for JawBaseline {
    fn visemes(&self) -> &VisemeSet {
        &self.visemes
    }

    fn reset(&mut self) {}

    fn animate(&mut self, features: &FrameFeatures, weights: &mut [f32]) {
        let open = self.openness(features.energy_db);
        weights[0] = 1.0 - open;
        weights[1] = open;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jaw_opens_with_energy_and_clamps() {
        let mut jaw = JawBaseline::new(-60.0, -20.0);
        let mut w = [0.0; 2];
        let mut f = crate::vocab::FrameFeatures::silent();
        for (energy, open) in [(-100.0, 0.0), (-40.0, 0.5), (0.0, 1.0), (f32::NAN, 0.0)] {
            f.energy_db = energy;
            jaw.animate(&f, &mut w);
            assert_eq!(w, [1.0 - open, open]);
        }
    }
}
