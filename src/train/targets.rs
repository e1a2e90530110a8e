//! The network's training targets over its viseme set, from the phone-derived weights over all
//! 15 visemes. Shared by training and evaluation.

use crate::lipsync::decompose::{DecomposeError, Decomposer, PointTrack};
use crate::lipsync::mouth::VisemeShapes;
use crate::lipsync::visemes::VisemeSet;
use crate::train::corpus::PreparedUtterance;

/// Per utterance: its targets over `set`, frames x `set.len()` flattened. A viseme of the set
/// keeps its own weight; each other viseme's weight goes to its convex decomposition onto the
/// set's shapes (the paper's III.A.1, per viseme), so the set's shapes are taught wherever the
/// phones call for them: a blend of the 15 decomposed frame by frame would let PP + aa stand in
/// for FF, whose points are nearly theirs.
pub fn set_targets(
    set: &VisemeSet,
    shapes: &VisemeShapes,
    utterances: &[PreparedUtterance],
) -> Result<Vec<Vec<f32>>, DecomposeError> {
    let full = VisemeSet::full();
    let k = set.len();
    let mut map = vec![0.0f32; full.len() * k];
    if set.len() == full.len() {
        for (v, row) in full.members().iter().zip(map.chunks_exact_mut(k)) {
            row[set.position(*v).expect("the full set")] = 1.0;
        }
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
        let decomposer = Decomposer::new(shapes, set, &all.point_sigmas())?;
        for (v, row) in full.members().iter().zip(map.chunks_exact_mut(k)) {
            match set.position(*v) {
                Some(i) => row[i] = 1.0,
                None => {
                    row.fill(1.0 / k as f32);
                    decomposer.fit(shapes.shape(*v)?, row);
                }
            }
        }
    }
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
