//! Scores of a viseme animator on held-out speakers, against the phone-derived targets.
//!
//! - Eq. 1 error: generated vs target feature points of the point model, per point divided by the
//!   target's deviation, on the paper's important points (deviation above average).
//! - Frame accuracy: the predicted argmax viseme equals the target's argmax over the 15 visemes
//!   (a reduced set can only ever be right on the visemes it has).
//! - Openness r: Pearson correlation of predicted and target mouth openness (jaw + aperture).
//! - Width r, rounding r: the same for lip width (spread +, narrowed -) and rounding
//!   (protrusion), from the design brief's viseme table ([`cues`]).
//! - Cue segments: the share of open-vowel segments (/aa ae ah ax ay aw/, >= 60 ms) whose
//!   openness exceeds 0.5, of rounded ones (/uw ux uh ow oy ao w/, >= 60 ms) whose rounding
//!   exceeds 0.3, and of /f v/ (>= 40 ms, +-20 ms) whose FF weight reaches 0.3, somewhere in the
//!   segment.
//! - Closures: the share of /p b m/ segments with at least one frame whose lip aperture is below
//!   [`CLOSED_APERTURE`]; false closures: the share of frames that are at least
//!   `CLOSURE_MARGIN_FRAMES` away from any bilabial or silence and still closed.

use std::fmt;

use crate::call::pipeline::{PeerPipeline, run_stream};
use crate::lipsync::decompose::{PointTrack, eq1_error, important_points};
use crate::lipsync::jaw::JawBaseline;
use crate::lipsync::mouth::{
    CLOSED_APERTURE, CUE_COUNT, Cue, ShapeError, VisemeShapes, cues, lip_aperture, openness,
};
use crate::lipsync::network::Model;
use crate::lipsync::phones::CueClass;
use crate::lipsync::{Animator, LipSync, ModelAnimator};
use crate::train::corpus::{Corpus, CorpusError, FeatureFn, PreparedUtterance, prepare};
use crate::vocab::{FrameFeatures, Viseme, VisemeSet};

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(transparent)]
    Corpus(#[from] CorpusError),
    #[error(transparent)]
    Shape(#[from] ShapeError),
    #[error("nothing to evaluate: no frames")]
    NoFrames,
}

#[derive(Debug, thiserror::Error)]
pub enum FramesError {
    #[error(transparent)]
    Decompose(#[from] crate::lipsync::decompose::DecomposeError),
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

/// The metrics of one animator.
#[derive(Debug, Clone, PartialEq)]
pub struct Scores {
    pub frames: usize,
    pub eq1_error: f64,
    pub frame_accuracy: f64,
    pub openness_r: f64,
    pub bilabial_segments: usize,
    pub closed_segments: usize,
    pub false_closure_rate: f64,
    /// Pearson r of width and of rounding (openness is `openness_r`).
    pub width_r: f64,
    pub rounding_r: f64,
    /// Per [`CueClass`]: segments scored, and segments in which the mouth showed the cue.
    pub cue_segments: [usize; 3],
    pub cue_shown: [usize; 3],
    /// The share of frames away from any /f v/ whose FF weight reaches the /f v/ threshold.
    pub false_labiodental_rate: f64,
}

/// What a segment of each [`CueClass`] must reach somewhere to count as shown.
pub const OPEN_VOWEL_OPENNESS: f32 = 0.5;
pub const ROUNDED_ROUNDING: f32 = 0.3;
pub const LABIODENTAL_WEIGHT: f32 = 0.3;

impl Scores {
    pub fn closure_share(&self) -> f64 {
        self.closed_segments as f64 / self.bilabial_segments.max(1) as f64
    }

    /// The share of `class` segments in which the mouth showed the cue.
    pub fn cue_share(&self, class: CueClass) -> f64 {
        self.cue_shown[class.index()] as f64 / self.cue_segments[class.index()].max(1) as f64
    }
}

pub fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len()) as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut cov, mut va, mut vb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        cov += (x - ma) * (y - mb);
        va += (x - ma) * (x - ma);
        vb += (y - mb) * (y - mb);
    }
    if va <= 0.0 || vb <= 0.0 {
        0.0
    } else {
        cov / (va * vb).sqrt()
    }
}

/// Scores predictions (per utterance, frames x `set.len()` flattened) against the targets.
pub fn score(
    set: &VisemeSet,
    shapes: &VisemeShapes,
    utterances: &[PreparedUtterance],
    predictions: &[Vec<f32>],
) -> Result<Scores, EvalError> {
    let full = VisemeSet::full();
    let k = set.len();
    let mut target_points = PointTrack::new(shapes.point_dim(), shapes.coords());
    let mut predicted_points = PointTrack::new(shapes.point_dim(), shapes.coords());
    let mut frame = vec![0.0; shapes.coords()];
    let mut target_cues: [Vec<f64>; CUE_COUNT] = Default::default();
    let mut predicted_cues: [Vec<f64>; CUE_COUNT] = Default::default();
    let (mut correct, mut segments, mut closed_segments) = (0usize, 0usize, 0usize);
    let (mut elsewhere, mut false_closed) = (0usize, 0usize);
    let (mut cue_segments, mut cue_shown) = ([0usize; 3], [0usize; 3]);
    let labiodental = set.position(Viseme::FF);
    let (mut away_from_fv, mut false_fv) = (0usize, 0usize);
    for (utt, predicted) in utterances.iter().zip(predictions) {
        let targets = &utt.targets;
        let mut closed = Vec::with_capacity(targets.len());
        let mut shown = Vec::with_capacity(targets.len());
        for (n, (target, weights)) in targets
            .weights
            .iter()
            .zip(predicted.chunks_exact(k))
            .enumerate()
        {
            shapes.blend_into(&full, target, &mut frame)?;
            target_points.push(&frame).expect("shape length");
            shapes.blend_into(set, weights, &mut frame)?;
            predicted_points.push(&frame).expect("shape length");
            let predicted = cues(set, weights);
            for (i, (t, p)) in cues(&full, target).iter().zip(predicted).enumerate() {
                target_cues[i].push(*t as f64);
                predicted_cues[i].push(p as f64);
            }
            let fv = labiodental.is_some_and(|i| weights[i] >= LABIODENTAL_WEIGHT);
            shown.push([
                predicted[Cue::Openness as usize] > OPEN_VOWEL_OPENNESS,
                predicted[Cue::Rounding as usize] > ROUNDED_ROUNDING,
                fv,
            ]);
            if !targets.labiodental_allowed[n] {
                away_from_fv += 1;
                false_fv += usize::from(fv);
            }
            if argmax_viseme(set, weights) == argmax_viseme(&full, target) {
                correct += 1;
            }
            let is_closed = lip_aperture(set, weights) < CLOSED_APERTURE;
            closed.push(is_closed);
            if !targets.closure_allowed[n] {
                elsewhere += 1;
                false_closed += usize::from(is_closed);
            }
        }
        for seg in &targets.bilabial_segments {
            segments += 1;
            closed_segments += usize::from(closed[seg.clone()].iter().any(|&c| c));
        }
        for (class, seg) in &targets.cue_segments {
            let i = class.index();
            cue_segments[i] += 1;
            cue_shown[i] += usize::from(shown[seg.clone()].iter().any(|s| s[i]));
        }
    }
    let frames = target_points.len();
    if frames == 0 {
        return Err(EvalError::NoFrames);
    }
    let sigmas = target_points.point_sigmas();
    Ok(Scores {
        frames,
        eq1_error: eq1_error(
            &predicted_points,
            &target_points,
            &important_points(&sigmas),
            &sigmas,
        ),
        frame_accuracy: correct as f64 / frames as f64,
        openness_r: pearson(&target_cues[0], &predicted_cues[0]),
        bilabial_segments: segments,
        closed_segments,
        false_closure_rate: false_closed as f64 / elsewhere.max(1) as f64,
        width_r: pearson(&target_cues[1], &predicted_cues[1]),
        rounding_r: pearson(&target_cues[2], &predicted_cues[2]),
        cue_segments,
        cue_shown,
        false_labiodental_rate: false_fv as f64 / away_from_fv.max(1) as f64,
    })
}

fn argmax_viseme(set: &VisemeSet, weights: &[f32]) -> Viseme {
    let best =
        weights.iter().enumerate().fold(
            (0, f32::MIN),
            |best, (i, &w)| if w > best.1 { (i, w) } else { best },
        );
    set.members()[best.0]
}

/// Runs an animator over every utterance (reset at each new speaker) through the receiver's
/// own pipeline ([`PeerPipeline`]: look-ahead, the rest in digital silence, the fallback for
/// the last frames, whose future never comes), frame n's weights at row n: what `animate`
/// writes and the app shows.
pub fn predict(animator: &mut dyn Animator, utterances: &[PreparedUtterance]) -> Vec<Vec<f32>> {
    let streams: Vec<(&str, &[FrameFeatures])> = utterances
        .iter()
        .map(|u| (u.speaker.as_str(), &u.features[..]))
        .collect();
    predict_streams(animator, &streams)
}

/// [`predict`] on `(speaker, features)` streams: the weights the receiver's pipeline shows for
/// each frame, a speaker's streams run as one call.
pub fn predict_streams(
    animator: &mut dyn Animator,
    streams: &[(&str, &[FrameFeatures])],
) -> Vec<Vec<f32>> {
    let k = animator.visemes().len();
    let borrowed: Box<dyn Animator + '_> = Box::new(animator);
    let mut pipeline = match LipSync::with_animator(borrowed, None) {
        Ok(lipsync) => PeerPipeline::with_lipsync(lipsync),
        Err(e) => {
            // No receiver can show this set either; its rows score as an idle mouth.
            tracing::error!("the model's viseme set cannot be shown: {e}");
            return streams
                .iter()
                .map(|(_, f)| vec![0.0; f.len() * k])
                .collect();
        }
    };
    let mut current: Option<&str> = None;
    streams
        .iter()
        .map(|&(speaker, features)| {
            // One speaker's utterances run as one call (the per-speaker state carries over).
            if current != Some(speaker) {
                pipeline.reset();
                current = Some(speaker);
            }
            let mut out = vec![0.0; features.len() * k];
            run_stream(&mut pipeline, features, &[], |frame| {
                let n = frame.tag as usize;
                out[n * k..(n + 1) * k].copy_from_slice(frame.weights);
            });
            out
        })
        .collect()
}

/// The evaluation of a model next to the jaw baseline and the targets themselves.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalReport {
    pub speakers: Vec<String>,
    pub utterances: usize,
    /// `(name, scores)`: the phone-derived targets, the network, the jaw baseline.
    pub rows: Vec<(String, Scores)>,
}

impl EvalReport {
    pub fn scores(&self, name: &str) -> Option<&Scores> {
        self.rows.iter().find(|(n, _)| n == name).map(|(_, s)| s)
    }
}

/// Row names of [`EvalReport`].
pub const TARGETS_ROW: &str = "targets";
pub const NETWORK_ROW: &str = "network";
pub const JAW_ROW: &str = "jaw baseline";

/// Evaluates `model` and the jaw baseline (scaled like the model's energy input) on `speakers`.
pub fn evaluate(
    model: &Model,
    corpus: &Corpus,
    speakers: &[String],
    features: &FeatureFn,
    shapes: &VisemeShapes,
) -> Result<EvalReport, EvalError> {
    let utterances = prepare(&corpus.utterances_of(speakers)?, features)?;
    evaluate_prepared(model, &utterances, speakers, shapes)
}

pub fn evaluate_prepared(
    model: &Model,
    utterances: &[PreparedUtterance],
    speakers: &[String],
    shapes: &VisemeShapes,
) -> Result<EvalReport, EvalError> {
    let full = VisemeSet::full();
    let targets: Vec<Vec<f32>> = utterances
        .iter()
        .map(|u| u.targets.weights.iter().flatten().copied().collect())
        .collect();
    let network = predict(&mut ModelAnimator::new(model), utterances);
    let mut jaw = JawBaseline::from_model(model);
    let baseline = predict(&mut jaw, utterances);
    Ok(EvalReport {
        speakers: speakers.to_vec(),
        utterances: utterances.len(),
        rows: vec![
            (
                TARGETS_ROW.into(),
                score(&full, shapes, utterances, &targets)?,
            ),
            (
                NETWORK_ROW.into(),
                score(&model.visemes, shapes, utterances, &network)?,
            ),
            (
                JAW_ROW.into(),
                score(jaw.visemes(), shapes, utterances, &baseline)?,
            ),
        ],
    })
}

/// Frame by frame, for analysis outside: `speaker,utterance,frame,target_openness,
/// set_target_openness,network_openness,jaw_openness,target_aperture,network_aperture,bilabial,
/// closure_allowed,network_closed,target_width,network_width,target_rounding,network_rounding`
/// (`set_target`: the targets decomposed onto the model's
/// reduced set, what the network is trained towards; `network_closed`: the closed viseme's
/// weight before the closure snap).
pub fn write_frames(
    out: &mut dyn std::io::Write,
    model: &Model,
    shapes: &VisemeShapes,
    utterances: &[PreparedUtterance],
) -> Result<(), FramesError> {
    let full = VisemeSet::full();
    let set_targets = crate::train::targets::set_targets(&model.visemes, shapes, utterances)?;
    let raw = predict(
        &mut ModelAnimator::with_closure_snap(model, 0.0),
        utterances,
    );
    let k = model.visemes.len();
    let network: Vec<Vec<f32>> = raw
        .iter()
        .map(|utt| {
            let mut utt = utt.clone();
            utt.chunks_exact_mut(k).for_each(|w| model.snap(w));
            utt
        })
        .collect();
    let closed = model.closed_index();
    let mut jaw = JawBaseline::from_model(model);
    let baseline = predict(&mut jaw, utterances);
    let jaw_set = jaw.visemes().clone();
    writeln!(
        out,
        "speaker,utterance,frame,target_openness,set_target_openness,network_openness,\
         jaw_openness,target_aperture,network_aperture,bilabial,closure_allowed,network_closed,\
         target_width,network_width,target_rounding,network_rounding"
    )?;
    for ((((utt, predicted), flap), set_target), raw) in utterances
        .iter()
        .zip(&network)
        .zip(&baseline)
        .zip(&set_targets)
        .zip(&raw)
    {
        let t = &utt.targets;
        for (n, (((target, weights), jaw_weights), set_weights)) in t
            .weights
            .iter()
            .zip(predicted.chunks_exact(k))
            .zip(flap.chunks_exact(jaw_set.len()))
            .zip(set_target.chunks_exact(k))
            .enumerate()
        {
            let raw_closed = closed.map_or(0.0, |c| raw[n * k + c]);
            let [_, target_width, target_rounding] = cues(&full, target);
            let [_, width, rounding] = cues(&model.visemes, weights);
            writeln!(
                out,
                "{},{},{n},{},{},{},{},{},{},{},{},{raw_closed},{target_width},{width},\
                 {target_rounding},{rounding}",
                utt.speaker,
                utt.id,
                openness(&full, target),
                openness(&model.visemes, set_weights),
                openness(&model.visemes, weights),
                openness(&jaw_set, jaw_weights),
                lip_aperture(&full, target),
                lip_aperture(&model.visemes, weights),
                u8::from(t.in_bilabial(n)),
                u8::from(t.closure_allowed[n]),
            )?;
        }
    }
    Ok(())
}

impl fmt::Display for EvalReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "held-out speakers: {} ({} utterances)",
            self.speakers.join(" "),
            self.utterances
        )?;
        writeln!(
            f,
            "{:<14} {:>7} {:>8} {:>9} {:>11} {:>14} {:>10}",
            "", "frames", "Eq.1 err", "accuracy", "openness r", "/p b m/ closed", "false cl."
        )?;
        for (name, s) in &self.rows {
            writeln!(
                f,
                "{:<14} {:>7} {:>7.2}% {:>8.1}% {:>11.3} {:>6.1}% {:>3}/{:<3} {:>9.1}%",
                name,
                s.frames,
                100.0 * s.eq1_error,
                100.0 * s.frame_accuracy,
                s.openness_r,
                100.0 * s.closure_share(),
                s.closed_segments,
                s.bilabial_segments,
                100.0 * s.false_closure_rate
            )?;
        }
        writeln!(
            f,
            "{:<14} {:>8} {:>10} {:>15} {:>15} {:>15} {:>10}",
            "", "width r", "rounding r", "open vowels", "rounded", "/f v/ shown", "false f/v"
        )?;
        for (name, s) in &self.rows {
            let cue = |class: CueClass| {
                format!(
                    "{:>5.1}% {:>4}/{:<4}",
                    100.0 * s.cue_share(class),
                    s.cue_shown[class.index()],
                    s.cue_segments[class.index()]
                )
            };
            writeln!(
                f,
                "{:<14} {:>8.3} {:>10.3} {:>15} {:>15} {:>15} {:>9.1}%",
                name,
                s.width_r,
                s.rounding_r,
                cue(CueClass::OpenVowel),
                cue(CueClass::Rounded),
                cue(CueClass::Labiodental),
                100.0 * s.false_labiodental_rate
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::corpus::{PhoneSegment, targets_from_phones};

    /// Silent features over the targets of `phones` (16 kHz samples).
    fn prepared(phones: &[(u64, u64, &str)], samples: u32) -> PreparedUtterance {
        let phones: Vec<PhoneSegment> = phones
            .iter()
            .map(|&(start, end, phone)| PhoneSegment {
                start,
                end,
                phone: phone.into(),
            })
            .collect();
        let targets = targets_from_phones(&phones, 16000, samples).unwrap();
        let features = vec![crate::vocab::FrameFeatures::silent(); targets.len()];
        PreparedUtterance {
            speaker: "x".into(),
            id: "y".into(),
            features,
            targets,
            weight: 1.0,
        }
    }

    fn utterance() -> PreparedUtterance {
        let phones = [
            (0, 3200, "h#"),
            (3200, 6400, "aa"),
            (6400, 8000, "m"),
            (8000, 11200, "aa"),
            (11200, 14400, "s"),
            (14400, 16000, "h#"),
        ];
        prepared(&phones, 16000)
    }

    #[test]
    fn perfect_predictions_score_perfectly() {
        let utt = utterance();
        let full = VisemeSet::full();
        let exact: Vec<f32> = utt.targets.weights.iter().flatten().copied().collect();
        let s = score(
            &full,
            &VisemeShapes::point_model(),
            std::slice::from_ref(&utt),
            &[exact],
        )
        .unwrap();
        assert_eq!(s.frame_accuracy, 1.0);
        assert!(s.eq1_error < 1e-6 && (s.openness_r - 1.0).abs() < 1e-9);
        assert_eq!((s.bilabial_segments, s.closed_segments), (1, 1));
        assert_eq!(s.false_closure_rate, 0.0);
    }

    fn cue_utterance() -> PreparedUtterance {
        let phones = [
            (0, 3200, "h#"),
            (3200, 4000, "f"),
            (4000, 5600, "uw"),
            (5600, 6000, "v"),
            (6000, 8000, "ae"),
            (8000, 9600, "h#"),
        ];
        prepared(&phones, 9600)
    }

    #[test]
    fn cue_segments_are_shown_by_the_targets_and_not_by_a_closed_mouth() {
        let utt = cue_utterance();
        // The 25 ms /v/ is too short to score; f, uw and ae are long enough.
        assert_eq!(utt.targets.cue_segments.len(), 3);
        let full = VisemeSet::full();
        let shapes = VisemeShapes::point_model();
        let exact: Vec<f32> = utt.targets.weights.iter().flatten().copied().collect();
        let s = score(&full, &shapes, std::slice::from_ref(&utt), &[exact]).unwrap();
        assert_eq!(s.cue_segments, [1, 1, 1]);
        assert_eq!(s.cue_shown, [1, 1, 1]);
        assert!((s.width_r - 1.0).abs() < 1e-9 && (s.rounding_r - 1.0).abs() < 1e-9);

        let set = VisemeSet::parse("PP,FF,aa,I,U").unwrap();
        let closed: Vec<f32> = (0..utt.targets.len())
            .flat_map(|_| [1.0, 0.0, 0.0, 0.0, 0.0])
            .collect();
        let s = score(&set, &shapes, std::slice::from_ref(&utt), &[closed]).unwrap();
        assert_eq!(s.cue_shown, [0, 0, 0]);
        assert_eq!((s.width_r, s.rounding_r), (0.0, 0.0));
        let rounded_only: Vec<f32> = (0..utt.targets.len())
            .flat_map(|_| [0.0, 0.0, 0.0, 0.0, 1.0])
            .collect();
        let s = score(&set, &shapes, std::slice::from_ref(&utt), &[rounded_only]).unwrap();
        assert_eq!(s.cue_shown, [0, 1, 0]);
    }

    #[test]
    fn an_always_closed_mouth_closes_everywhere() {
        let utt = utterance();
        let set = VisemeSet::reduced(2).unwrap();
        let closed: Vec<f32> = (0..utt.targets.len()).flat_map(|_| [1.0, 0.0]).collect();
        let s = score(
            &set,
            &VisemeShapes::point_model(),
            std::slice::from_ref(&utt),
            &[closed],
        )
        .unwrap();
        assert_eq!(s.closure_share(), 1.0);
        assert_eq!(s.false_closure_rate, 1.0);
        assert_eq!(s.openness_r, 0.0);
        assert!(s.eq1_error > 0.5);
    }
}
