//! The settings of one training run: the data, the network's shape, the loss and the optimiser.
//! Every part of training reads them; they import nothing of training but the speaker split and the video clips.

use std::path::PathBuf;

use crate::lipsync::controls::CONTROL_COUNT;
use crate::lipsync::mouth::VisemeShapes;
use crate::lipsync::network::Dynamics;
use crate::train::control_targets::ControlVideo;
use crate::train::corpus::SpeakerSplit;
use crate::train::video::VideoTraining;
use crate::vocab::VisemeSet;

#[derive(Debug, Clone)]
pub struct TrainConfig {
    pub corpus_root: PathBuf,
    /// `None`: [`SpeakerSplit::standard`].
    pub split: Option<SpeakerSplit>,
    pub visemes: VisemeSet,
    /// Source of the feature points that reduced-set targets are decomposed on.
    pub shapes: VisemeShapes,
    /// Frames fed to the network besides the newest one.
    pub context: usize,
    /// How many of the fed frames lie after the frame the output describes (free look-ahead:
    /// the receiver's buffers hide it); at most `context`.
    pub lookahead: usize,
    /// Causal per-speaker LSP normalisation over about this many speech frames (`None`: off).
    pub speaker_norm_frames: Option<u32>,
    /// Energy-derived stateful inputs (`None`: the paper's raw 11 features).
    pub dynamics: Option<Dynamics>,
    /// Targets inside /p b m/ segments become a full closure (one-hot PP) instead of the
    /// coarticulated blend.
    pub sharp_closures: bool,
    /// After training, pick the closure-snap threshold on the validation speakers.
    pub tune_closure_snap: bool,
    pub hidden: usize,
    pub max_epochs: usize,
    /// Epochs without a better validation loss before stopping.
    pub patience: usize,
    /// Train exactly `max_epochs` and keep the last weights (the epoch count chosen beforehand,
    /// e.g. by cross-validation; the validation set then only draws the curves).
    pub keep_last: bool,
    pub learning_rate: f32,
    pub batch_size: usize,
    pub seed: u64,
    /// Loss weight of frames inside /p b m/ segments (1 = none).
    pub closure_weight: f32,
    /// Loss weight of frames inside /f v/ segments (1 = none): the lower lip under the teeth
    /// is a few frames of weak friction among hundreds.
    pub labiodental_weight: f32,
    /// Weight of the segment closure loss (0 = off): per /p b m/ segment, minus the log of the
    /// chance that the lips close in at least one of its frames (noisy-OR of the closed
    /// viseme's weights). It asks for one closure per segment wherever the audio shows it best,
    /// not for a closure in every frame, many of which sound like any other stop closure.
    pub segment_closure_weight: f32,
    /// Vocal-tract-length augmentation: each training utterance's LSPs are scaled by a factor
    /// drawn from `[1 - warp, 1 + warp]` (formants move with them), so the few training voices
    /// stand for longer and shorter vocal tracts too. 0 = off.
    pub warp: f32,
    /// Weight of a squared-error term on mouth openness (linear in the weights) beside the KL
    /// loss; 0 = off.
    pub openness_weight: f32,
    /// The same for lip width (spread +, narrowed -) and for rounding (protrusion).
    pub width_weight: f32,
    pub rounding_weight: f32,
    /// Decoupled weight decay per step, as a fraction of the learning rate (AdamW); 0 = off.
    pub weight_decay: f32,
    /// Utterances per speaker (all when `None`), for quick runs.
    pub utterances_per_speaker: Option<usize>,
    /// Writes the learning curves here (CSV).
    pub curves_csv: Option<PathBuf>,
    pub show_progress: bool,
    /// Accept a network costing more than [`MULTIPLY_ADD_BUDGET`](crate::lipsync::network::MULTIPLY_ADD_BUDGET) per frame.
    pub allow_over_budget: bool,
    /// Cross-validation: each fold takes its epochs from an inner cross-validation over the
    /// other groups instead of early stopping on its own held-out group.
    pub nested_fold_epochs: bool,
    /// Measured lips as a second loss term (training frames only; never validation).
    pub video: Option<VideoTraining>,
    /// Other speakers' measured lips, never trained on: early stopping watches their loss
    /// (times their frame weight) beside the held-out phones'.
    pub lip_validation: Option<VideoTraining>,
    /// The network outputs the articulatory controls (lip-sync v4) instead of viseme weights;
    /// `visemes` is then the set they are decomposed onto.
    pub controls: bool,
    /// For a control network: s1's measured lips as control targets beside the phones'.
    pub control_video: Option<ControlVideo>,
    /// For a control network: which controls the loss teaches (in `Controls::to_array` order);
    /// the others are left untrained, as for an articulation network whose aperture, jaw,
    /// closure and tuck the viseme network beside it gives.
    pub learnt_controls: [bool; CONTROL_COUNT],
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            corpus_root: PathBuf::from("../shared/data/timit-sample"),
            split: None,
            visemes: VisemeSet::reduced(6).expect("6 is a reduced set size"),
            shapes: VisemeShapes::point_model(),
            context: 2,
            lookahead: 0,
            speaker_norm_frames: None,
            dynamics: None,
            sharp_closures: false,
            tune_closure_snap: false,
            hidden: 10,
            max_epochs: 400,
            patience: 40,
            keep_last: false,
            learning_rate: 0.003,
            batch_size: 32,
            seed: 0x5EED_CAFE,
            closure_weight: 4.0,
            labiodental_weight: 1.0,
            segment_closure_weight: 0.0,
            warp: 0.0,
            weight_decay: 0.0,
            openness_weight: 0.0,
            width_weight: 0.0,
            rounding_weight: 0.0,
            utterances_per_speaker: None,
            curves_csv: None,
            show_progress: true,
            allow_over_budget: false,
            nested_fold_epochs: false,
            video: None,
            lip_validation: None,
            controls: false,
            control_video: None,
            learnt_controls: [true; CONTROL_COUNT],
        }
    }
}
