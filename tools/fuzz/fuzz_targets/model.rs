//! The lip-sync model file (`Model::from_text`, what `--model` and the built-in model go
//! through). No panic; a model that loads writes itself out to the same text again, and gives
//! convex weights (finite, non-negative, summing to 1) for silence, a loud frame and a frame
//! at the edges of the LSP range, in every feature family.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lipcall::codec::FeatureFamily;
use lipcall::lipsync::network::{Model, silence_features};

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(model) = Model::from_text(text) else {
        return;
    };
    let written = model.to_text();
    let again = Model::from_text(&written).expect("a loaded model's own text loads");
    assert_eq!(again.to_text(), written, "the model's text is not stable");

    let silence = silence_features();
    let mut loud = silence;
    loud.energy_db = 0.0;
    loud.mode = Some(5);
    let mut edges = loud;
    edges.lsp = std::array::from_fn(|i| 1e-3 + i as f32 * 1e-3);
    edges.lsp[9] = std::f32::consts::PI - 1e-3;
    let mut state = model.new_state();
    let mut weights = vec![0.0f32; model.outputs()];
    for family in [
        FeatureFamily::Bitstream,
        FeatureFamily::Nlsf,
        FeatureFamily::Analysis,
    ] {
        for frame in [silence, loud, edges, silence] {
            let frame = lipcall::codec::speex::features::FrameFeatures { family, ..frame };
            let snap = model.closure_snap_of(family);
            model.step_with_snap(&mut state, &frame, &mut weights, snap);
            let sum: f32 = weights.iter().sum();
            assert!(
                weights.iter().all(|w| w.is_finite() && *w >= 0.0) && (sum - 1.0).abs() < 1e-3,
                "weights not convex: {weights:?}"
            );
        }
    }
});
