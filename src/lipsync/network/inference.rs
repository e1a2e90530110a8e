//! Inference: one frame through both layers, the per-stream input history that carries the
//! context and look-ahead frames, the output sharpness and the closure snap. Allocates nothing.

use super::normalise::{
    DELTA_SPAN_DB, NORM_PRIOR_FRAMES, NORM_SPEECH_BELOW_PEAK_DB, SpeakerNorm, scale_relative,
};
use super::{FEATURES_PER_FRAME, Model, PEAK_FLOOR_DB, frame_width};
use crate::vocab::FeatureFamily;
use crate::vocab::LSP_COUNT;
use crate::vocab::{FrameFeatures, SILENCE_DB};

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

/// The most a model's output smoothing may weigh the running mean: at 0.9 a shape takes
/// about 10 frames (200 ms) to show, longer than any phone.
pub const MAX_SMOOTHING: f32 = 0.9;

/// Per-stream state of a running model: the scaled input history, the energy tracker and
/// scratch space.
#[derive(Debug, Clone)]
pub struct InferenceState {
    pub(super) input: Vec<f32>,
    pub(super) hidden: Vec<f32>,
    pub(super) peak_db: f32,
    pub(super) previous_db: f32,
    /// Scaled peak-relative energies, newest first, `1 + context + energy_context` of them.
    pub(super) relative: Vec<f32>,
    /// The speaker's running LSP means and the speech frames they have seen.
    pub(super) lsp_mean: [f32; LSP_COUNT],
    pub(super) speech_frames: u32,
    /// The running mean of the weights shown (the model's smoothing), once started.
    pub(super) smoothed: Vec<f32>,
    pub(super) smoothing_started: bool,
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
        self.smoothed.clone_from_slice(&other.smoothed);
        self.smoothing_started = other.smoothing_started;
    }
}

impl Model {
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
            smoothed: vec![0.0; self.outputs()],
            smoothing_started: false,
        };
        self.reset(&mut state);
        state
    }

    /// Forgets the history: as if the stream had been silent.
    pub fn reset(&self, state: &mut InferenceState) {
        state.peak_db = PEAK_FLOOR_DB;
        state.previous_db = SILENCE_DB;
        state.speech_frames = 0;
        state.smoothing_started = false;
        if let Some(norm) = &self.speaker_norm {
            state.lsp_mean = norm.prior;
        }
        let silence = FrameFeatures::silent();
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
        if self.smoothing > 0.0 {
            let closes = self.closes(weights, closure_snap);
            self.smooth(state, weights);
            if closes {
                self.close(weights);
            }
        } else {
            self.snap_with(weights, closure_snap);
        }
    }

    /// `weights` become the running mean of the weights shown so far (the first frame after
    /// a reset starts it). Convex weights stay convex.
    fn smooth(&self, state: &mut InferenceState, weights: &mut [f32]) {
        let keep = if state.smoothing_started {
            self.smoothing
        } else {
            0.0
        };
        state.smoothing_started = true;
        for (m, w) in state.smoothed.iter_mut().zip(weights.iter_mut()) {
            *m = keep * *m + (1.0 - keep) * *w;
            *w = *m;
        }
    }

    /// The weights the receiver uses before the closure snap: [`Model::forward`] with the
    /// model's sharpness.
    pub fn output(&self, input: &[f32], hidden: &mut [f32], weights: &mut [f32]) {
        self.logits(input, hidden, weights);
        if self.has_control_outputs() {
            activate_controls(weights);
            return;
        }
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
        if self.closes(weights, closure_snap) {
            self.close(weights);
        }
    }

    fn closes(&self, weights: &[f32], closure_snap: f32) -> bool {
        closure_snap > 0.0
            && self
                .closed_index()
                .is_some_and(|closed| weights[closed] >= closure_snap)
    }

    fn close(&self, weights: &mut [f32]) {
        if let Some(closed) = self.closed_index() {
            weights.fill(0.0);
            weights[closed] = 1.0;
        }
    }

    /// Both layers on an already scaled input vector, as trained (no sharpness, no closure
    /// rule).
    pub fn forward(&self, input: &[f32], hidden: &mut [f32], weights: &mut [f32]) {
        self.logits(input, hidden, weights);
        if self.has_control_outputs() {
            activate_controls(weights);
        } else {
            softmax_in_place(weights);
        }
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
}

/// The output layer of articulatory outputs: aperture and width (the first two) stay linear,
/// the activations pass a logistic into 0..1.
pub fn activate_controls(values: &mut [f32]) {
    for v in values.iter_mut().skip(LINEAR_CONTROLS) {
        *v = 1.0 / (1.0 + (-*v).exp());
    }
}

/// Aperture and width, in eye widths: unbounded.
pub const LINEAR_CONTROLS: usize = 2;

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

/// Eight independent sums, so the compiler can keep them in SIMD lanes.
// Without the hint, the build after the split called it out of line, once per row of each layer.
#[inline]
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

impl SpeakerNorm {
    // Without the hint, the build after the split called it out of line from push_frame.
    #[inline]
    pub(super) fn update(
        &self,
        state: &mut InferenceState,
        energy_db: f32,
        features: &mut FrameFeatures,
    ) {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lipsync::network::fixtures::{frame, sample_model};

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
    fn control_outputs_bound_the_activations_and_never_snap() {
        let mut model = sample_model().with_control_outputs();
        model.closure_snap = 0.5;
        model.sharpness = 2.0;
        model.b2 = vec![-0.3, 0.02, 30.0, -30.0, 0.0, 1.0];
        model.w2.fill(0.0);
        let mut state = model.new_state();
        let mut out = vec![0.0; model.outputs()];
        model.step(&mut state, &frame(-30.0), &mut out);
        assert_eq!(out[..2], [-0.3, 0.02]);
        assert!(out[2] > 0.999 && out[3] < 0.001 && (out[4] - 0.5).abs() < 1e-6);
        assert!(out.iter().all(|v| v.is_finite()));
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
    fn smoothing_shows_a_running_mean_but_closes_at_once() {
        let mut model = sample_model();
        let loud = frame(-20.0);
        // The frames' own weights, for a quiet lead-in and then a loud stretch.
        let stream = [frame(-60.0), frame(-60.0), loud, loud, loud];
        let own: Vec<[f32; 3]> = {
            let mut state = model.new_state();
            stream
                .iter()
                .map(|f| {
                    let mut w = [0.0; 3];
                    model.step(&mut state, f, &mut w);
                    w
                })
                .collect()
        };
        model.smoothing = 0.5;
        let mut state = model.new_state();
        let mut mean = own[0];
        for (n, (f, own)) in stream.iter().zip(&own).enumerate() {
            let mut w = [0.0; 3];
            model.step(&mut state, f, &mut w);
            if n > 0 {
                for (m, o) in mean.iter_mut().zip(own) {
                    *m = 0.5 * *m + 0.5 * o;
                }
            }
            for (w, m) in w.iter().zip(&mean) {
                assert!((w - m).abs() < 1e-6, "frame {n}: {w} vs {m}");
            }
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        }
        // A reset starts the mean again from the next frame.
        model.reset(&mut state);
        let mut first = [0.0; 3];
        model.step(&mut state, &stream[0], &mut first);
        assert_eq!(first, own[0]);
        // A frame whose own closed weight reaches the snap closes fully, smoothed or not;
        // the running mean goes on from the frame's own weights.
        let snap = own[4][0] - 1e-3;
        let mut state = model.new_state();
        let mut w = [0.0; 3];
        for f in &stream {
            model.step_with_snap(&mut state, f, &mut w, snap);
        }
        assert_eq!(w, [1.0, 0.0, 0.0]);
        assert!(state.smoothed[0] < 1.0);
    }
}

#[cfg(test)]
mod timing {
    use super::*;
    use crate::lipsync::network::InputScaling;
    use crate::vocab::VisemeSet;

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
        let mut features = FrameFeatures::silent();
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
