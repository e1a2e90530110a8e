//! `lipcall decompose`'s material: the phone-derived targets of a corpus as the point track the
//! paper's Table I decomposes, and decomposition weights per marker frame as CSV.

use std::io::Write;

use crate::lipsync::decompose::PointTrack;
use crate::lipsync::mouth::VisemeShapes;
use crate::train::corpus::{Corpus, utterance_targets};
use crate::train::error::TrainError;
use crate::vocab::VisemeSet;

/// The phone-derived 15-viseme targets of the first `per_speaker` utterances (all when `None`)
/// of every speaker, through the point model's shapes: the track Table I decomposes. Returns
/// it with the number of utterances in it.
pub fn phone_target_track(
    corpus: &Corpus,
    shapes: &VisemeShapes,
    per_speaker: Option<usize>,
) -> Result<(PointTrack, usize), TrainError> {
    let full = VisemeSet::full();
    let mut track = PointTrack::new(shapes.point_dim(), shapes.coords());
    let mut utterances = 0;
    for speaker in &corpus.speakers {
        let n = per_speaker.unwrap_or(speaker.utterances.len());
        for utt in speaker.utterances.iter().take(n) {
            let targets = utterance_targets(utt)?;
            let weights = targets.weights.iter().map(|w| &w[..]);
            for frame in PointTrack::from_weights(shapes, &full, weights)?.frames() {
                track.push(frame)?;
            }
            utterances += 1;
        }
    }
    Ok((track, utterances))
}

/// Decomposition weights per marker frame as CSV: `frame,<viseme names of set>`.
pub fn write_frame_weights(
    out: &mut impl Write,
    set: &VisemeSet,
    frame_numbers: &[u64],
    weights: &[Vec<f32>],
) -> std::io::Result<()> {
    let names: Vec<&str> = set.members().iter().map(|v| v.name()).collect();
    writeln!(out, "frame,{}", names.join(","))?;
    for (frame, row) in frame_numbers.iter().zip(weights) {
        write!(out, "{frame}")?;
        for v in row {
            write!(out, ",{v:.5}")?;
        }
        writeln!(out)?;
    }
    Ok(())
}
