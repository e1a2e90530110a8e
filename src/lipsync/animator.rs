//! What turns a stream of decoded frames into convex viseme weights: the [`Animator`] trait and
//! the trained network behind it, with its closure snap per feature family.

use std::sync::Arc;

use super::controls::{CONTROL_COUNT, Controls};
use super::network::{InferenceState, Model};
use super::viseme_controls::{self, ControlDecomposer};
use crate::vocab::FeatureFamily;
use crate::vocab::FrameFeatures;
use crate::vocab::VisemeSet;

/// Anything that turns a stream of decoded frames into convex viseme weights.
pub trait Animator {
    fn visemes(&self) -> &VisemeSet;
    /// Starts a new stream (forget the past frames).
    fn reset(&mut self);
    /// Feeds the next frame and writes weights over `self.visemes()` into `weights`: those of
    /// the frame fed `self.lookahead()` calls ago.
    fn animate(&mut self, features: &FrameFeatures, weights: &mut [f32]);
    /// Frames the output lags the input (the future frames it looks at).
    fn lookahead(&self) -> usize {
        0
    }
    /// The weights [`Animator::animate`] would write if `extra` more frames, each a repeat of
    /// the last one fed, were fed now; changes no state. The fallback for a frame whose future
    /// has not arrived in time.
    fn peek(&mut self, extra: usize, weights: &mut [f32]) {
        let _ = (extra, weights);
    }
    /// The articulatory controls behind the weights last written (by `animate` or `peek`),
    /// where the animator has them (a network with control outputs).
    fn controls(&self) -> Option<Controls> {
        None
    }
}

/// A trained model with its per-stream state.
#[derive(Debug, Clone)]
pub struct ModelAnimator<'a> {
    model: &'a Model,
    state: InferenceState,
    /// Scratch for [`Animator::peek`], so the fallback allocates nothing.
    scratch: InferenceState,
    last: FrameFeatures,
    /// The closure snap per [`FeatureFamily`] of the newest row.
    closure_snaps: [f32; 3],
    /// A network with control outputs: the decomposition onto its viseme set, the controls
    /// last shown and the weights last written (the next frame's warm start).
    decomposer: Option<Arc<ControlDecomposer>>,
    controls: [f32; CONTROL_COUNT],
    previous: Vec<f32>,
    /// The model's articulation network with its own stream state and scratch.
    articulation: Option<Articulation<'a>>,
}

/// A viseme network's articulation network running beside it ([`Model::articulation`]).
#[derive(Debug, Clone)]
struct Articulation<'a> {
    model: &'a Model,
    state: InferenceState,
    scratch: InferenceState,
    controls: [f32; CONTROL_COUNT],
}

const FAMILIES: [FeatureFamily; 3] = [
    FeatureFamily::Bitstream,
    FeatureFamily::Nlsf,
    FeatureFamily::Analysis,
];

fn family_index(family: FeatureFamily) -> usize {
    match family {
        FeatureFamily::Bitstream => 0,
        FeatureFamily::Nlsf => 1,
        FeatureFamily::Analysis => 2,
    }
}

impl<'a> ModelAnimator<'a> {
    pub fn new(model: &'a Model) -> Self {
        Self::with_closure_bias(model, 0.0)
    }

    /// With one closure-snap threshold for every family instead of the model's (0 = none).
    pub fn with_closure_snap(model: &'a Model, closure_snap: f32) -> Self {
        Self::with_snaps(model, [closure_snap; 3])
    }

    fn with_snaps(model: &'a Model, closure_snaps: [f32; 3]) -> Self {
        let state = model.new_state();
        let decomposer = model
            .has_control_outputs()
            .then(|| ControlDecomposer::new(&model.visemes).ok().map(Arc::new))
            .flatten();
        let mut previous = vec![0.0; model.visemes.len()];
        if let Some(first) = previous.first_mut() {
            *first = 1.0;
        }
        let articulation = model.articulation.as_deref().map(|a| Articulation {
            model: a,
            state: a.new_state(),
            scratch: a.new_state(),
            controls: [0.0; CONTROL_COUNT],
        });
        Self {
            model,
            scratch: state.clone(),
            state,
            last: FrameFeatures::silent(),
            closure_snaps,
            decomposer,
            controls: [0.0; CONTROL_COUNT],
            previous,
            articulation,
        }
    }

    /// Convex weights over the model's set from the controls just computed, warm-started from
    /// the last frame's (kept for the next when `keep`).
    fn decompose(&mut self, weights: &mut [f32], keep: bool) {
        let Some(decomposer) = &self.decomposer else {
            weights.copy_from_slice(&self.previous);
            return;
        };
        weights.copy_from_slice(&self.previous);
        decomposer.fit(&Controls::from_array(self.controls), weights);
        if keep {
            self.previous.copy_from_slice(weights);
        }
    }

    /// With the model's closure snaps moved by `bias` ([`Model::closure_snap_with_bias`]).
    pub fn with_closure_bias(model: &'a Model, bias: f32) -> Self {
        Self::with_snaps(
            model,
            FAMILIES.map(|family| model.closure_snap_with_bias(family, bias)),
        )
    }

    /// The closure snap for rows of `family`.
    pub fn closure_snap(&self, family: FeatureFamily) -> f32 {
        self.closure_snaps[family_index(family)]
    }
}

/// Parses a closure bias for the command line: a number from -1 to 1.
pub fn parse_closure_bias(text: &str) -> Result<f32, String> {
    match text.parse::<f32>() {
        Ok(b) if (-1.0..=1.0).contains(&b) => Ok(b),
        _ => Err(format!("{text:?} is not a number from -1 to 1")),
    }
}

impl Animator for ModelAnimator<'_> {
    fn visemes(&self) -> &VisemeSet {
        &self.model.visemes
    }

    fn reset(&mut self) {
        self.model.reset(&mut self.state);
        if let Some(a) = &mut self.articulation {
            a.model.reset(&mut a.state);
            a.controls = [0.0; CONTROL_COUNT];
        }
        self.last = FrameFeatures::silent();
        self.controls = [0.0; CONTROL_COUNT];
        self.previous.fill(0.0);
        if let Some(first) = self.previous.first_mut() {
            *first = 1.0;
        }
    }

    fn animate(&mut self, features: &FrameFeatures, weights: &mut [f32]) {
        self.last = *features;
        if self.model.has_control_outputs() {
            self.model
                .step_with_snap(&mut self.state, features, &mut self.controls, 0.0);
            self.decompose(weights, true);
            return;
        }
        let snap = self.closure_snap(features.family);
        self.model
            .step_with_snap(&mut self.state, features, weights, snap);
        if let Some(a) = &mut self.articulation {
            a.model
                .step_with_snap(&mut a.state, features, &mut a.controls, 0.0);
            self.previous.copy_from_slice(weights);
        }
    }

    fn controls(&self) -> Option<Controls> {
        if let Some(a) = &self.articulation {
            let mut controls = viseme_controls::from_weights(&self.model.visemes, &self.previous);
            let own = Controls::from_array(a.controls);
            controls.width = own.width;
            controls.rounding = own.rounding;
            return Some(controls);
        }
        self.model
            .has_control_outputs()
            .then(|| Controls::from_array(self.controls))
    }

    fn lookahead(&self) -> usize {
        self.model.lookahead
    }

    fn peek(&mut self, extra: usize, weights: &mut [f32]) {
        self.scratch.copy_from(&self.state);
        for _ in 0..extra {
            self.model.push_frame(&mut self.scratch, &self.last);
        }
        if self.model.has_control_outputs() {
            self.model.infer(&mut self.scratch, &mut self.controls, 0.0);
            self.decompose(weights, false);
            return;
        }
        let snap = self.closure_snap(self.last.family);
        self.model.infer(&mut self.scratch, weights, snap);
        if let Some(a) = &mut self.articulation {
            a.scratch.copy_from(&a.state);
            for _ in 0..extra {
                a.model.push_frame(&mut a.scratch, &self.last);
            }
            a.model.infer(&mut a.scratch, &mut a.controls, 0.0);
            self.previous.copy_from_slice(weights);
        }
    }
}

#[cfg(test)]
/// A control network of the default model's shape whose width follows the newest frame's
/// energy input and whose rounding is fixed at `rounding`.
pub(crate) fn articulation_beside(model: &Model, rounding: f32) -> Model {
    let mut a = Model::zeros_with(
        model.visemes.clone(),
        model.scaling.clone(),
        model.context,
        model.dynamics,
        1,
    )
    .with_control_outputs();
    a.lookahead = model.lookahead;
    a.speaker_norm = model.speaker_norm.clone();
    a.w1.fill(0.01);
    a.w2[1] = 0.05;
    a.b2[3] = (rounding / (1.0 - rounding)).ln();
    a
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lipsync::{default_model, network};

    #[test]
    fn closure_bias_moves_the_snap_around_the_models_own() {
        let mut model = default_model();
        let own = model.closure_snap;
        assert!(own > 0.5 && own < 1.0);
        let snap = |m: &Model, b: f32| {
            ModelAnimator::with_closure_bias(m, b).closure_snap(FeatureFamily::Bitstream)
        };
        assert_eq!(snap(&model, 0.0), own);
        assert!(snap(&model, 1.0) < own && snap(&model, -1.0) > own);
        assert_eq!(snap(&model, f32::NAN), own);
        assert_eq!(snap(&model, 7.0), snap(&model, 1.0));
        model.closure_snap = 0.0;
        assert_eq!(snap(&model, 0.0), 0.0);
        assert_eq!(snap(&model, -1.0), 0.0);
        assert!((snap(&model, 1.0) - (1.0 - network::CLOSURE_BIAS_SPAN)).abs() < 1e-6);
        assert!(parse_closure_bias("-0.5").is_ok() && parse_closure_bias("1.5").is_err());
    }

    #[test]
    fn an_articulation_network_gives_width_and_rounding_and_leaves_the_weights() {
        let plain = default_model();
        let paired = plain
            .clone()
            .with_articulation(articulation_beside(&plain, 0.7))
            .unwrap();
        assert!(paired.multiply_adds() > plain.multiply_adds());
        let (mut a, mut b) = (ModelAnimator::new(&plain), ModelAnimator::new(&paired));
        let (mut wa, mut wb) = (vec![0.0; 5], vec![0.0; 5]);
        let mut widths = Vec::new();
        for n in 0..12 {
            let mut f = FrameFeatures::silent();
            f.energy_db = -60.0 + 4.0 * n as f32;
            f.lsp = std::array::from_fn(|i| 0.25 * (i + 1) as f32 + 0.01 * (n % 3) as f32);
            a.animate(&f, &mut wa);
            b.animate(&f, &mut wb);
            assert_eq!(wa, wb, "the weights are the viseme network's");
            let own = a.controls();
            let shown = b.controls().expect("a paired model has controls");
            let derived = viseme_controls::from_weights(&plain.visemes, &wa);
            assert!(own.is_none());
            assert_eq!(shown.aperture, derived.aperture);
            assert_eq!(shown.closure, derived.closure);
            assert!((shown.rounding - 0.7).abs() < 1e-4, "{shown:?}");
            widths.push(shown.width);
        }
        assert!(widths.windows(2).any(|w| w[0] != w[1]), "{widths:?}");
        b.peek(1, &mut wb);
        a.peek(1, &mut wa);
        assert_eq!(wa, wb);
    }

    #[test]
    fn a_width_gain_scales_the_width_shown_and_nothing_else() {
        let plain = default_model();
        let art = articulation_beside(&plain, 0.4);
        let mut gained = art.clone();
        gained.scale_width_output(4.0);
        let mut viseme_net = plain.clone();
        viseme_net.scale_width_output(4.0);
        assert_eq!(viseme_net, plain, "a viseme network has no width output");
        let one = plain.clone().with_articulation(art).unwrap();
        let four = plain.clone().with_articulation(gained).unwrap();
        let (mut a, mut b) = (ModelAnimator::new(&one), ModelAnimator::new(&four));
        let mut w = vec![0.0; 5];
        let mut f = FrameFeatures::silent();
        f.energy_db = -30.0;
        f.lsp = std::array::from_fn(|i| 0.27 * (i + 1) as f32);
        a.animate(&f, &mut w);
        b.animate(&f, &mut w);
        let (x, y) = (a.controls().unwrap(), b.controls().unwrap());
        assert!(x.width.abs() > 1e-4 && (y.width - 4.0 * x.width).abs() < 1e-5);
        assert_eq!((x.aperture, x.rounding), (y.aperture, y.rounding));
    }

    #[test]
    fn articulation_networks_must_fit_beside_the_viseme_network() {
        let plain = default_model();
        let mut ahead = articulation_beside(&plain, 0.5);
        ahead.lookahead = 0;
        assert!(plain.clone().with_articulation(ahead).is_err());
        assert!(plain.clone().with_articulation(plain.clone()).is_err());
        let mut big = articulation_beside(&plain, 0.5);
        big.hidden = 60;
        big.w1 = vec![0.0; 60 * big.inputs()];
        big.b1 = vec![0.0; 60];
        big.w2 = vec![0.0; 60 * CONTROL_COUNT];
        assert!(plain.with_articulation(big).is_err());
    }

    #[test]
    fn each_feature_family_snaps_at_its_own_threshold() {
        let mut model = default_model();
        let closed = model.closed_index().unwrap();
        let mut features = FrameFeatures::silent();
        features.energy_db = -30.0;
        let mut raw = vec![0.0; model.outputs()];
        ModelAnimator::with_closure_snap(&model, 0.0).animate(&features, &mut raw);
        let p = raw[closed];
        assert!(p > 0.0 && p < 1.0, "{raw:?}");
        // Speex LSPs snap above this row's closed weight, NLSFs below it.
        model.closure_snap = p + 0.5 * (1.0 - p);
        model.nlsf_snap = Some(0.5 * p);
        model.analysis_snap = None;
        let mut weights = vec![0.0; model.outputs()];
        for (family, snapped) in [
            (FeatureFamily::Bitstream, false),
            (FeatureFamily::Analysis, false),
            (FeatureFamily::Nlsf, true),
        ] {
            features.family = family;
            ModelAnimator::new(&model).animate(&features, &mut weights);
            assert_eq!(weights[closed] == 1.0, snapped, "{family:?}: {weights:?}");
        }
        model.closure_snap = 0.9;
        model.nlsf_snap = Some(0.5);
        let biased = ModelAnimator::with_closure_bias(&model, 1.0);
        assert!((biased.closure_snap(FeatureFamily::Nlsf) - 0.4).abs() < 1e-6);
        assert!((biased.closure_snap(FeatureFamily::Analysis) - 0.8).abs() < 1e-6);
    }
}
