//! The default network compiled into the client (paper III.C.3): build.rs turns
//! `assets/models/default.lipmodel` into constant arrays, so no file is read at run time.

use super::network::{Dynamics, InputScaling, Model};
use super::visemes::{Viseme, VisemeSet};

include!(concat!(env!("OUT_DIR"), "/default_model.rs"));

/// The shipped default network. Its viseme names are `default_model().viseme_names()`.
pub fn default_model() -> Model {
    let members = VISEMES
        .iter()
        .map(|name| name.parse::<Viseme>())
        .collect::<Result<Vec<_>, _>>()
        .and_then(VisemeSet::new)
        .expect("build.rs checked the viseme names");
    let mut scaling = InputScaling::new(-1.0, 1.0);
    scaling.offset = INPUT_OFFSET;
    scaling.scale = INPUT_SCALE;
    Model {
        visemes: members,
        scaling,
        context: CONTEXT,
        dynamics: DYNAMICS.map(|(peak_decay_db, energy_context)| Dynamics {
            peak_decay_db,
            energy_context,
        }),
        closure_snap: CLOSURE_SNAP,
        hidden: HIDDEN,
        w1: W1.to_vec(),
        b1: B1.to_vec(),
        w2: W2.to_vec(),
        b2: B2.to_vec(),
        notes: NOTES.iter().map(|n| n.to_string()).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_in_model_equals_the_shipped_file() {
        let text = include_str!("../../assets/models/default.lipmodel");
        assert_eq!(default_model(), Model::from_text(text).unwrap());
        assert!(default_model().multiply_adds() <= super::super::network::MULTIPLY_ADD_BUDGET);
    }
}
