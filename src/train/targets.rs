//! The network's training targets over its viseme set, from the phone-derived weights over all
//! 15 visemes. Shared by training and evaluation.

use crate::lipsync::decompose::{DecomposeError, PointTrack};
use crate::lipsync::mouth::VisemeShapes;
use crate::lipsync::reproject::decomposition_map;
use crate::train::corpus::PreparedUtterance;
use crate::vocab::VisemeSet;

/// Per utterance: its targets over `set`, frames x `set.len()` flattened: the 15-viseme weights
/// through the receiver's re-projection map (`lipsync::reproject`), so the set's shapes are
/// taught wherever the phones call for them. The shape points are weighed by their spread over
/// the corpus.
pub fn set_targets(
    set: &VisemeSet,
    shapes: &VisemeShapes,
    utterances: &[PreparedUtterance],
) -> Result<Vec<Vec<f32>>, DecomposeError> {
    let full = VisemeSet::full();
    let k = set.len();
    let points = shapes.coords() / shapes.point_dim();
    let point_weights = if full.members().iter().all(|v| set.position(*v).is_some()) {
        // Nothing is decomposed onto a set that holds all 15.
        vec![1.0; points]
    } else {
        let mut all = PointTrack::new(shapes.point_dim(), shapes.coords());
        for utt in utterances {
            let track = PointTrack::from_weights(
                shapes,
                &full,
                utt.targets.weights.iter().map(|w| &w[..]),
            )?;
            for frame in track.frames() {
                all.push(frame)?;
            }
        }
        all.point_sigmas()
    };
    let map = decomposition_map(shapes, &full, set, &point_weights)?;
    Ok(utterances
        .iter()
        .map(|u| {
            let mut out = vec![0.0f32; u.targets.weights.len() * k];
            for (w, o) in u.targets.weights.iter().zip(out.chunks_exact_mut(k)) {
                for (weight, row) in w.iter().zip(map.chunks_exact(k)) {
                    for (o, m) in o.iter_mut().zip(row) {
                        *o += weight * m;
                    }
                }
            }
            out
        })
        .collect())
}
