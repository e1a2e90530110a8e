//! The training frames in the network's layout: scaled inputs, targets over the model's set and
//! loss weights.

use crate::lipsync::controls::CONTROL_COUNT;
use crate::lipsync::mouth::{Articulation, CUE_COUNT, cues};
use crate::lipsync::network::{InferenceState, Model};
use crate::lipsync::phones::CueClass;
use crate::train::augment::{Rng, warp_frames};
use crate::train::control_targets::ControlVideo;
use crate::train::corpus::PreparedUtterance;
use crate::train::video::{LIP_CUES, VideoTraining, head_lips};
use crate::vocab::{FrameFeatures, Viseme, VisemeSet};

/// Scaled network inputs, targets over the model's set and loss weights, frame by frame.
#[derive(Debug, Clone)]
pub(crate) struct Dataset {
    pub(super) inputs: Vec<f32>,
    pub(super) targets: Vec<f32>,
    pub(super) weights: Vec<f32>,
    /// Frames per utterance, in order.
    pub(super) lengths: Vec<usize>,
    /// Frame ranges of the /p b m/ segments.
    pub(super) segments: Vec<std::ops::Range<usize>>,
    /// Frame ranges of the /f v/ segments (with their slack).
    pub(super) labiodental: Vec<std::ops::Range<usize>>,
    /// Openness, width and rounding of each output viseme, of each frame's 15-viseme target,
    /// and the weights of their squared errors in the loss.
    pub(super) cues: Vec<[f32; CUE_COUNT]>,
    pub(super) target_cues: Vec<[f32; CUE_COUNT]>,
    pub(super) cue_weights: [f32; CUE_COUNT],
    /// Measured lips of video frames (aperture, width on the head's scale); `None` for
    /// phone-labelled frames, which alone carry the KL and cue terms.
    pub(super) video: Vec<Option<[f32; LIP_CUES]>>,
    /// Aperture and width of each output viseme, and the weights of their squared errors.
    pub(super) video_keys: Vec<[f32; LIP_CUES]>,
    pub(super) video_cue_weights: [f32; LIP_CUES],
    /// For a control network: per frame, which controls the target knows (1) or not (0), and
    /// each control's loss scale (1 / its spread squared over the training targets).
    pub(super) known: Vec<[f32; CONTROL_COUNT]>,
    pub(super) control_scale: [f32; CONTROL_COUNT],
    pub(super) input_len: usize,
    pub(super) outputs: usize,
}

impl Dataset {
    pub(super) fn frames(&self) -> usize {
        self.weights.len()
    }

    pub(super) fn input(&self, n: usize) -> &[f32] {
        &self.inputs[n * self.input_len..(n + 1) * self.input_len]
    }

    pub(super) fn target(&self, n: usize) -> &[f32] {
        &self.targets[n * self.outputs..(n + 1) * self.outputs]
    }
}

pub(crate) fn build_dataset(
    model: &Model,
    utterances: &[PreparedUtterance],
    targets: &[Vec<f32>],
    closure_weight: f32,
    sharp_closures: bool,
) -> Dataset {
    let input_len = model.inputs();
    let outputs = model.outputs();
    let mut data = Dataset {
        inputs: Vec::new(),
        targets: targets.concat(),
        weights: Vec::new(),
        lengths: Vec::new(),
        segments: Vec::new(),
        labiodental: Vec::new(),
        cues: model
            .visemes
            .members()
            .iter()
            .map(|v| Articulation::of(*v).cues())
            .collect(),
        target_cues: Vec::new(),
        cue_weights: [0.0; CUE_COUNT],
        video: Vec::new(),
        video_keys: (0..model.visemes.len())
            .map(|k| {
                let mut one_hot = vec![0.0; model.visemes.len()];
                one_hot[k] = 1.0;
                head_lips(&model.visemes, &one_hot)
            })
            .collect(),
        video_cue_weights: [0.0; LIP_CUES],
        known: Vec::new(),
        control_scale: [1.0; CONTROL_COUNT],
        input_len,
        outputs,
    };
    let closed = model.closed_index().and(model.visemes.position(Viseme::PP));
    let full = VisemeSet::full();
    let mut state = model.new_state();
    let mut start = 0;
    let mut speaker: Option<&str> = None;
    for utt in utterances {
        // One speaker's utterances follow each other as in one call: the per-speaker state
        // (normalisation, energy peak) carries over.
        if speaker != Some(utt.speaker.as_str()) {
            model.reset(&mut state);
            speaker = Some(utt.speaker.as_str());
        }
        feed_clip(model, &mut state, &utt.features, |n, input| {
            data.inputs.extend_from_slice(input);
            data.target_cues.push(cues(&full, &utt.targets.weights[n]));
            data.video.push(None);
            data.known.push([1.0; CONTROL_COUNT]);
            let in_closure = utt.targets.in_bilabial(n);
            data.weights
                .push(utt.weight * if in_closure { closure_weight } else { 1.0 });
            if let (true, true, Some(closed)) = (sharp_closures, in_closure, closed) {
                let target = &mut data.targets[(start + n) * outputs..(start + n + 1) * outputs];
                target.fill(0.0);
                target[closed] = 1.0;
            }
        });
        data.segments.extend(
            utt.targets
                .bilabial_segments
                .iter()
                .map(|seg| start + seg.start..start + seg.end.min(utt.features.len()))
                .filter(|seg| !seg.is_empty()),
        );
        data.labiodental.extend(
            utt.targets
                .cue_segments
                .iter()
                .filter(|(class, _)| *class == CueClass::Labiodental)
                .map(|(_, seg)| start + seg.start..start + seg.end.min(utt.features.len()))
                .filter(|seg| !seg.is_empty()),
        );
        start += utt.features.len();
        data.lengths.push(utt.features.len());
    }
    data
}

/// Appends the frames of measured-lip clips: no phone targets (zero KL target, zero cues),
/// their lips as video targets, each tracked frame weighing `training.frame_weight`.
pub(crate) fn append_video(data: &mut Dataset, model: &Model, training: &VideoTraining) {
    data.video_cue_weights = training.cue_weights;
    let mut state = model.new_state();
    let mut speaker: Option<&str> = None;
    for clip in training.clips.iter() {
        if speaker != Some(clip.speaker.as_str()) {
            model.reset(&mut state);
            speaker = Some(clip.speaker.as_str());
        }
        feed_clip(model, &mut state, &clip.features, |n, input| {
            data.inputs.extend_from_slice(input);
            data.targets.extend(std::iter::repeat_n(0.0, data.outputs));
            data.target_cues.push([0.0; CUE_COUNT]);
            let lips = clip.lips.get(n).copied().flatten();
            data.weights.push(if lips.is_some() {
                training.frame_weight
            } else {
                0.0
            });
            data.video.push(Some(lips.unwrap_or_default()));
            data.known.push([0.0; CONTROL_COUNT]);
        });
        data.lengths.push(clip.features.len());
    }
}

/// Appends the frames of clips with control targets (a control network's video half): their
/// targets where tracked, the controls they know, each tracked frame weighing `frame_weight`.
pub(crate) fn append_control_video(data: &mut Dataset, model: &Model, video: &ControlVideo) {
    let mut state = model.new_state();
    let mut speaker: Option<&str> = None;
    for clip in video.clips.iter() {
        if speaker != Some(clip.speaker.as_str()) {
            model.reset(&mut state);
            speaker = Some(clip.speaker.as_str());
        }
        feed_clip(model, &mut state, &clip.features, |n, input| {
            data.inputs.extend_from_slice(input);
            let target = clip.targets.get(n).copied().flatten();
            data.targets
                .extend(target.map_or([0.0; CONTROL_COUNT], |t| t.values));
            data.known
                .push(target.map_or([0.0; CONTROL_COUNT], |t| t.known));
            data.target_cues.push([0.0; CUE_COUNT]);
            data.video.push(None);
            data.weights.push(if target.is_some() {
                video.frame_weight
            } else {
                0.0
            });
        });
        data.lengths.push(clip.features.len());
    }
}

/// Feeds one clip through the model as the receiver would and hands `frame` each frame's index
/// and the network's input: frame n is described once frame n + lookahead is fed; past the end,
/// the receiver's fallback repeats the last frame. The state carries over from the clip before
/// (one speaker's clips follow each other as in one call).
fn feed_clip(
    model: &Model,
    state: &mut InferenceState,
    features: &[FrameFeatures],
    mut frame: impl FnMut(usize, &[f32]),
) {
    let silence = FrameFeatures::silent();
    let fed = features.iter().chain(std::iter::repeat_n(
        features.last().unwrap_or(&silence),
        model.lookahead,
    ));
    for (m, row) in fed.enumerate() {
        model.push_frame(state, row);
        let Some(n) = m.checked_sub(model.lookahead) else {
            continue;
        };
        if n >= features.len() {
            break;
        }
        frame(n, state.input());
    }
}

/// Copies of `utterances` whose LSPs are scaled by a random factor in `[1 - warp, 1 + warp]`
/// per utterance, kept increasing and inside (0, pi).
pub(super) fn warp_lsps(
    utterances: &[PreparedUtterance],
    warp: f32,
    rng: &mut Rng,
) -> Vec<PreparedUtterance> {
    utterances
        .iter()
        .map(|utt| {
            let mut utt = utt.clone();
            warp_frames(&mut utt.features, warp, rng);
            utt
        })
        .collect()
}
