//! Decoded frames to the weights a head shows: the network (or the jaw baseline) with its
//! closure bias, one frame of free look-ahead, a still mouth in digital silence, and the
//! re-projection onto the viseme set the viewer chose. `crate::call::pipeline` wraps it with the
//! living face into the one per-peer pipeline of the app, `receive`, `animate` and evaluation,
//! so what `animate` writes and `evaluate` scores is what the app shows.
//!
//! Look-ahead: a model with `lookahead` 1 gives the weights of frame n once frame n + 1 has been
//! decoded. The jitter buffer and the output device hold at least 20 ms each, so frame n + 1 is
//! normally decoded before frame n is heard and the look-ahead costs no latency. Where it is not
//! (a loss burst, the end of a talk spurt, the jitter buffer at its floor), the caller asks for
//! [`LipSync::flush`]: the frame is animated as if its future repeated the newest frame, and the
//! network's own output for it is dropped when the real future arrives.

use std::marker::PhantomData;

use super::animator::{Animator, ModelAnimator};
use super::controls::Controls;
use super::jaw::JawBaseline;
use super::network::{MAX_LOOKAHEAD, Model};
use super::reproject::{ReprojectError, Reprojector};
use super::viseme_controls;
use crate::lipsync::mouth::VisemeShapes;
use crate::vocab::FrameFeatures;
use crate::vocab::{FullWeights, Viseme, VisemeSet};

/// Frames at or below this energy are digital silence: the mouth rests, whatever the network
/// says (quiet breath and room noise through the codec stay above -75 dB).
pub const STILL_BELOW_DB: f32 = -75.0;

/// The viewer's choices for one peer.
#[derive(Debug, Clone, PartialEq)]
pub struct LipSyncOptions {
    /// The jaw-from-energy baseline instead of the network.
    pub jaw: bool,
    /// -1 (fewer lip closures) .. 1 (more); 0 is the model's own balance.
    pub closure_bias: f32,
    /// The set the head is driven with; `None`: the network's own.
    pub visemes: Option<VisemeSet>,
}

impl Default for LipSyncOptions {
    fn default() -> Self {
        Self {
            jaw: false,
            closure_bias: 0.0,
            visemes: None,
        }
    }
}

/// One peer's weights, in stream order, each tagged with the caller's tag of its frame. The
/// animator is the model's (or the jaw's) by default; evaluation hands in one of its own.
pub struct LipSync<'m, A: Animator + ?Sized = dyn Animator + Send + 'm> {
    animator: Box<A>,
    reprojector: Reprojector,
    lookahead: usize,
    /// Frames fed whose network output has not come yet, oldest first: (tag, silent).
    pending: [(u64, bool); MAX_LOOKAHEAD + 1],
    pending_len: usize,
    /// How many of the oldest pending frames [`LipSync::flush`] has already given out.
    flushed: usize,
    raw: Vec<f32>,
    out: Vec<f32>,
    rest: Vec<f32>,
    /// A control network's controls of the frame last given out (none in silence, or from a
    /// viseme network: the weights' own are blended only when asked for).
    network_controls: Option<Controls>,
    model: PhantomData<&'m ()>,
}

/// An animator borrowed for a run (evaluation's), so a [`LipSync`] can drive it.
impl<T: Animator + ?Sized> Animator for &mut T {
    fn visemes(&self) -> &VisemeSet {
        (**self).visemes()
    }

    fn reset(&mut self) {
        (**self).reset();
    }

    fn animate(&mut self, features: &FrameFeatures, weights: &mut [f32]) {
        (**self).animate(features, weights);
    }

    fn lookahead(&self) -> usize {
        (**self).lookahead()
    }

    fn peek(&mut self, extra: usize, weights: &mut [f32]) {
        (**self).peek(extra, weights);
    }
}

impl<'m> LipSync<'m> {
    pub fn new(model: &'m Model, options: &LipSyncOptions) -> Result<Self, ReprojectError> {
        let animator: Box<dyn Animator + Send + 'm> = if options.jaw {
            Box::new(JawBaseline::from_model(model))
        } else {
            Box::new(ModelAnimator::with_closure_bias(
                model,
                options.closure_bias,
            ))
        };
        Self::with_animator(animator, options.visemes.clone())
    }
}

impl<'m, A: Animator + ?Sized> LipSync<'m, A> {
    /// Around `animator`, re-projecting onto `visemes` (`None`: the animator's own set).
    pub fn with_animator(
        animator: Box<A>,
        visemes: Option<VisemeSet>,
    ) -> Result<Self, ReprojectError> {
        let source = animator.visemes().clone();
        let target = visemes.unwrap_or_else(|| source.clone());
        let mut rest = vec![0.0; target.len()];
        match target.position(Viseme::Sil).or(target.position(Viseme::PP)) {
            Some(i) => rest[i] = 1.0,
            None => {
                // No closed shape in the set: the closest blend of what it has.
                let project = Reprojector::new(
                    VisemeSet::full(),
                    target.clone(),
                    VisemeShapes::point_model(),
                )?;
                project.project(&Viseme::Sil.one_hot(), &mut rest);
            }
        }
        Ok(Self {
            lookahead: animator.lookahead().min(MAX_LOOKAHEAD),
            reprojector: Reprojector::new(source.clone(), target, VisemeShapes::point_model())?,
            raw: vec![0.0; source.len()],
            out: vec![0.0; rest.len()],
            rest,
            animator,
            pending: [(0, false); MAX_LOOKAHEAD + 1],
            pending_len: 0,
            flushed: 0,
            network_controls: None,
            model: PhantomData,
        })
    }

    /// The set the weights are expressed over.
    pub fn visemes(&self) -> &VisemeSet {
        self.reprojector.target()
    }

    /// Frames of look-ahead: a frame's weights come out this many frames after it was fed.
    pub fn lookahead(&self) -> usize {
        self.lookahead
    }

    /// Frames fed whose weights have not been given out.
    pub fn waiting(&self) -> usize {
        self.pending_len - self.flushed
    }

    /// Starts a new stream: forgets the history and any frame still waiting.
    pub fn reset(&mut self) {
        self.animator.reset();
        self.pending_len = 0;
        self.flushed = 0;
    }

    /// Feeds the next decoded frame. Returns the weights of the frame fed `lookahead` frames
    /// ago (at once for a model without look-ahead) with its tag, unless
    /// [`LipSync::flush`] gave that frame out already. Allocates nothing.
    pub fn push(&mut self, tag: u64, features: &FrameFeatures) -> Option<(u64, &[f32])> {
        self.animator.animate(features, &mut self.raw);
        let silent = features.energy_db.is_nan() || features.energy_db <= STILL_BELOW_DB;
        self.pending[self.pending_len] = (tag, silent);
        self.pending_len += 1;
        if self.pending_len <= self.lookahead {
            return None;
        }
        let (tag, silent) = self.pending[0];
        self.pending.copy_within(1..self.pending_len, 0);
        self.pending_len -= 1;
        if self.flushed > 0 {
            self.flushed -= 1;
            return None;
        }
        Some((tag, self.finish(silent)))
    }

    /// Gives out the oldest waiting frame now, without the future it waits for (the fallback
    /// when the next frame is late or will not come). `None` when nothing waits.
    pub fn flush(&mut self) -> Option<(u64, &[f32])> {
        if self.waiting() == 0 {
            return None;
        }
        let i = self.flushed;
        let missing = i + self.lookahead + 1 - self.pending_len;
        self.animator.peek(missing, &mut self.raw);
        self.flushed += 1;
        let (tag, silent) = self.pending[i];
        Some((tag, self.finish(silent)))
    }

    /// [`LipSync::push`] with the frame's controls ([`LipSync::controls`]).
    pub fn push_with_controls(
        &mut self,
        tag: u64,
        features: &FrameFeatures,
    ) -> Option<(u64, &[f32], Controls)> {
        let (tag, _) = self.push(tag, features)?;
        Some((tag, &self.out, self.controls()))
    }

    /// [`LipSync::flush`] with the frame's controls.
    pub fn flush_with_controls(&mut self) -> Option<(u64, &[f32], Controls)> {
        let (tag, _) = self.flush()?;
        Some((tag, &self.out, self.controls()))
    }

    /// [`LipSync::push`] with the weights spread over all 15 visemes (what a head takes).
    pub fn push_full(&mut self, tag: u64, features: &FrameFeatures) -> Option<(u64, FullWeights)> {
        let (tag, _) = self.push(tag, features)?;
        Some((tag, self.full()))
    }

    /// [`LipSync::flush`] with the weights spread over all 15 visemes.
    pub fn flush_full(&mut self) -> Option<(u64, FullWeights)> {
        let (tag, _) = self.flush()?;
        Some((tag, self.full()))
    }

    fn full(&self) -> FullWeights {
        self.reprojector.target().to_full(&self.out)
    }

    /// The articulatory controls of the frame last given out: a control network's own, else
    /// the controls of the weights shown (each viseme's measured ones, blended); rest in
    /// silence. What a head that takes controls is driven by.
    pub fn controls(&self) -> Controls {
        self.network_controls
            .unwrap_or_else(|| viseme_controls::from_weights(self.reprojector.target(), &self.out))
    }

    fn finish(&mut self, silent: bool) -> &[f32] {
        if silent {
            self.out.copy_from_slice(&self.rest);
            self.network_controls = None;
        } else {
            self.reprojector.project(&self.raw, &mut self.out);
            self.network_controls = self.animator.controls();
        }
        &self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lipsync::network::InputScaling;

    /// Weights of every frame of a stream, in order, as the receiver gives them out (the frames
    /// still waiting at the end are flushed).
    fn animate_stream(lipsync: &mut LipSync, features: &[FrameFeatures]) -> Vec<Vec<f32>> {
        let mut rows = Vec::with_capacity(features.len());
        for (n, f) in features.iter().enumerate() {
            if let Some((_, w)) = lipsync.push(n as u64, f) {
                rows.push(w.to_vec());
            }
        }
        while let Some((_, w)) = lipsync.flush() {
            rows.push(w.to_vec());
        }
        rows
    }

    fn loud(value: f32) -> FrameFeatures {
        let mut f = crate::vocab::FrameFeatures::silent();
        f.energy_db = -30.0;
        f.lsp[0] = value;
        f
    }

    /// A network whose first output follows the first LSP of the newest frame it was fed.
    fn probe_model(lookahead: usize) -> Model {
        let set = VisemeSet::parse("PP,aa").unwrap();
        let mut scaling = InputScaling::new(-1.0, 1.0);
        scaling.offset[0] = 0.0;
        scaling.scale[0] = 1.0;
        let mut model = Model::zeros(set, scaling, lookahead, 1);
        model.lookahead = lookahead;
        model.w1[0] = 2.0;
        model.w2[0] = 4.0;
        model
    }

    /// A control network over PP FF aa I U whose aperture follows the first LSP (0.1 opens
    /// it to s1's /aa/, -0.1 shuts it) and whose closure is set by the second.
    fn control_model() -> Model {
        let set = VisemeSet::parse("PP,FF,aa,I,U").unwrap();
        let mut scaling = InputScaling::new(-1.0, 1.0);
        scaling.offset[..2].fill(0.0);
        scaling.scale[..2].fill(1.0);
        let mut model = Model::zeros(set, scaling, 0, 2).with_control_outputs();
        let inputs = model.inputs();
        model.w1[0] = 1.0;
        model.w1[inputs + 1] = 1.0;
        let aa = crate::lipsync::viseme_controls::of(Viseme::Aa);
        // Output rows: aperture, width, jaw, rounding, closure, tuck (hidden units 0 and 1).
        model.w2[0] = aa.aperture / 0.1f32.tanh();
        let logit = |p: f32| (p / (1.0 - p)).ln();
        model.w2[2 * 2] = (logit(aa.jaw) + 6.0) / 0.1f32.tanh();
        model.b2[2] = -6.0;
        model.b2[3] = -6.0;
        model.w2[4 * 2 + 1] = 40.0;
        model.b2[4] = -20.0;
        model.b2[5] = -6.0;
        model
    }

    #[test]
    fn a_control_network_shows_its_controls_and_the_visemes_that_make_them() {
        let model = control_model();
        let mut lipsync = LipSync::new(&model, &LipSyncOptions::default()).unwrap();
        let aa = lipsync.visemes().position(Viseme::Aa).unwrap();
        let mut open = loud(0.1);
        open.lsp[1] = 0.0;
        let (_, w, controls) = lipsync.push_with_controls(0, &open).unwrap();
        assert!(w[aa] > 0.5, "{w:?}");
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-4);
        assert!(
            controls.aperture > 0.08 && controls.closure < 0.01,
            "{controls:?}"
        );
        let mut pressed = loud(0.0);
        pressed.lsp[1] = 1.0;
        let (_, w, controls) = lipsync.push_with_controls(1, &pressed).unwrap();
        assert!(controls.closure > 0.99, "{controls:?}");
        assert!(w[0] > 0.5, "PP leads a closure: {w:?}");
        // Digital silence: the rest, and the controls of the rest.
        let mut silent = loud(0.1);
        silent.energy_db = -90.0;
        lipsync.push(2, &silent).unwrap();
        assert_eq!(
            lipsync.controls().aperture,
            crate::lipsync::viseme_controls::of(Viseme::PP).aperture
        );
    }

    #[test]
    fn a_viseme_network_shows_the_controls_of_its_weights() {
        let model = probe_model(0);
        let mut lipsync = LipSync::new(&model, &LipSyncOptions::default()).unwrap();
        let (_, w, controls) = lipsync.push_with_controls(0, &loud(0.3)).unwrap();
        let expected = crate::lipsync::viseme_controls::from_weights(&model.visemes, w);
        assert_eq!(controls, expected);
        assert!(controls.aperture > 0.0);
    }

    #[test]
    fn look_ahead_gives_each_frame_once_in_order_with_its_own_tag() {
        let model = probe_model(1);
        let mut lipsync = LipSync::new(&model, &LipSyncOptions::default()).unwrap();
        assert_eq!(lipsync.lookahead(), 1);
        assert!(lipsync.push(10, &loud(0.1)).is_none());
        let (tag, _) = lipsync.push(11, &loud(0.2)).unwrap();
        assert_eq!(tag, 10);
        // Frame 12 is late: 11 goes out without its future, and the network's output for it
        // is dropped when 12 comes.
        assert_eq!(lipsync.flush().map(|(t, _)| t), Some(11));
        assert!(lipsync.flush().is_none());
        assert!(lipsync.push(12, &loud(0.3)).is_none());
        assert_eq!(lipsync.push(13, &loud(0.4)).map(|(t, _)| t), Some(12));
        assert_eq!(lipsync.flush().map(|(t, _)| t), Some(13));
        assert_eq!(lipsync.waiting(), 0);
    }

    #[test]
    fn the_fallback_matches_a_future_that_repeats_the_last_frame() {
        let model = probe_model(1);
        let mut a = LipSync::new(&model, &LipSyncOptions::default()).unwrap();
        let mut b = LipSync::new(&model, &LipSyncOptions::default()).unwrap();
        a.push(0, &loud(0.5));
        let flushed = a.flush().unwrap().1.to_vec();
        b.push(0, &loud(0.5));
        let repeated = b.push(1, &loud(0.5)).unwrap().1.to_vec();
        assert_eq!(flushed, repeated);
        // And the look-ahead sees the future: a different next frame changes frame 0.
        let mut c = LipSync::new(&model, &LipSyncOptions::default()).unwrap();
        c.push(0, &loud(0.5));
        assert_ne!(c.push(1, &loud(-0.5)).unwrap().1.to_vec(), repeated);
    }

    #[test]
    fn every_frame_comes_out_once_whatever_the_lookahead() {
        for lookahead in 0..=MAX_LOOKAHEAD {
            let model = probe_model(lookahead);
            let mut lipsync = LipSync::new(&model, &LipSyncOptions::default()).unwrap();
            let features: Vec<FrameFeatures> = (0..7).map(|i| loud(0.1 * i as f32)).collect();
            let rows = animate_stream(&mut lipsync, &features);
            assert_eq!(rows.len(), features.len());
            for w in rows {
                assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn the_models_sharpness_reaches_the_weights_shown() {
        let mut model = probe_model(1);
        let features: Vec<FrameFeatures> = (0..6).map(|i| loud(0.1 + 0.1 * i as f32)).collect();
        let plain = animate_stream(
            &mut LipSync::new(&model, &LipSyncOptions::default()).unwrap(),
            &features,
        );
        model.sharpness = 2.0;
        let sharp = animate_stream(
            &mut LipSync::new(&model, &LipSyncOptions::default()).unwrap(),
            &features,
        );
        for (p, s) in plain.iter().zip(&sharp) {
            let lead = p.iter().copied().fold(0.0, f32::max);
            assert!(s.iter().copied().fold(0.0, f32::max) > lead, "{p:?} {s:?}");
        }
    }

    #[test]
    fn digital_silence_is_a_still_closed_mouth() {
        let model = crate::lipsync::default_model();
        for visemes in [None, Some(VisemeSet::parse("aa,I,U").unwrap())] {
            let options = LipSyncOptions {
                visemes,
                ..LipSyncOptions::default()
            };
            let mut lipsync = LipSync::new(&model, &options).unwrap();
            let mut features: Vec<FrameFeatures> =
                (0..20).map(|i| loud(0.3 + 0.05 * i as f32)).collect();
            features.extend(std::iter::repeat_n(
                crate::vocab::FrameFeatures::silent(),
                30,
            ));
            let rows = animate_stream(&mut lipsync, &features);
            let still = &rows[20..];
            assert!(
                still.windows(2).all(|w| w[0] == w[1]),
                "the mouth moves in silence"
            );
        }
    }

    #[test]
    fn the_jaw_baseline_goes_through_the_same_pipeline() {
        let model = crate::lipsync::default_model();
        let options = LipSyncOptions {
            jaw: true,
            visemes: Some(VisemeSet::full()),
            ..LipSyncOptions::default()
        };
        let mut lipsync = LipSync::new(&model, &options).unwrap();
        assert_eq!(lipsync.lookahead(), 0);
        let (tag, w) = lipsync.push(3, &loud(0.2)).unwrap();
        assert_eq!((tag, w.len()), (3, 15));
    }
}
