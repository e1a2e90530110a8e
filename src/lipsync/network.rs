//! The per-frame network: 11 decoder features (10 LSPs + energy) of the current frame and a few
//! past ones, scaled to [-1, 1], one tanh hidden layer, and a softmax over the viseme set so the
//! output weights are convex. Inference allocates nothing.
//!
//! # Model file (text, UTF-8, fit for `include_str!`)
//!
//! ```text
//! # any number of comment lines (kept as notes), e.g. what the weights were trained on
//! lipcall-viseme-mlp 3
//! visemes PP aa I O E FF        names from the 15, in output order
//! context 2                     frames fed besides the newest one
//! lookahead 1                   (version 3) of those frames, how many lie after the frame the
//!                               output describes (0: the output describes the newest frame)
//! normalise 150 <10 numbers>    (version 3) per-speaker LSP normalisation: the running mean of
//!                               the speech frames' LSPs (over about 150 of them, starting
//!                               from the 10 prior means) is replaced by the prior; `off`
//! dynamics 0.15 6               (version 2) peak decay dB/frame, extra energy-only past frames;
//!                               `dynamics off` for the 11 raw features only
//! closure_snap 0.55             (version 2) closed-viseme weight that snaps to a full closure;
//!                               0 = off; optionally followed by `nlsf 0.6 analysis 0.5`, the
//!                               thresholds for rows of those feature families (else the same)
//! sharpness 1.6                 (optional; absent = 1) the logits are multiplied by this
//!                               before the softmax (the convex weights raised to this power
//!                               and renormalised), so the dominant shape leads more decisively;
//!                               from 0.25 to 4; `sharpness 1.6 open-shapes`: the closed
//!                               shape keeps its weight and only the others are sharpened
//!                               among themselves (the closures stay the closure snap's)
//! hidden 10                     hidden units
//! input_offset <11 numbers>     scaled input = clamp((x - offset) * scale, -1, 1)
//! input_scale <11 numbers>      in the order lsp1..lsp10, energy_db
//! w1 <hidden x inputs numbers>  row-major, one row per hidden unit
//! b1 <hidden numbers>
//! w2 <outputs x hidden numbers> row-major, one row per viseme
//! b2 <outputs numbers>
//! end
//! ```
//!
//! Version 1 files (no `dynamics` and `closure_snap` lines) still load, as raw-feature models;
//! version 2 files (no `lookahead` line) as models without look-ahead.
//!
//! Inputs are ordered frame by frame, newest first: the current frame's values (11 raw, or 13
//! with dynamics: the raw ones, the energy relative to a running peak and the energy change from
//! the previous frame), then the frame before, and so on; with dynamics, `energy_context` more
//! past frames' peak-relative energies follow (older frames, newest first). Numbers are written in Rust's shortest round-trip form, so a save and load
//! gives bit-identical weights. Anything malformed, missing or trailing is a [`ModelError`].

use std::fmt::Write as _;
use std::path::Path;

use crate::vocab::FeatureFamily;
use crate::vocab::LSP_COUNT;
use crate::vocab::{FrameFeatures, SILENCE_DB};
use crate::vocab::{Viseme, VisemeError, VisemeSet};

/// Features per frame: 10 LSPs and the energy.
pub const FEATURES_PER_FRAME: usize = 11;

/// How far a full closure bias moves the closure-snap threshold. On the shipped model's
/// cross-validation a move of 0.05 trades about 14 points of /p b m/ closures against 6 of
/// false closures (docs/model.md).
pub const CLOSURE_BIAS_SPAN: f32 = 0.1;

/// The lowest closure-snap threshold training tries or a bias reaches.
pub const MIN_CLOSURE_SNAP: f32 = 0.3;

/// The range of the output sharpness a model file may hold: beyond it the weights are all but
/// one-hot (or all but uniform) and no calibration would choose it.
pub const MIN_SHARPNESS: f32 = 0.25;
pub const MAX_SHARPNESS: f32 = 4.0;

/// Multiply-adds per frame the paper budgets for the network (Section III.D).
pub const MULTIPLY_ADD_BUDGET: usize = 400;

const MAGIC: &str = "lipcall-viseme-mlp";
const VERSION: &str = "3";
const VERSION_TWO: &str = "2";
const OLD_VERSION: &str = "1";
/// The largest weight, bias or scale a model file may hold.
const MAX_PARAMETER: f32 = 1.0e4;
/// Look-ahead frames a model may use: each costs 20 ms that the receiver's buffers must hide.
pub const MAX_LOOKAHEAD: usize = 2;
const MAX_CONTEXT: usize = 32;
const MAX_HIDDEN: usize = 1024;
/// Largest model file read: the largest network allowed (1024 hidden units over 32 frames of
/// context) writes about 7 MB of text.
const MAX_MODEL_BYTES: u64 = 32 << 20;

/// Per input: `scaled = clamp((x - offset) * scale, -1, 1)`.
#[derive(Debug, Clone, PartialEq)]
pub struct InputScaling {
    pub offset: [f32; FEATURES_PER_FRAME],
    pub scale: [f32; FEATURES_PER_FRAME],
}

impl InputScaling {
    /// LSPs from [0, pi] and the energy from `[energy_low_db, energy_high_db]` onto [-1, 1].
    pub fn new(energy_low_db: f32, energy_high_db: f32) -> Self {
        let half_pi = std::f32::consts::FRAC_PI_2;
        let mut offset = [half_pi; FEATURES_PER_FRAME];
        let mut scale = [1.0 / half_pi; FEATURES_PER_FRAME];
        offset[10] = 0.5 * (energy_low_db + energy_high_db);
        scale[10] = 2.0 / (energy_high_db - energy_low_db).max(1e-3);
        Self { offset, scale }
    }

    /// Writes the 11 scaled inputs of one frame into `out`.
    pub fn apply(&self, features: &FrameFeatures, out: &mut [f32]) {
        let raw = features
            .lsp
            .iter()
            .chain(std::iter::once(&features.energy_db));
        for (i, (o, &x)) in out.iter_mut().zip(raw).enumerate() {
            let scaled = (x - self.offset[i]) * self.scale[i];
            // NaN from a broken frame must not poison the history.
            *o = if scaled.is_nan() {
                0.0
            } else {
                scaled.clamp(-1.0, 1.0)
            };
        }
    }

    /// Energy in dB that maps to the scaled value `s` in [-1, 1].
    pub fn energy_db_at(&self, s: f32) -> f32 {
        self.offset[10] + s / self.scale[10]
    }
}

/// What a silent stream looks like before its first frame: evenly spread LSPs, no energy.
pub fn silence_features() -> FrameFeatures {
    let mut lsp = [0.0; 10];
    for (i, l) in lsp.iter_mut().enumerate() {
        *l = std::f32::consts::PI * (i + 1) as f32 / 11.0;
    }
    FrameFeatures {
        mode: None,
        lsp,
        energy_db: -100.0,
        family: crate::vocab::FeatureFamily::Bitstream,
    }
}

/// Stateful, causal inputs derived from the energy (model file version 2). A running peak
/// follows the loudest recent frame and falls by `peak_decay_db` per frame, so the energy
/// relative to it is independent of the talker's level and the codec's gain; the dip of a stop
/// closure shows in it and in the frame-to-frame energy change.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dynamics {
    pub peak_decay_db: f32,
    /// Past frames beyond `context` whose peak-relative energy is fed as well.
    pub energy_context: usize,
}

/// The running peak never falls below this, so leading silence reads as quiet, not as loud.
pub const PEAK_FLOOR_DB: f32 = -55.0;
/// Peak-relative energy: 0 dB maps to 1, -40 dB to -1.
const RELATIVE_SPAN_DB: f32 = 20.0;
/// Energy change per frame: +-15 dB maps to +-1.
const DELTA_SPAN_DB: f32 = 15.0;
const MAX_ENERGY_CONTEXT: usize = 64;

/// Values fed per frame: 11 raw, 13 with dynamics.
pub fn frame_width(dynamics: Option<Dynamics>) -> usize {
    FEATURES_PER_FRAME + if dynamics.is_some() { 2 } else { 0 }
}

/// A one-hidden-layer network from decoder features to convex viseme weights.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    pub visemes: VisemeSet,
    pub scaling: InputScaling,
    /// Frames fed besides the newest one.
    pub context: usize,
    /// How many of the fed frames lie after the frame the output describes: the weights of
    /// frame n come out when frame n + lookahead is pushed (at most `context`).
    pub lookahead: usize,
    /// Causal per-speaker normalisation of the LSPs (version 3).
    pub speaker_norm: Option<SpeakerNorm>,
    /// Energy-derived inputs (version 2); `None` for the paper's raw 11 features.
    pub dynamics: Option<Dynamics>,
    /// When the closed viseme's weight reaches this, the output snaps to a full closure
    /// (0 = never). A cheap causal rule: an average of closed and open is never closed.
    pub closure_snap: f32,
    /// The closure snap for rows of SILK NLSFs and of LPC analysis, where it differs from
    /// `closure_snap` (which Speex's bitstream LSPs use): each family leans its own way.
    pub nlsf_snap: Option<f32>,
    pub analysis_snap: Option<f32>,
    /// The logits are multiplied by this before the softmax: above 1 the leading shape takes
    /// more of the weight (a network trained on blended targets hedges between shapes), 1 is
    /// the network as trained. Applied before the closure snap.
    pub sharpness: f32,
    /// The sharpness leaves the closed shape's weight alone and sharpens the others among
    /// themselves (`open-shapes` in the file).
    pub sharpen_open_shapes_only: bool,
    pub hidden: usize,
    /// `hidden x inputs`, row-major.
    pub w1: Vec<f32>,
    pub b1: Vec<f32>,
    /// `outputs x hidden`, row-major.
    pub w2: Vec<f32>,
    pub b2: Vec<f32>,
    /// Free text kept as comment lines at the top of the file (provenance of the weights).
    pub notes: Vec<String>,
}

/// Per-stream state of a running model: the scaled input history, the energy tracker and
/// scratch space.
#[derive(Debug, Clone)]
pub struct InferenceState {
    input: Vec<f32>,
    hidden: Vec<f32>,
    peak_db: f32,
    previous_db: f32,
    /// Scaled peak-relative energies, newest first, `1 + context + energy_context` of them.
    relative: Vec<f32>,
    /// The speaker's running LSP means and the speech frames they have seen.
    lsp_mean: [f32; LSP_COUNT],
    speech_frames: u32,
}

/// Causal per-speaker normalisation: a voice's LSPs sit higher or lower (vocal tract length,
/// microphone, codec) as a whole. The receiver follows the speaker's mean LSPs over speech
/// frames and moves every frame by the difference to the training speakers' mean, so a new voice
/// settles within a few seconds of speech.
#[derive(Debug, Clone, PartialEq)]
pub struct SpeakerNorm {
    /// Speech frames the running mean spans once settled.
    pub frames: u32,
    /// The training speakers' mean LSPs, where every speaker starts.
    pub prior: [f32; LSP_COUNT],
}

/// The prior counts as this many speech frames of the speaker's own.
const NORM_PRIOR_FRAMES: u32 = 25;
/// Frames this far below the running peak (or below the floor) are not speech.
const NORM_SPEECH_BELOW_PEAK_DB: f32 = 25.0;
const MAX_NORM_FRAMES: u32 = 100_000;

impl SpeakerNorm {
    fn update(&self, state: &mut InferenceState, energy_db: f32, features: &mut FrameFeatures) {
        let speech = energy_db > PEAK_FLOOR_DB
            && energy_db > state.peak_db - NORM_SPEECH_BELOW_PEAK_DB
            && features.lsp.iter().all(|l| l.is_finite());
        if speech {
            state.speech_frames = state.speech_frames.saturating_add(1);
            let span = NORM_PRIOR_FRAMES + state.speech_frames.min(self.frames);
            for (m, x) in state.lsp_mean.iter_mut().zip(&features.lsp) {
                *m += (x - *m) / span as f32;
            }
        }
        for ((x, m), p) in features
            .lsp
            .iter_mut()
            .zip(&state.lsp_mean)
            .zip(&self.prior)
        {
            *x += p - m;
        }
    }
}

impl InferenceState {
    /// The network's input vector after the last frame pushed.
    pub fn input(&self) -> &[f32] {
        &self.input
    }

    /// Becomes a copy of `other` (a state of the same model) without allocating.
    pub fn copy_from(&mut self, other: &Self) {
        self.input.clone_from_slice(&other.input);
        self.hidden.clone_from_slice(&other.hidden);
        self.relative.clone_from_slice(&other.relative);
        self.peak_db = other.peak_db;
        self.previous_db = other.previous_db;
        self.lsp_mean = other.lsp_mean;
        self.speech_frames = other.speech_frames;
    }
}

impl Model {
    /// A raw-feature network with all weights zero (uniform output), to be trained.
    pub fn zeros(visemes: VisemeSet, scaling: InputScaling, context: usize, hidden: usize) -> Self {
        Self::zeros_with(visemes, scaling, context, None, hidden)
    }

    /// A network with all weights zero, with or without dynamics.
    pub fn zeros_with(
        visemes: VisemeSet,
        scaling: InputScaling,
        context: usize,
        dynamics: Option<Dynamics>,
        hidden: usize,
    ) -> Self {
        let inputs = input_count(context, dynamics);
        let outputs = visemes.len();
        Self {
            visemes,
            scaling,
            context,
            lookahead: 0,
            speaker_norm: None,
            dynamics,
            closure_snap: 0.0,
            nlsf_snap: None,
            analysis_snap: None,
            sharpness: 1.0,
            sharpen_open_shapes_only: false,
            hidden,
            w1: vec![0.0; hidden * inputs],
            b1: vec![0.0; hidden],
            w2: vec![0.0; outputs * hidden],
            b2: vec![0.0; outputs],
            notes: Vec::new(),
        }
    }

    pub fn inputs(&self) -> usize {
        input_count(self.context, self.dynamics)
    }

    pub fn outputs(&self) -> usize {
        self.visemes.len()
    }

    /// Multiply-adds of one frame through both layers.
    pub fn multiply_adds(&self) -> usize {
        self.inputs() * self.hidden + self.hidden * self.outputs()
    }

    /// The names of the visemes the output weights drive, in output order (a head must have
    /// a shape for each).
    pub fn viseme_names(&self) -> Vec<&'static str> {
        self.visemes.members().iter().map(|v| v.name()).collect()
    }

    /// Output index of the closed shape (PP, else sil) that `closure_snap` drives.
    pub fn closed_index(&self) -> Option<usize> {
        self.visemes
            .position(Viseme::PP)
            .or_else(|| self.visemes.position(Viseme::Sil))
    }

    pub fn new_state(&self) -> InferenceState {
        let relative_len = 1 + self.context + self.dynamics.map_or(0, |d| d.energy_context);
        let mut state = InferenceState {
            input: vec![0.0; self.inputs()],
            hidden: vec![0.0; self.hidden],
            peak_db: PEAK_FLOOR_DB,
            previous_db: SILENCE_DB,
            relative: vec![0.0; relative_len],
            lsp_mean: [0.0; LSP_COUNT],
            speech_frames: 0,
        };
        self.reset(&mut state);
        state
    }

    /// Forgets the history: as if the stream had been silent.
    pub fn reset(&self, state: &mut InferenceState) {
        state.peak_db = PEAK_FLOOR_DB;
        state.previous_db = SILENCE_DB;
        state.speech_frames = 0;
        if let Some(norm) = &self.speaker_norm {
            state.lsp_mean = norm.prior;
        }
        let silence = silence_features();
        let mut silent = [0.0; FEATURES_PER_FRAME + 2];
        let width = frame_width(self.dynamics);
        self.scaling
            .apply(&silence, &mut silent[..FEATURES_PER_FRAME]);
        if self.dynamics.is_some() {
            silent[FEATURES_PER_FRAME] = scale_relative(SILENCE_DB - PEAK_FLOOR_DB);
            silent[FEATURES_PER_FRAME + 1] = 0.0;
        }
        let frames = width * (1 + self.context);
        for frame in state.input[..frames].chunks_exact_mut(width) {
            frame.copy_from_slice(&silent[..width]);
        }
        state.relative.fill(silent[FEATURES_PER_FRAME]);
        state.input[frames..].fill(silent[FEATURES_PER_FRAME]);
    }

    /// Feeds one frame into the state's input vector (the history shifts by one frame).
    pub fn push_frame(&self, state: &mut InferenceState, features: &FrameFeatures) {
        let width = frame_width(self.dynamics);
        let frames = width * (1 + self.context);
        state.input.copy_within(0..frames - width, width);
        let energy = if features.energy_db.is_nan() {
            SILENCE_DB
        } else {
            features.energy_db.max(SILENCE_DB)
        };
        if let Some(dynamics) = self.dynamics {
            state.peak_db = energy
                .max(state.peak_db - dynamics.peak_decay_db)
                .max(PEAK_FLOOR_DB);
        }
        match &self.speaker_norm {
            Some(norm) => {
                let mut normalised = *features;
                norm.update(state, energy, &mut normalised);
                self.scaling
                    .apply(&normalised, &mut state.input[..FEATURES_PER_FRAME]);
            }
            None => self
                .scaling
                .apply(features, &mut state.input[..FEATURES_PER_FRAME]),
        }
        if self.dynamics.is_none() {
            return;
        }
        let relative = scale_relative(energy - state.peak_db);
        let delta = ((energy - state.previous_db) / DELTA_SPAN_DB).clamp(-1.0, 1.0);
        state.previous_db = energy;
        state.input[FEATURES_PER_FRAME] = relative;
        state.input[FEATURES_PER_FRAME + 1] = delta;
        let len = state.relative.len();
        state.relative.copy_within(0..len - 1, 1);
        state.relative[0] = relative;
        let extra = &state.relative[1 + self.context..];
        state.input[frames..].copy_from_slice(extra);
    }

    /// Feeds one frame and writes convex weights over `self.visemes` into `weights`
    /// (which must hold `self.outputs()` values). Allocates nothing.
    pub fn step(&self, state: &mut InferenceState, features: &FrameFeatures, weights: &mut [f32]) {
        self.step_with_snap(state, features, weights, self.closure_snap);
    }

    /// [`Model::step`] with another closure-snap threshold than the model's own.
    pub fn step_with_snap(
        &self,
        state: &mut InferenceState,
        features: &FrameFeatures,
        weights: &mut [f32],
        closure_snap: f32,
    ) {
        self.push_frame(state, features);
        self.infer(state, weights, closure_snap);
    }

    /// The weights for the frames already pushed (no new frame).
    pub fn infer(&self, state: &mut InferenceState, weights: &mut [f32], closure_snap: f32) {
        self.output(&state.input, &mut state.hidden, weights);
        self.snap_with(weights, closure_snap);
    }

    /// The weights the receiver uses before the closure snap: [`Model::forward`] with the
    /// model's sharpness.
    pub fn output(&self, input: &[f32], hidden: &mut [f32], weights: &mut [f32]) {
        self.logits(input, hidden, weights);
        if self.sharpness == 1.0 {
            softmax_in_place(weights);
            return;
        }
        let spared = self.spared_shape();
        // The spared shape's weight as the plain softmax gives it.
        let kept = spared.map(|c| {
            let own = weights[c];
            1.0 / weights.iter().map(|z| (z - own).exp()).sum::<f32>()
        });
        for w in weights.iter_mut() {
            *w *= self.sharpness;
        }
        spread_around(weights, spared.zip(kept));
    }

    /// The shape [`Model::sharpness`] leaves alone, if any.
    pub fn spared_shape(&self) -> Option<usize> {
        if self.sharpen_open_shapes_only {
            self.closed_index()
        } else {
            None
        }
    }

    /// The closure snap moved by `bias` in [-1, 1]: positive closes the lips more readily
    /// (every /p b m/, and more often elsewhere), negative less; 0 is the model's own balance,
    /// chosen in training. A model without the rule keeps it off at 0 and below.
    pub fn closure_snap_with_bias(&self, family: FeatureFamily, bias: f32) -> f32 {
        let bias = if bias.is_finite() {
            bias.clamp(-1.0, 1.0)
        } else {
            0.0
        };
        let own = self.closure_snap_of(family);
        if own <= 0.0 && bias <= 0.0 {
            return 0.0;
        }
        let from = if own > 0.0 { own } else { 1.0 };
        (from - CLOSURE_BIAS_SPAN * bias).clamp(MIN_CLOSURE_SNAP, 1.0)
    }

    /// The closure snap for rows of `family`.
    pub fn closure_snap_of(&self, family: FeatureFamily) -> f32 {
        match family {
            FeatureFamily::Bitstream => self.closure_snap,
            FeatureFamily::Nlsf => self.nlsf_snap.unwrap_or(self.closure_snap),
            FeatureFamily::Analysis => self.analysis_snap.unwrap_or(self.closure_snap),
        }
    }

    /// The closure rule on one frame's output weights.
    pub fn snap(&self, weights: &mut [f32]) {
        self.snap_with(weights, self.closure_snap);
    }

    /// The closure rule at another threshold than the model's own (0 = none).
    pub fn snap_with(&self, weights: &mut [f32], closure_snap: f32) {
        if closure_snap <= 0.0 {
            return;
        }
        if let Some(closed) = self.closed_index()
            && weights[closed] >= closure_snap
        {
            weights.fill(0.0);
            weights[closed] = 1.0;
        }
    }

    /// Both layers on an already scaled input vector, as trained (no sharpness, no closure
    /// rule).
    pub fn forward(&self, input: &[f32], hidden: &mut [f32], weights: &mut [f32]) {
        self.logits(input, hidden, weights);
        softmax_in_place(weights);
    }

    fn logits(&self, input: &[f32], hidden: &mut [f32], weights: &mut [f32]) {
        let inputs = input.len();
        for ((h, row), b) in hidden
            .iter_mut()
            .zip(self.w1.chunks_exact(inputs))
            .zip(&self.b1)
        {
            *h = (b + dot(row, input)).tanh();
        }
        for ((o, row), b) in weights
            .iter_mut()
            .zip(self.w2.chunks_exact(self.hidden))
            .zip(&self.b2)
        {
            *o = b + dot(row, hidden);
        }
    }

    /// The model in its text file format (version 2).
    pub fn to_text(&self) -> String {
        let mut text = String::new();
        for note in &self.notes {
            let _ = writeln!(text, "# {note}");
        }
        let _ = writeln!(text, "{MAGIC} {VERSION}");
        let _ = writeln!(text, "visemes {}", self.viseme_names().join(" "));
        let _ = writeln!(text, "context {}", self.context);
        let _ = writeln!(text, "lookahead {}", self.lookahead);
        match &self.speaker_norm {
            Some(norm) => {
                let _ = write!(text, "normalise {}", norm.frames);
                for p in norm.prior {
                    let _ = write!(text, " {p}");
                }
                text.push('\n');
            }
            None => text.push_str("normalise off\n"),
        }
        match self.dynamics {
            Some(d) => {
                let _ = writeln!(text, "dynamics {} {}", d.peak_decay_db, d.energy_context);
            }
            None => text.push_str("dynamics off\n"),
        }
        let _ = write!(text, "closure_snap {}", self.closure_snap);
        for (name, snap) in [("nlsf", self.nlsf_snap), ("analysis", self.analysis_snap)] {
            if let Some(snap) = snap {
                let _ = write!(text, " {name} {snap}");
            }
        }
        text.push('\n');
        if self.sharpness != 1.0 || self.sharpen_open_shapes_only {
            let _ = write!(text, "sharpness {}", self.sharpness);
            if self.sharpen_open_shapes_only {
                text.push_str(" open-shapes");
            }
            text.push('\n');
        }
        let _ = writeln!(text, "hidden {}", self.hidden);
        for (key, values) in [
            ("input_offset", &self.scaling.offset[..]),
            ("input_scale", &self.scaling.scale[..]),
            ("w1", &self.w1),
            ("b1", &self.b1),
            ("w2", &self.w2),
            ("b2", &self.b2),
        ] {
            text.push_str(key);
            for v in values {
                let _ = write!(text, " {v}");
            }
            text.push('\n');
        }
        text.push_str("end\n");
        text
    }

    /// Parses the text file format (versions 1 to 3).
    pub fn from_text(text: &str) -> Result<Self, ModelError> {
        let mut lines = KeyedLines::new(text);
        let mut next = |key| lines.next(key);

        let (line, version) = next(MAGIC).map_err(|e| match e {
            ModelError::UnexpectedKey { .. } | ModelError::Truncated(_) => ModelError::NotAModel,
            other => other,
        })?;
        let (version_two, version_three) = match version[..] {
            [v] if v == VERSION => (true, true),
            [v] if v == VERSION_TWO => (true, false),
            [v] if v == OLD_VERSION => (false, false),
            _ => {
                return Err(ModelError::Version {
                    line,
                    found: version.join(" "),
                });
            }
        };
        let (line, names) = next("visemes")?;
        let visemes = VisemeSet::parse(&names.join(","))
            .map_err(|error| ModelError::Visemes { line, error })?;
        let context = parse_size(next("context")?, "context", MAX_CONTEXT)?;
        let lookahead = if version_three {
            let (line, words) = next("lookahead")?;
            let lookahead = parse_size((line, words), "lookahead", MAX_LOOKAHEAD)?;
            if lookahead > context {
                return Err(ModelError::OutOfRange {
                    line,
                    key: "lookahead",
                    value: lookahead,
                    max: context,
                });
            }
            lookahead
        } else {
            0
        };
        let speaker_norm = if version_three {
            let (line, words) = next("normalise")?;
            match words[..] {
                ["off"] => None,
                [frames, ..] => {
                    let frames =
                        parse_size((line, vec![frames]), "normalise", MAX_NORM_FRAMES as usize)?;
                    let prior = parse_floats((line, words[1..].to_vec()), "normalise", LSP_COUNT)?;
                    if frames == 0
                        || prior
                            .iter()
                            .any(|p| !(0.0..=std::f32::consts::PI).contains(p))
                    {
                        return Err(ModelError::BadNumber {
                            line,
                            key: "normalise",
                            text: words.join(" "),
                        });
                    }
                    let mut norm = SpeakerNorm {
                        frames: frames as u32,
                        prior: [0.0; LSP_COUNT],
                    };
                    norm.prior.copy_from_slice(&prior);
                    Some(norm)
                }
                [] => {
                    return Err(ModelError::WrongCount {
                        line,
                        key: "normalise",
                        expected: 1 + LSP_COUNT,
                        found: 0,
                    });
                }
            }
        } else {
            None
        };
        let (dynamics, closure_snaps) = if version_two {
            let (line, words) = next("dynamics")?;
            let dynamics = match words[..] {
                ["off"] => None,
                [decay, extra] => {
                    let decay = parse_floats((line, vec![decay]), "dynamics", 1)?[0];
                    if !(0.0..=10.0).contains(&decay) {
                        return Err(ModelError::BadNumber {
                            line,
                            key: "dynamics",
                            text: decay.to_string(),
                        });
                    }
                    let energy_context = parse_size(
                        (line, vec![extra]),
                        "dynamics energy context",
                        MAX_ENERGY_CONTEXT,
                    )?;
                    Some(Dynamics {
                        peak_decay_db: decay,
                        energy_context,
                    })
                }
                _ => {
                    return Err(ModelError::WrongCount {
                        line,
                        key: "dynamics",
                        expected: 2,
                        found: words.len(),
                    });
                }
            };
            let (line, words) = next("closure_snap")?;
            (dynamics, parse_closure_snaps(line, &words)?)
        } else {
            (None, [Some(0.0), None, None])
        };
        let [closure_snap, nlsf_snap, analysis_snap] = closure_snaps;
        let closure_snap = closure_snap.unwrap_or(0.0);
        let (sharpness, sharpen_open_shapes_only) = match lines.optional("sharpness") {
            Some(found) if version_three => parse_sharpness(found)?,
            Some((line, _)) => {
                return Err(ModelError::UnexpectedKey {
                    line,
                    expected: "hidden",
                    found: "sharpness".into(),
                });
            }
            None => (1.0, false),
        };
        let mut next = |key| lines.next(key);
        let hidden = parse_size(next("hidden")?, "hidden", MAX_HIDDEN)?;
        let inputs = input_count(context, dynamics);
        let outputs = visemes.len();
        let offset = parse_floats(next("input_offset")?, "input_offset", FEATURES_PER_FRAME)?;
        let scale = parse_floats(next("input_scale")?, "input_scale", FEATURES_PER_FRAME)?;
        let w1 = parse_floats(next("w1")?, "w1", hidden * inputs)?;
        let b1 = parse_floats(next("b1")?, "b1", hidden)?;
        let w2 = parse_floats(next("w2")?, "w2", outputs * hidden)?;
        let b2 = parse_floats(next("b2")?, "b2", outputs)?;
        let (line, rest) = next("end")?;
        if !rest.is_empty() {
            return Err(ModelError::TrailingData { line });
        }
        if let Some((line, _)) = lines.rest() {
            return Err(ModelError::TrailingData { line });
        }
        let mut scaling = InputScaling::new(-1.0, 1.0);
        scaling.offset.copy_from_slice(&offset);
        scaling.scale.copy_from_slice(&scale);
        Ok(Self {
            visemes,
            scaling,
            context,
            lookahead,
            speaker_norm,
            dynamics,
            closure_snap,
            nlsf_snap,
            analysis_snap,
            sharpness,
            sharpen_open_shapes_only,
            hidden,
            w1,
            b1,
            w2,
            b2,
            notes: lines.notes,
        })
    }

    pub fn load(path: &Path) -> Result<Self, ModelError> {
        let in_file = |error| ModelError::InFile {
            path: path.display().to_string(),
            error: Box::new(error),
        };
        let bytes = crate::input::read(path, MAX_MODEL_BYTES)?;
        let text = String::from_utf8(bytes).map_err(|_| in_file(ModelError::NotAModel))?;
        Self::from_text(&text).map_err(in_file)
    }

    /// Writes the model file; a model its own loader would refuse (the NaN or huge weights of
    /// a training that diverged) is not written.
    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        let text = self.to_text();
        Self::from_text(&text).map_err(|error| ModelError::WouldNotLoad(Box::new(error)))?;
        std::fs::write(path, text).map_err(|error| ModelError::Io {
            path: path.display().to_string(),
            error,
        })
    }
}

/// A model file's lines, each read as `key value...`; comment lines are kept as notes and
/// blank lines skipped.
struct KeyedLines<'t> {
    lines: std::iter::Peekable<std::iter::Enumerate<std::str::Lines<'t>>>,
    notes: Vec<String>,
}

impl<'t> KeyedLines<'t> {
    fn new(text: &'t str) -> Self {
        Self {
            lines: text.lines().enumerate().peekable(),
            notes: Vec::new(),
        }
    }

    /// The next line that is neither a comment nor blank, left unread: (line number, text).
    fn peek(&mut self) -> Option<(usize, &'t str)> {
        while let Some(&(i, line)) = self.lines.peek() {
            let line = line.trim();
            if let Some(note) = line.strip_prefix('#') {
                self.notes.push(note.trim().to_string());
            } else if !line.is_empty() {
                return Some((i + 1, line));
            }
            self.lines.next();
        }
        None
    }

    /// The next line, which must start with `key`: its number and the words after the key.
    fn next(&mut self, key: &'static str) -> Result<(usize, Vec<&'t str>), ModelError> {
        let (line, text) = self.peek().ok_or(ModelError::Truncated(key))?;
        let mut words = text.split_whitespace();
        let found = words.next().unwrap_or_default();
        if found != key {
            return Err(ModelError::UnexpectedKey {
                line,
                expected: key,
                found: found.to_string(),
            });
        }
        self.lines.next();
        Ok((line, words.collect()))
    }

    /// The next line if it starts with `key`, else nothing read.
    fn optional(&mut self, key: &'static str) -> Option<(usize, Vec<&'t str>)> {
        let (_, text) = self.peek()?;
        if text.split_whitespace().next() != Some(key) {
            return None;
        }
        self.next(key).ok()
    }

    /// Whatever is left.
    fn rest(&mut self) -> Option<(usize, &'t str)> {
        self.peek()
    }
}

const OPEN_SHAPES_ONLY: &str = "open-shapes";

/// `sharpness G [open-shapes]`: a finite number from [`MIN_SHARPNESS`] to [`MAX_SHARPNESS`].
fn parse_sharpness((line, words): (usize, Vec<&str>)) -> Result<(f32, bool), ModelError> {
    let (word, open_shapes_only) = match words[..] {
        [word] => (word, false),
        [word, OPEN_SHAPES_ONLY] => (word, true),
        [_, other] => {
            return Err(ModelError::UnexpectedKey {
                line,
                expected: OPEN_SHAPES_ONLY,
                found: other.to_string(),
            });
        }
        _ => {
            return Err(ModelError::WrongCount {
                line,
                key: "sharpness",
                expected: 1,
                found: words.len(),
            });
        }
    };
    match word.parse::<f32>() {
        Ok(g) if (MIN_SHARPNESS..=MAX_SHARPNESS).contains(&g) => Ok((g, open_shapes_only)),
        _ => Err(ModelError::Sharpness {
            line,
            text: word.to_string(),
        }),
    }
}

/// Convex weights sharpened as [`Model::output`] does it on the logits, for outputs already
/// computed: each raised to `sharpness` and the whole renormalised (the same as the logits
/// multiplied by it, since the softmax's own normalisation cancels); with `spared`, that
/// shape keeps its weight and the others share the rest so.
pub fn sharpen(weights: &mut [f32], sharpness: f32, spared: Option<usize>) {
    if sharpness == 1.0 {
        return;
    }
    let kept = spared.map(|c| weights[c]);
    for w in weights.iter_mut() {
        *w = sharpness * w.max(f32::MIN_POSITIVE).ln();
    }
    spread_around(weights, spared.zip(kept));
}

/// The softmax of `logits`, or with `spared` = (c, w): shape c gets w and the softmax of the
/// others shares 1 - w.
fn spread_around(logits: &mut [f32], spared: Option<(usize, f32)>) {
    let Some((c, kept)) = spared else {
        softmax_in_place(logits);
        return;
    };
    if logits.len() < 2 {
        logits.fill(1.0);
        return;
    }
    logits[c] = f32::NEG_INFINITY;
    softmax_in_place(logits);
    for w in logits.iter_mut() {
        *w *= 1.0 - kept;
    }
    logits[c] = kept;
}

fn scale_relative(relative_db: f32) -> f32 {
    ((relative_db + RELATIVE_SPAN_DB) / RELATIVE_SPAN_DB).clamp(-1.0, 1.0)
}

/// Network inputs for this context and dynamics.
pub fn input_count(context: usize, dynamics: Option<Dynamics>) -> usize {
    frame_width(dynamics) * (1 + context) + dynamics.map_or(0, |d| d.energy_context)
}

/// Multiply-adds of one frame for a raw-feature network of this shape.
pub fn multiply_adds(context: usize, hidden: usize, outputs: usize) -> usize {
    FEATURES_PER_FRAME * (1 + context) * hidden + hidden * outputs
}

/// Eight independent sums, so the compiler can keep them in SIMD lanes.
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut lanes = [0.0f32; 8];
    let (chunks_a, chunks_b) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = chunks_a
        .remainder()
        .iter()
        .zip(chunks_b.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (ca, cb) in chunks_a.zip(chunks_b) {
        for i in 0..8 {
            lanes[i] += ca[i] * cb[i];
        }
    }
    lanes.iter().sum::<f32>() + tail
}

pub(crate) fn softmax_in_place(values: &mut [f32]) {
    let max = values.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let mut total = 0.0;
    for v in values.iter_mut() {
        *v = (*v - max).exp();
        total += *v;
    }
    for v in values.iter_mut() {
        *v /= total;
    }
}

fn parse_size(
    (line, words): (usize, Vec<&str>),
    key: &'static str,
    max: usize,
) -> Result<usize, ModelError> {
    let [word] = words[..] else {
        return Err(ModelError::WrongCount {
            line,
            key,
            expected: 1,
            found: words.len(),
        });
    };
    let value: usize = word.parse().map_err(|_| ModelError::BadNumber {
        line,
        key,
        text: word.to_string(),
    })?;
    if value > max || (key == "hidden" && value == 0) {
        return Err(ModelError::OutOfRange {
            line,
            key,
            value,
            max,
        });
    }
    Ok(value)
}

fn parse_floats(
    (line, words): (usize, Vec<&str>),
    key: &'static str,
    expected: usize,
) -> Result<Vec<f32>, ModelError> {
    if words.len() != expected {
        return Err(ModelError::WrongCount {
            line,
            key,
            expected,
            found: words.len(),
        });
    }
    words
        .iter()
        .map(|word| match word.parse::<f32>() {
            // Larger weights overflow the logits into NaN; no trained network comes near.
            Ok(v) if v.abs() <= MAX_PARAMETER => Ok(v),
            _ => Err(ModelError::BadNumber {
                line,
                key,
                text: word.to_string(),
            }),
        })
        .collect()
}

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("not a lipcall viseme model (the first line must be `{MAGIC} {VERSION}`)")]
    NotAModel,
    #[error("line {line}: unsupported model version {found:?} (this build reads 1 to {VERSION})")]
    Version { line: usize, found: String },
    #[error("model file ends early: `{0}` is missing")]
    Truncated(&'static str),
    #[error("line {line}: expected `{expected}`, found {found:?}")]
    UnexpectedKey {
        line: usize,
        expected: &'static str,
        found: String,
    },
    #[error("line {line}: `{key}` has {found} values, expected {expected}")]
    WrongCount {
        line: usize,
        key: &'static str,
        expected: usize,
        found: usize,
    },
    #[error("line {line}: bad number {text:?} in `{key}`")]
    BadNumber {
        line: usize,
        key: &'static str,
        text: String,
    },
    #[error("line {line}: `{key}` {value} is out of range (at most {max})")]
    OutOfRange {
        line: usize,
        key: &'static str,
        value: usize,
        max: usize,
    },
    #[error("line {line}: {error}")]
    Visemes { line: usize, error: VisemeError },
    #[error(
        "line {line}: sharpness {text:?} is not a number from {MIN_SHARPNESS} to {MAX_SHARPNESS}"
    )]
    Sharpness { line: usize, text: String },
    #[error("line {line}: data after `end`")]
    TrailingData { line: usize },
    #[error("{path}: {error}")]
    Io { path: String, error: std::io::Error },
    #[error(transparent)]
    Input(#[from] crate::input::InputError),
    #[error("the model would not load back (did training diverge?): {0}")]
    WouldNotLoad(Box<ModelError>),
    #[error("{path}: {error}")]
    InFile {
        path: String,
        error: Box<ModelError>,
    },
}

/// `closure_snap S [nlsf S] [analysis S]`: the default threshold and those of two families.
fn parse_closure_snaps(line: usize, words: &[&str]) -> Result<[Option<f32>; 3], ModelError> {
    let bad = |text: &str| ModelError::BadNumber {
        line,
        key: "closure_snap",
        text: text.to_string(),
    };
    let value = |text: &str| match text.parse::<f32>() {
        Ok(snap) if (0.0..=1.0).contains(&snap) => Ok(snap),
        _ => Err(bad(text)),
    };
    let Some((first, rest)) = words.split_first() else {
        return Err(ModelError::WrongCount {
            line,
            key: "closure_snap",
            expected: 1,
            found: 0,
        });
    };
    let mut snaps = [Some(value(first)?), None, None];
    if rest.len() % 2 != 0 {
        return Err(bad(&rest.join(" ")));
    }
    for pair in rest.chunks_exact(2) {
        let slot = match pair[0] {
            "nlsf" => 1,
            "analysis" => 2,
            other => return Err(bad(other)),
        };
        if snaps[slot].is_some() {
            return Err(bad(pair[0]));
        }
        snaps[slot] = Some(value(pair[1])?);
    }
    Ok(snaps)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_model() -> Model {
        let mut model = Model::zeros(
            VisemeSet::reduced(3).unwrap(),
            InputScaling::new(-70.0, -10.0),
            2,
            4,
        );
        let mut x = 0.37f32;
        for w in model
            .w1
            .iter_mut()
            .chain(&mut model.b1)
            .chain(&mut model.w2)
            .chain(&mut model.b2)
        {
            x = (x * 3.7 + 0.11).fract();
            *w = (x - 0.5) * 1.3e-3 / (x + 0.01);
        }
        model.notes.push("test weights".into());
        model
    }

    #[test]
    fn a_model_file_larger_than_any_model_is_not_read() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("huge.lipmodel");
        let file = std::fs::File::create(&path).unwrap();
        file.set_len(MAX_MODEL_BYTES + 1).unwrap();
        let e = Model::load(&path).unwrap_err();
        assert!(
            matches!(
                e,
                ModelError::Input(crate::input::InputError::TooLarge { .. })
            ),
            "{e}"
        );
    }

    #[test]
    fn a_model_the_loader_would_refuse_is_not_saved() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("diverged.lipmodel");
        let mut model = sample_model();
        model.w2[3] = f32::NAN;
        let e = model.save(&path).unwrap_err();
        assert!(matches!(e, ModelError::WouldNotLoad(_)), "{e}");
        assert!(e.to_string().contains("w2"), "{e}");
        assert!(!path.exists());
        model.w2[3] = 2.0 * MAX_PARAMETER;
        assert!(model.save(&path).is_err());
        model.w2[3] = 0.5;
        model.save(&path).unwrap();
        assert_eq!(Model::load(&path).unwrap().w2, model.w2);
    }

    fn frame(energy_db: f32) -> FrameFeatures {
        let mut f = silence_features();
        f.energy_db = energy_db;
        f.lsp[0] = 0.2;
        f
    }

    #[test]
    fn outputs_are_convex_and_use_the_past() {
        let model = sample_model();
        let mut state = model.new_state();
        let mut first = [0.0; 3];
        model.step(&mut state, &frame(-20.0), &mut first);
        assert!((first.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        assert!(first.iter().all(|&w| w > 0.0));
        let mut second = [0.0; 3];
        model.step(&mut state, &frame(-20.0), &mut second);
        assert_ne!(first, second, "the history changed the answer");
        model.reset(&mut state);
        model.step(&mut state, &frame(-20.0), &mut second);
        assert_eq!(first, second);
        assert_eq!(model.multiply_adds(), 33 * 4 + 4 * 3);
    }

    #[test]
    fn model_file_round_trips_exactly() {
        let model = sample_model();
        let text = model.to_text();
        assert!(text.starts_with("# test weights\nlipcall-viseme-mlp 3\nvisemes PP aa I\n"));
        assert_eq!(Model::from_text(&text).unwrap(), model);
        let mut ahead = model.clone();
        ahead.lookahead = 1;
        ahead.speaker_norm = Some(SpeakerNorm {
            frames: 150,
            prior: silence_features().lsp,
        });
        assert_eq!(Model::from_text(&ahead.to_text()).unwrap(), ahead);
        let mut families = model.clone();
        families.closure_snap = 0.6;
        families.nlsf_snap = Some(0.75);
        assert!(
            families
                .to_text()
                .contains("\nclosure_snap 0.6 nlsf 0.75\n")
        );
        assert_eq!(Model::from_text(&families.to_text()).unwrap(), families);
        families.analysis_snap = Some(0.5);
        assert_eq!(Model::from_text(&families.to_text()).unwrap(), families);
        assert_eq!(families.closure_snap_of(FeatureFamily::Bitstream), 0.6);
        assert_eq!(families.closure_snap_of(FeatureFamily::Nlsf), 0.75);
        assert_eq!(families.closure_snap_of(FeatureFamily::Analysis), 0.5);
        families.analysis_snap = None;
        assert_eq!(families.closure_snap_of(FeatureFamily::Analysis), 0.6);
    }

    #[test]
    fn sharpness_round_trips_and_one_writes_nothing() {
        let model = sample_model();
        assert_eq!(model.sharpness, 1.0);
        assert!(!model.to_text().contains("sharpness"));
        let mut sharp = model.clone();
        sharp.sharpness = 1.6;
        let text = sharp.to_text();
        assert!(
            text.contains("\nclosure_snap 0\nsharpness 1.6\nhidden 4\n"),
            "{text}"
        );
        assert_eq!(Model::from_text(&text).unwrap(), sharp);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sharp.lipmodel");
        sharp.save(&path).unwrap();
        assert_eq!(Model::load(&path).unwrap().sharpness, 1.6);
        // The shipped file reads back byte for byte.
        let shipped = crate::lipsync::builtin::shipped();
        let file = include_str!("../../assets/models/default.lipmodel");
        assert_eq!(shipped.to_text(), file);
    }

    #[test]
    fn a_bad_sharpness_is_refused_with_its_line() {
        let text = sample_model().to_text();
        let with = |line: &str| text.replacen("hidden 4\n", &format!("{line}\nhidden 4\n"), 1);
        for bad in ["0", "-1", "0.2", "4.5", "NaN", "inf", "1e39", "x"] {
            let message = Model::from_text(&with(&format!("sharpness {bad}")))
                .unwrap_err()
                .to_string();
            assert!(
                message.contains(&format!(
                    "sharpness \"{bad}\" is not a number from 0.25 to 4"
                )),
                "{message}"
            );
        }
        assert!(matches!(
            Model::from_text(&with("sharpness 1 2")),
            Err(ModelError::UnexpectedKey {
                expected: "open-shapes",
                ..
            })
        ));
        for wrong in ["sharpness", "sharpness 1 open-shapes 2"] {
            assert!(
                matches!(
                    Model::from_text(&with(wrong)),
                    Err(ModelError::WrongCount {
                        key: "sharpness",
                        ..
                    })
                ),
                "accepted {wrong:?}"
            );
        }
        // Only where the format puts it, and not twice.
        assert!(Model::from_text(&with("sharpness 2\nsharpness 2")).is_err());
        let misplaced = text.replacen("context 2\n", "context 2\nsharpness 2\n", 1);
        assert!(Model::from_text(&misplaced).is_err());
        let v2 = with("sharpness 2")
            .replace("lipcall-viseme-mlp 3", "lipcall-viseme-mlp 2")
            .replace("lookahead 0\n", "")
            .replace("normalise off\n", "");
        assert!(Model::from_text(&v2).is_err());
        // The loader names the file.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.lipmodel");
        std::fs::write(&path, with("sharpness 9")).unwrap();
        let message = Model::load(&path).unwrap_err().to_string();
        assert!(
            message.contains("bad.lipmodel") && message.contains("sharpness \"9\""),
            "{message}"
        );
        // Nor is such a model written.
        let mut model = sample_model();
        model.sharpness = f32::NAN;
        assert!(model.save(&dir.path().join("nan.lipmodel")).is_err());
    }

    #[test]
    fn sharpness_one_is_the_network_as_trained_bit_for_bit() {
        let model = sample_model();
        let mut state = model.new_state();
        let (mut stepped, mut plain) = ([0.0; 3], [0.0; 3]);
        let mut hidden = vec![0.0; model.hidden];
        for energy in [-20.0, -35.0, -12.0] {
            model.step(&mut state, &frame(energy), &mut stepped);
            model.forward(state.input(), &mut hidden, &mut plain);
            assert_eq!(stepped.map(f32::to_bits), plain.map(f32::to_bits));
        }
        let mut same = plain;
        sharpen(&mut same, 1.0, None);
        assert_eq!(same, plain);
    }

    #[test]
    fn sharpening_raises_the_dominant_weight() {
        let mut model = sample_model();
        model.b2 = vec![0.8, 0.1, -0.4];
        let mut state = model.new_state();
        let mut plain = [0.0; 3];
        model.step(&mut state, &frame(-20.0), &mut plain);
        model.sharpness = 2.0;
        let mut state = model.new_state();
        let mut sharp = [0.0; 3];
        model.step(&mut state, &frame(-20.0), &mut sharp);
        let lead = |w: &[f32; 3]| (0..3).max_by(|&a, &b| w[a].total_cmp(&w[b])).unwrap();
        assert_eq!(lead(&sharp), lead(&plain));
        assert!(
            sharp[lead(&plain)] > plain[lead(&plain)] + 0.05,
            "{plain:?} {sharp:?}"
        );
        assert!((sharp.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        // The power of the weights is the scaled logits: the tuning and the receiver agree.
        let mut powered = plain;
        sharpen(&mut powered, 2.0, None);
        for (p, s) in powered.iter().zip(&sharp) {
            assert!((p - s).abs() < 1e-6, "{powered:?} {sharp:?}");
        }
        // Below 1 it softens.
        let mut soft = plain;
        sharpen(&mut soft, 0.5, None);
        assert!(soft[lead(&plain)] < plain[lead(&plain)]);
    }

    #[test]
    fn open_shapes_sharpening_leaves_the_closed_weight_alone() {
        let mut model = sample_model();
        model.b2 = vec![0.3, 0.6, -0.2];
        let mut state = model.new_state();
        let mut plain = [0.0; 3];
        model.step(&mut state, &frame(-20.0), &mut plain);
        model.sharpness = 2.0;
        model.sharpen_open_shapes_only = true;
        let text = model.to_text();
        assert!(text.contains("\nsharpness 2 open-shapes\n"), "{text}");
        assert_eq!(Model::from_text(&text).unwrap(), model);
        let mut state = model.new_state();
        let mut sharp = [0.0; 3];
        model.step(&mut state, &frame(-20.0), &mut sharp);
        assert!((sharp[0] - plain[0]).abs() < 1e-6, "{plain:?} {sharp:?}");
        let open = |w: &[f32; 3]| w[1] / (w[1] + w[2]);
        assert!(open(&sharp) > open(&plain) + 0.05, "{plain:?} {sharp:?}");
        assert!((sharp.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        let mut powered = plain;
        sharpen(&mut powered, 2.0, model.spared_shape());
        for (p, s) in powered.iter().zip(&sharp) {
            assert!((p - s).abs() < 1e-6, "{powered:?} {sharp:?}");
        }
        let other = text.replace("open-shapes", "closed");
        assert!(Model::from_text(&other).is_err());
    }

    #[test]
    fn corrupt_model_files_are_typed_errors() {
        let text = sample_model().to_text();
        let cut = &text[..text.len() / 2];
        let truncated_at_line = cut.rfind('\n').map_or(cut, |i| &cut[..i]);
        assert!(matches!(
            Model::from_text(truncated_at_line),
            Err(ModelError::Truncated(_))
        ));
        assert!(matches!(
            Model::from_text(cut),
            Err(ModelError::WrongCount { .. } | ModelError::BadNumber { .. })
        ));
        assert!(matches!(Model::from_text(""), Err(ModelError::NotAModel)));
        assert!(matches!(
            Model::from_text("GIF89a"),
            Err(ModelError::NotAModel)
        ));
        let cases = [
            ("lipcall-viseme-mlp 3\n", "lipcall-viseme-mlp 4\n"),
            ("lookahead 0", "lookahead 3"),
            ("lookahead 0", "lookahead 1 1"),
            ("normalise off", "normalise 150 1 2"),
            ("normalise off", "normalise 0 1 2 3 4 5 6 7 8 9 10"),
            ("normalise off", "normalise"),
            ("dynamics off", "dynamics 1"),
            ("closure_snap 0", "closure_snap 2"),
            ("closure_snap 0", "closure_snap 0.5 nlsf"),
            ("closure_snap 0", "closure_snap 0.5 nlsf 1.5"),
            ("closure_snap 0", "closure_snap 0.5 speex 0.5"),
            ("closure_snap 0", "closure_snap 0.5 nlsf 0.4 nlsf 0.6"),
            ("closure_snap 0", "closure_snap"),
            ("visemes PP aa I", "visemes PP xx I"),
            ("hidden 4", "hidden 99999999"),
            ("hidden 4", "hidden 0"),
            ("context 2", "context -1"),
            ("end\n", "end\nw1 1\n"),
        ];
        for (from, to) in cases {
            let broken = text.replacen(from, to, 1);
            assert!(Model::from_text(&broken).is_err(), "accepted {to:?}");
        }
        for bad in ["1e999", "NaN", "x", "3e38"] {
            let broken: Vec<String> = text
                .lines()
                .map(|line| match line.strip_prefix("b1 ") {
                    Some(values) => {
                        let rest = values.split_once(' ').map_or("", |(_, r)| r);
                        format!("b1 {bad} {rest}")
                    }
                    None => line.to_string(),
                })
                .collect();
            let message = Model::from_text(&broken.join("\n"))
                .unwrap_err()
                .to_string();
            assert!(
                message.contains(&format!("bad number \"{bad}\" in `b1`")),
                "{message}"
            );
        }
    }

    #[test]
    fn dynamics_track_the_energy_and_closure_snap_closes() {
        let mut model = Model::zeros_with(
            VisemeSet::reduced(3).unwrap(),
            InputScaling::new(-70.0, -10.0),
            1,
            Some(Dynamics {
                peak_decay_db: 0.5,
                energy_context: 2,
            }),
            2,
        );
        assert_eq!(model.inputs(), 13 * 2 + 2);
        let mut state = model.new_state();
        let mut w = [0.0; 3];
        model.step(&mut state, &frame(-20.0), &mut w);
        // At the peak: relative energy 0 dB -> 1; a 20 dB rise clamps at +1.
        assert_eq!(&state.input()[11..13], &[1.0, 1.0]);
        model.step(&mut state, &frame(-40.0), &mut w);
        let relative = (-40.0 - (-20.5) + 20.0) / 20.0;
        assert!((state.input()[11] - relative).abs() < 1e-6);
        assert!((state.input()[12] + 1.0).abs() < 1e-6);
        // The older peak-relative energies follow the full frames.
        model.step(&mut state, &frame(-40.0), &mut w);
        assert_eq!(state.input()[26], 1.0);
        // Snap: uniform output (1/3) snaps at 0.3, not at 0.5.
        model.closure_snap = 0.5;
        model.step(&mut state, &frame(-40.0), &mut w);
        assert!((w[0] - 1.0 / 3.0).abs() < 1e-6);
        model.closure_snap = 0.3;
        model.step(&mut state, &frame(-40.0), &mut w);
        assert_eq!(w, [1.0, 0.0, 0.0]);
        assert_eq!(Model::from_text(&model.to_text()).unwrap(), model);
        assert_eq!(model.viseme_names(), ["PP", "aa", "I"]);
    }

    #[test]
    fn version_one_files_load_as_raw_feature_models() {
        let v3 = sample_model().to_text();
        let v2 = v3
            .replace("lipcall-viseme-mlp 3", "lipcall-viseme-mlp 2")
            .replace("lookahead 0\n", "")
            .replace("normalise off\n", "");
        assert_eq!(Model::from_text(&v2).unwrap(), sample_model());
        let v1 = v2
            .replace("lipcall-viseme-mlp 2", "lipcall-viseme-mlp 1")
            .replace("dynamics off\n", "")
            .replace("closure_snap 0\n", "");
        let model = Model::from_text(&v1).unwrap();
        assert_eq!(model, sample_model());
        assert_eq!(model.dynamics, None);
    }

    #[test]
    fn speaker_normalisation_takes_out_a_voices_offset_within_seconds() {
        let dynamics = Some(Dynamics {
            peak_decay_db: 0.15,
            energy_context: 0,
        });
        let mut model = Model::zeros_with(
            VisemeSet::reduced(3).unwrap(),
            InputScaling::new(-70.0, -10.0),
            0,
            dynamics,
            2,
        );
        let prior = silence_features().lsp;
        model.speaker_norm = Some(SpeakerNorm { frames: 150, prior });
        let voice = |shift: f32, n: usize| {
            let mut f = silence_features();
            f.energy_db = -25.0;
            for (i, l) in f.lsp.iter_mut().enumerate() {
                *l += shift + 0.05 * ((n + i) % 3) as f32;
            }
            f
        };
        let run = |model: &Model, shift: f32, frames: usize| {
            let mut state = model.new_state();
            for n in 0..frames {
                model.push_frame(&mut state, &voice(shift, n));
            }
            state.input()[..LSP_COUNT].to_vec()
        };
        let gap = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f32::max)
        };
        // Three seconds of speech: the lower voice's inputs meet the prior voice's.
        assert!(gap(&run(&model, 0.0, 150), &run(&model, -0.08, 150)) < 0.01);
        // Without it they stay apart.
        let mut plain = model.clone();
        plain.speaker_norm = None;
        assert!(gap(&run(&plain, 0.0, 150), &run(&plain, -0.08, 150)) > 0.05);
        // Silence does not move the mean.
        let mut state = model.new_state();
        let mut quiet = voice(-0.3, 0);
        quiet.energy_db = -90.0;
        for _ in 0..100 {
            model.push_frame(&mut state, &quiet);
        }
        assert_eq!(state.lsp_mean, prior);
    }

    #[test]
    fn scaling_clamps_and_ignores_nan() {
        let scaling = InputScaling::new(-70.0, -10.0);
        let mut out = [0.0; 11];
        let mut f = frame(0.0);
        f.lsp[1] = f32::NAN;
        scaling.apply(&f, &mut out);
        assert_eq!(out[10], 1.0);
        assert_eq!(out[1], 0.0);
        assert!((scaling.energy_db_at(0.0) + 40.0).abs() < 1e-5);
    }
}

#[cfg(test)]
mod timing {
    use super::*;

    /// `cargo test --release --lib inference_time -- --ignored --nocapture`
    #[test]
    #[ignore = "timing, meaningful in release only"]
    fn inference_time_per_frame() {
        let model = Model::zeros(
            VisemeSet::reduced(6).unwrap(),
            InputScaling::new(-70.0, -10.0),
            2,
            10,
        );
        let mut state = model.new_state();
        let mut features = silence_features();
        let mut weights = [0.0; 6];
        let frames = 1_000_000;
        let start = std::time::Instant::now();
        for n in 0..frames {
            features.energy_db = -60.0 + (n % 50) as f32;
            model.step(&mut state, std::hint::black_box(&features), &mut weights);
            std::hint::black_box(&weights);
        }
        let per_frame = start.elapsed().as_secs_f64() / frames as f64;
        println!(
            "{} multiply-adds, {:.0} ns per frame",
            model.multiply_adds(),
            per_frame * 1e9
        );
        assert!(per_frame < 1e-6);
    }
}
