//! The network's shape: [`Model`], its size and budget.

use std::sync::Arc;

use super::normalise::{Dynamics, FEATURES_PER_FRAME, InputScaling, SpeakerNorm, frame_width};
use crate::lipsync::controls::CONTROL_COUNT;
use crate::vocab::{Viseme, VisemeSet};

/// Multiply-adds per frame the paper budgets for the network (Section III.D).
pub const MULTIPLY_ADD_BUDGET: usize = 400;

/// Multiply-adds per frame issue 47 allows a network with articulatory outputs.
pub const CONTROL_MULTIPLY_ADD_BUDGET: usize = 2000;

/// What the output layer gives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OutputKind {
    /// Convex weights over the model's viseme set (a softmax), lip-sync v2.
    #[default]
    Visemes,
    /// The articulatory [`Controls`](crate::lipsync::controls::Controls) (lip-sync v4):
    /// aperture and width linear, the activations bounded to 0..1 by a logistic; the receiver
    /// turns them into weights over the viseme set by the paper's decomposition.
    Controls,
}

/// Look-ahead frames a model may use: each costs 20 ms that the receiver's buffers must hide.
pub const MAX_LOOKAHEAD: usize = 2;

/// A one-hidden-layer network from decoder features to convex viseme weights.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    /// The shapes the output drives: the softmax's, or those the controls are decomposed onto.
    pub visemes: VisemeSet,
    pub output_kind: OutputKind,
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
    /// The weights shown are a running mean of the network's: each frame's weights count
    /// `1 - smoothing`, the running mean `smoothing` (0 = none). Measured lips move smoothly
    /// where the frame-by-frame output jitters; the closure snap still reads the frame's own
    /// weights, so a closure is as quick as without it.
    pub smoothing: f32,
    pub hidden: usize,
    /// `hidden x inputs`, row-major.
    pub w1: Vec<f32>,
    pub b1: Vec<f32>,
    /// `outputs x hidden`, row-major.
    pub w2: Vec<f32>,
    pub b2: Vec<f32>,
    /// Free text kept as comment lines at the top of the file (provenance of the weights).
    pub notes: Vec<String>,
    /// A control network run beside a viseme network (lip-sync v4, issue 47): the weights and
    /// their aperture, jaw, closure and tuck stay this network's, its width and rounding are
    /// the articulation network's own (real mouths spread and round apart from the viseme).
    pub articulation: Option<Arc<Model>>,
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
            output_kind: OutputKind::Visemes,
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
            smoothing: 0.0,
            hidden,
            w1: vec![0.0; hidden * inputs],
            b1: vec![0.0; hidden],
            w2: vec![0.0; outputs * hidden],
            b2: vec![0.0; outputs],
            notes: Vec::new(),
            articulation: None,
        }
    }

    /// The same network with articulatory outputs (zero output weights), for the same set.
    pub fn with_control_outputs(mut self) -> Self {
        self.output_kind = OutputKind::Controls;
        self.w2 = vec![0.0; CONTROL_COUNT * self.hidden];
        self.b2 = vec![0.0; CONTROL_COUNT];
        self
    }

    pub fn has_control_outputs(&self) -> bool {
        self.output_kind == OutputKind::Controls
    }

    /// The most multiply-adds a network of this kind may cost.
    pub fn budget(&self) -> usize {
        match self.output_kind {
            OutputKind::Visemes => MULTIPLY_ADD_BUDGET,
            OutputKind::Controls => CONTROL_MULTIPLY_ADD_BUDGET,
        }
    }

    pub fn inputs(&self) -> usize {
        input_count(self.context, self.dynamics)
    }

    pub fn outputs(&self) -> usize {
        match self.output_kind {
            OutputKind::Visemes => self.visemes.len(),
            OutputKind::Controls => CONTROL_COUNT,
        }
    }

    /// Multiply-adds of one frame through both layers (and the articulation network's).
    pub fn multiply_adds(&self) -> usize {
        self.inputs() * self.hidden
            + self.hidden * self.outputs()
            + self.articulation.as_ref().map_or(0, |a| a.multiply_adds())
    }

    /// Multiplies a control network's width output by `gain` (its output layer's width row and
    /// bias), noted in the file: a regression's width moves less than real lips, and a head must
    /// move visibly for a viewer (or a face tracker) to follow it. No-op for viseme outputs.
    pub fn scale_width_output(&mut self, gain: f32) {
        if !self.has_control_outputs() || !gain.is_finite() {
            return;
        }
        let row = 1;
        for w in &mut self.w2[row * self.hidden..(row + 1) * self.hidden] {
            *w *= gain;
        }
        self.b2[row] *= gain;
        self.notes
            .push(format!("width output scaled by {gain} after training"));
    }

    /// Runs `articulation` beside this viseme network: its width and rounding replace those
    /// of the weights' controls. Both must see the same future frames, and together stay
    /// within the control budget.
    pub fn with_articulation(mut self, articulation: Model) -> Result<Self, String> {
        if self.has_control_outputs() || !articulation.has_control_outputs() {
            return Err(
                "an articulation network (control outputs) goes beside a viseme network".into(),
            );
        }
        if articulation.articulation.is_some() {
            return Err("an articulation network cannot carry one of its own".into());
        }
        if articulation.lookahead != self.lookahead {
            return Err(format!(
                "the articulation network looks {} frame(s) ahead, the viseme network {}",
                articulation.lookahead, self.lookahead
            ));
        }
        self.articulation = Some(Arc::new(articulation));
        let cost = self.multiply_adds();
        if cost > CONTROL_MULTIPLY_ADD_BUDGET {
            return Err(format!(
                "the two networks cost {cost} multiply-adds, over the {CONTROL_MULTIPLY_ADD_BUDGET} allowed"
            ));
        }
        Ok(self)
    }

    /// The names of the visemes the output weights drive, in output order (a head must have
    /// a shape for each).
    pub fn viseme_names(&self) -> Vec<&'static str> {
        self.visemes.members().iter().map(|v| v.name()).collect()
    }

    /// Output index of the closed shape (PP, else sil) that `closure_snap` drives; none for
    /// articulatory outputs (their closure is a control of its own).
    pub fn closed_index(&self) -> Option<usize> {
        if self.has_control_outputs() {
            return None;
        }
        self.visemes
            .position(Viseme::PP)
            .or_else(|| self.visemes.position(Viseme::Sil))
    }
}

/// Network inputs for this context and dynamics.
pub fn input_count(context: usize, dynamics: Option<Dynamics>) -> usize {
    frame_width(dynamics) * (1 + context) + dynamics.map_or(0, |d| d.energy_context)
}

/// Multiply-adds of one frame for a raw-feature network of this shape.
pub fn multiply_adds(context: usize, hidden: usize, outputs: usize) -> usize {
    FEATURES_PER_FRAME * (1 + context) * hidden + hidden * outputs
}
