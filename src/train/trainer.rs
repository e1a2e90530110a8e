//! Backpropagation training of the viseme network with early stopping on held-out speakers.
//!
//! Loss: per frame, the Kullback-Leibler divergence from the target weights to the softmax
//! output (soft-target cross-entropy), frames inside /p b m/ segments weighted by
//! `closure_weight`: a closure is a few frames among hundreds, and an average of closed and
//! open neighbours is never closed. Adam on shuffled mini-batches, a fixed-seed xorshift PRNG.

use std::fmt;
use std::io::Write as _;

use indicatif::{ProgressBar, ProgressStyle};

use super::augment::Rng;
use super::backprop::{Params, loss_and_gradient, model_params_mut, segment_loss_and_gradient};
use super::closure_snap::predictions;
pub use super::closure_snap::{FALSE_CLOSURE_COST, HeldOutPredictions, best_snap, snap_candidates};
use super::config::TrainConfig;
use super::dataset::{Dataset, append_control_video, append_video, build_dataset, warp_lsps};
use super::error::TrainError;
use super::init::initial_model;
use crate::lipsync::controls::{CONTROL_COUNT, CONTROL_NAMES};
use crate::lipsync::network::{
    CONTROL_MULTIPLY_ADD_BUDGET, MAX_LOOKAHEAD, MULTIPLY_ADD_BUDGET, Model, input_count,
};
use crate::train::control_targets::{ControlTarget, phone_controls, spreads};
use crate::train::corpus::{
    Corpus, CorpusError, FeatureFn, PreparedUtterance, SpeakerSplit, prepare,
};
use crate::train::eval::{Scores, score};
pub use crate::train::targets::set_targets;

/// One point of the learning curves.
#[derive(Debug, Clone, PartialEq)]
pub struct EpochStats {
    pub epoch: usize,
    pub train_loss: f64,
    pub validation_loss: f64,
    pub validation_closure_share: f64,
    pub validation_openness_r: f64,
}

#[derive(Debug, Clone)]
pub struct TrainReport {
    /// The weights of the epoch with the lowest validation loss.
    pub model: Model,
    pub split: SpeakerSplit,
    pub best_epoch: usize,
    pub curve: Vec<EpochStats>,
    pub train_frames: usize,
    pub validation_frames: usize,
    /// Scores of the chosen model on the validation speakers.
    pub validation: Scores,
}

impl fmt::Display for TrainReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let best = &self.curve[self.best_epoch.saturating_sub(1).min(self.curve.len() - 1)];
        let dynamics = match self.model.dynamics {
            Some(d) => format!(
                "peak decay {} dB/frame, {} extra energy frames",
                d.peak_decay_db, d.energy_context
            ),
            None => "off".into(),
        };
        writeln!(
            f,
            "visemes {} | context {} | dynamics {} | closure snap {} | hidden {} | {} multiply-adds/frame",
            self.model.visemes,
            self.model.context,
            dynamics,
            self.model.closure_snap,
            self.model.hidden,
            self.model.multiply_adds()
        )?;
        writeln!(
            f,
            "train {} frames ({}), validation {} frames ({})",
            self.train_frames,
            self.split.train.join(" "),
            self.validation_frames,
            self.split.validation.join(" ")
        )?;
        writeln!(
            f,
            "best epoch {} of {}: train loss {:.4}, validation loss {:.4}",
            self.best_epoch,
            self.curve.len(),
            best.train_loss,
            best.validation_loss
        )?;
        write!(
            f,
            "validation: openness r {:.3}, /p b m/ closed {:.1}% ({}/{}), false closures {:.1}%, Eq.1 {:.2}%",
            self.validation.openness_r,
            100.0 * self.validation.closure_share(),
            self.validation.closed_segments,
            self.validation.bilabial_segments,
            100.0 * self.validation.false_closure_rate,
            100.0 * self.validation.eq1_error
        )
    }
}

/// Trains on the split's training speakers, stopping early on its validation speakers.
/// `features` is the codec boundary: decoder features of one WAV file.
pub fn run(config: &TrainConfig, features: &FeatureFn) -> Result<TrainReport, TrainError> {
    let corpus = Corpus::open(&config.corpus_root)?;
    let split = match &config.split {
        Some(split) => split.clone(),
        None => SpeakerSplit::standard(&corpus)?,
    };
    let pick = |speakers: &[String]| -> Result<Vec<PreparedUtterance>, CorpusError> {
        let mut chosen = Vec::new();
        for name in speakers {
            let utts = &corpus.speaker(name)?.utterances;
            let n = config
                .utterances_per_speaker
                .unwrap_or(utts.len())
                .min(utts.len());
            chosen.extend(utts[..n].iter());
        }
        prepare(&chosen, features)
    };
    let train = pick(&split.train)?;
    let validation = pick(&split.validation)?;
    let mut report = train_on(config, &train, &validation)?;
    report.split = split;
    report.model.notes = vec![
        "Derived from the TIMIT corpus sample (Copyright 1993 Linguistic Data Consortium, CC BY-NC-SA)."
            .into(),
        format!("training speakers: {}", report.split.train.join(" ")),
        format!("validation speakers: {}", report.split.validation.join(" ")),
        format!(
            "seed {:#x}, closure weight {}, best epoch {}",
            config.seed, config.closure_weight, report.best_epoch
        ),
    ];
    Ok(report)
}

/// Trains on already prepared utterances (the split inside the report is left empty).
pub fn train_on(
    config: &TrainConfig,
    train: &[PreparedUtterance],
    validation: &[PreparedUtterance],
) -> Result<TrainReport, TrainError> {
    let mut run = Run::new(config, train)?;
    let validation_data = run.dataset(config, validation)?;
    if validation_data.frames() == 0 {
        return Err(TrainError::NoFrames);
    }
    let lips = run.lip_validation(config);
    let progress = if config.show_progress {
        ProgressBar::new(config.max_epochs as u64)
    } else {
        ProgressBar::hidden()
    };
    progress.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} epochs {elapsed} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );

    let mut curve = Vec::new();
    let mut best = (f64::INFINITY, 0usize, run.model.clone());
    for epoch in 1..=config.max_epochs {
        run.epoch(config);
        let train_loss = run.loss(config, &run.train_data);
        let validation_loss = run.loss(config, &validation_data) + run.lips_loss(config, &lips);
        let scores = score(
            &run.model.visemes,
            &config.shapes,
            validation,
            &predictions(&run.model, &validation_data),
        )?;
        curve.push(EpochStats {
            epoch,
            train_loss,
            validation_loss,
            validation_closure_share: scores.closure_share(),
            validation_openness_r: scores.openness_r,
        });
        if validation_loss < best.0 || config.keep_last {
            best = (validation_loss, epoch, run.model.clone());
        }
        progress.inc(1);
        progress.set_message(format!(
            "train {train_loss:.4} val {validation_loss:.4} closed {:.0}% r {:.3}",
            100.0 * scores.closure_share(),
            scores.openness_r
        ));
        if !config.keep_last && epoch - best.1 >= config.patience {
            break;
        }
    }
    progress.finish_and_clear();
    let (_, best_epoch, mut model) = best;
    if config.tune_closure_snap && !config.controls {
        let curve = HeldOutPredictions::new(&model, validation).snap_curve(&config.shapes)?;
        model.closure_snap = best_snap(&curve);
    }
    let validation_scores = score(
        &model.visemes,
        &config.shapes,
        validation,
        &predictions(&model, &validation_data),
    )?;
    if let Some(path) = &config.curves_csv {
        write_curves(path, &curve)?;
    }
    Ok(TrainReport {
        model,
        split: SpeakerSplit {
            train: Vec::new(),
            validation: Vec::new(),
            test: Vec::new(),
        },
        best_epoch,
        curve,
        train_frames: run.train_data.frames(),
        validation_frames: validation_data.frames(),
        validation: validation_scores,
    })
}

/// The epoch [`train_on`] would stop early at with each of `validations` as its validation
/// set, from one training: the trajectory depends on the training utterances only, so one run
/// serves every set (an inner cross-validation pairs each set with the same training data
/// twice). It trains until every set has gone `patience` epochs without a better loss.
pub fn best_epochs(
    config: &TrainConfig,
    train: &[PreparedUtterance],
    validations: &[&[PreparedUtterance]],
) -> Result<Vec<usize>, TrainError> {
    let mut run = Run::new(config, train)?;
    let data = validations
        .iter()
        .map(|v| run.dataset(config, v))
        .collect::<Result<Vec<_>, _>>()?;
    if data.iter().any(|d| d.frames() == 0) {
        return Err(TrainError::NoFrames);
    }
    let lips = run.lip_validation(config);
    // Per set: the lowest loss, its epoch, and whether the set has stopped.
    let mut best = vec![(f64::INFINITY, 0usize, false); data.len()];
    for epoch in 1..=config.max_epochs {
        run.epoch(config);
        let lips_loss = run.lips_loss(config, &lips);
        for (best, data) in best.iter_mut().zip(&data) {
            if best.2 {
                continue;
            }
            let loss = run.loss(config, data) + lips_loss;
            if loss < best.0 {
                (best.0, best.1) = (loss, epoch);
            }
            best.2 = epoch - best.1 >= config.patience;
        }
        if best.iter().all(|b| b.2) {
            break;
        }
    }
    Ok(best.into_iter().map(|(_, epoch, _)| epoch).collect())
}

/// A network and its training frames, trained one epoch at a time (Adam on shuffled
/// mini-batches).
struct Run {
    model: Model,
    train_data: Dataset,
    rng: Rng,
    order: Vec<usize>,
    segments: Vec<usize>,
    grad: Params,
    first_moment: Params,
    second_moment: Params,
    step: i32,
    /// A control network's per-control loss scale (1 / spread squared of its training targets).
    control_scale: [f32; CONTROL_COUNT],
}

impl Run {
    fn new(config: &TrainConfig, train: &[PreparedUtterance]) -> Result<Self, TrainError> {
        let inputs = input_count(config.context, config.dynamics);
        let (outputs, budget) = if config.controls {
            (CONTROL_COUNT, CONTROL_MULTIPLY_ADD_BUDGET)
        } else {
            (config.visemes.len(), MULTIPLY_ADD_BUDGET)
        };
        let cost = inputs * config.hidden + config.hidden * outputs;
        if cost > budget && !config.allow_over_budget {
            return Err(TrainError::OverBudget { cost });
        }
        if config.lookahead > config.context.min(MAX_LOOKAHEAD) {
            return Err(TrainError::BadConfig(format!(
                "look-ahead {} needs at least as many context frames and at most {MAX_LOOKAHEAD}",
                config.lookahead
            )));
        }
        if config.hidden == 0 || config.batch_size == 0 || config.max_epochs == 0 {
            return Err(TrainError::BadConfig(
                "hidden units, batch size and epochs must be positive".into(),
            ));
        }
        let mut rng = Rng::new(config.seed);
        let warped;
        let train = if config.warp > 0.0 {
            warped = warp_lsps(train, config.warp, &mut rng);
            &warped[..]
        } else {
            train
        };
        let model = initial_model(config, train, &mut rng);
        let mut train_data = prepare_frames(&model, config, train)?;
        match (&config.video, &config.control_video) {
            (_, Some(video)) if config.controls => {
                append_control_video(&mut train_data, &model, video)
            }
            (Some(video), _) if !config.controls => append_video(&mut train_data, &model, video),
            _ => {}
        }
        forget_unlearnt(&mut train_data, config);
        let control_scale = control_scale(&train_data);
        train_data.control_scale = control_scale;
        if train_data.frames() == 0 {
            return Err(TrainError::NoFrames);
        }
        Ok(Self {
            grad: Params::zeros_like(&model),
            first_moment: Params::zeros_like(&model),
            second_moment: Params::zeros_like(&model),
            order: (0..train_data.frames()).collect(),
            segments: (0..train_data.segments.len()).collect(),
            model,
            train_data,
            rng,
            step: 0,
            control_scale,
        })
    }

    fn dataset(
        &self,
        config: &TrainConfig,
        utterances: &[PreparedUtterance],
    ) -> Result<Dataset, TrainError> {
        let mut data = prepare_frames(&self.model, config, utterances)?;
        forget_unlearnt(&mut data, config);
        data.control_scale = self.control_scale;
        Ok(data)
    }

    /// The other speakers' lips of `config.lip_validation` as frames of their own.
    fn lip_validation(&self, config: &TrainConfig) -> Option<Dataset> {
        if config.controls {
            return None;
        }
        let lips = config.lip_validation.as_ref()?;
        let mut data = build_dataset(&self.model, &[], &[], 0.0, false);
        append_video(&mut data, &self.model, lips);
        Some(data)
    }

    /// Their loss, times their frame weight (0 without them).
    fn lips_loss(&self, config: &TrainConfig, lips: &Option<Dataset>) -> f64 {
        match (lips, &config.lip_validation) {
            (Some(data), Some(video)) => video.frame_weight as f64 * self.loss(config, data),
            _ => 0.0,
        }
    }

    /// The loss on `data` (frames and /p b m/ segments).
    fn loss(&self, config: &TrainConfig, data: &Dataset) -> f64 {
        let frames: Vec<usize> = (0..data.frames()).collect();
        let segments: Vec<usize> = (0..data.segments.len()).collect();
        loss_and_gradient(&self.model, data, &frames, None)
            + segment_loss_and_gradient(
                &self.model,
                data,
                &segments,
                config.segment_closure_weight,
                None,
            )
    }

    fn epoch(&mut self, config: &TrainConfig) {
        let (beta1, beta2, epsilon) = (0.9f32, 0.999f32, 1e-8f32);
        let segment_weight = config.segment_closure_weight;
        self.rng.shuffle(&mut self.order);
        for batch in self.order.chunks(config.batch_size) {
            self.grad.clear();
            loss_and_gradient(&self.model, &self.train_data, batch, Some(&mut self.grad));
            if segment_weight > 0.0 && !self.segments.is_empty() {
                let pick = (self.rng.next_u64() % self.segments.len() as u64) as usize;
                segment_loss_and_gradient(
                    &self.model,
                    &self.train_data,
                    &[pick],
                    segment_weight,
                    Some(&mut self.grad),
                );
            }
            self.step += 1;
            let correction1 = 1.0 - beta1.powi(self.step);
            let correction2 = 1.0 - beta2.powi(self.step);
            let params = model_params_mut(&mut self.model);
            let grads = self.grad.slices_mut();
            let m1 = self.first_moment.slices_mut();
            let m2 = self.second_moment.slices_mut();
            for (((p, g), m), v) in params.into_iter().zip(grads).zip(m1).zip(m2) {
                for (((p, g), m), v) in p
                    .iter_mut()
                    .zip(g.iter())
                    .zip(m.iter_mut())
                    .zip(v.iter_mut())
                {
                    *m = beta1 * *m + (1.0 - beta1) * g;
                    *v = beta2 * *v + (1.0 - beta2) * g * g;
                    *p -= config.learning_rate
                        * ((*m / correction1) / ((*v / correction2).sqrt() + epsilon)
                            + config.weight_decay * *p);
                }
            }
        }
    }
}

/// Marks the controls `config` does not teach as unknown in every frame of a control network.
fn forget_unlearnt(data: &mut Dataset, config: &TrainConfig) {
    if !config.controls {
        return;
    }
    for known in &mut data.known {
        for (k, learnt) in known.iter_mut().zip(config.learnt_controls) {
            if !learnt {
                *k = 0.0;
            }
        }
    }
}

/// Each control's loss scale: 1 / the spread of its training targets (where known, weighted
/// frames only), printed so a run shows what it weighed.
fn control_scale(data: &Dataset) -> [f32; CONTROL_COUNT] {
    let targets: Vec<ControlTarget> = (0..data.frames())
        .filter(|&n| data.weights[n] > 0.0 && data.outputs == CONTROL_COUNT)
        .map(|n| ControlTarget {
            values: std::array::from_fn(|c| data.target(n)[c]),
            known: data.known[n],
        })
        .collect();
    if targets.is_empty() {
        return [1.0; CONTROL_COUNT];
    }
    let spread = spreads(&targets);
    let shown: Vec<String> = CONTROL_NAMES
        .iter()
        .zip(spread)
        .map(|(name, s)| format!("{name} {s:.4}"))
        .collect();
    eprintln!("control targets' spread: {}", shown.join(", "));
    spread.map(|s| 1.0 / (s * s))
}

/// The frames of `utterances` as `model` sees them, with their targets and the loss's weights.
fn prepare_frames(
    model: &Model,
    config: &TrainConfig,
    utterances: &[PreparedUtterance],
) -> Result<Dataset, TrainError> {
    let targets = if model.has_control_outputs() {
        utterances
            .iter()
            .map(|u| {
                phone_controls(&u.targets)
                    .iter()
                    .flat_map(|t| t.values)
                    .collect()
            })
            .collect()
    } else {
        set_targets(&config.visemes, &config.shapes, utterances)?
    };
    let mut data = build_dataset(
        model,
        utterances,
        &targets,
        config.closure_weight,
        config.sharp_closures,
    );
    data.cue_weights = [
        config.openness_weight,
        config.width_weight,
        config.rounding_weight,
    ];
    for seg in data.labiodental.clone() {
        for w in &mut data.weights[seg] {
            *w *= config.labiodental_weight;
        }
    }
    Ok(data)
}

/// Learning curves as CSV: `epoch,train_loss,validation_loss,validation_closure_share,validation_openness_r`.
pub fn write_curves(path: &std::path::Path, curve: &[EpochStats]) -> Result<(), TrainError> {
    let io = |source| TrainError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    writeln!(
        out,
        "epoch,train_loss,validation_loss,validation_closure_share,validation_openness_r"
    )
    .map_err(io)?;
    for e in curve {
        writeln!(
            out,
            "{},{},{},{},{}",
            e.epoch,
            e.train_loss,
            e.validation_loss,
            e.validation_closure_share,
            e.validation_openness_r
        )
        .map_err(io)?;
    }
    out.flush().map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::corpus::tests::timit_root;
    use crate::train::stand_in;
    use crate::vocab::VisemeSet;

    fn tiny_data() -> (Vec<PreparedUtterance>, Vec<PreparedUtterance>) {
        let corpus = Corpus::open(&timit_root()).unwrap();
        let take = |speaker: &str, n: usize| {
            let utts: Vec<_> = corpus
                .speaker(speaker)
                .unwrap()
                .utterances
                .iter()
                .take(n)
                .collect();
            prepare(&utts, &stand_in::features_for_utterance).unwrap()
        };
        (take("dr1-fvmh0", 3), take("dr4-maeb0", 1))
    }

    /// Compares the analytic gradient `grad` of `loss` at `model` with central differences on
    /// every `stride`-th parameter of each block; returns how many it compared.
    fn assert_gradient(
        model: &Model,
        grad: &Params,
        stride: usize,
        loss: impl Fn(&Model) -> f64,
    ) -> usize {
        let h = 1e-2f32;
        let analytic = [&grad.w1, &grad.b1, &grad.w2, &grad.b2];
        let mut checked = 0;
        for (which, analytic) in analytic.iter().enumerate() {
            for i in (0..analytic.len()).step_by(stride) {
                let mut plus = model.clone();
                model_params_mut(&mut plus)[which][i] += h;
                let mut minus = model.clone();
                model_params_mut(&mut minus)[which][i] -= h;
                let numeric = (loss(&plus) - loss(&minus)) / (2.0 * h as f64);
                let a = analytic[i] as f64;
                assert!(
                    (a - numeric).abs() < 1e-3 + 2e-2 * numeric.abs(),
                    "param {which}[{i}]: backprop {a} vs numeric {numeric}"
                );
                checked += 1;
            }
        }
        checked
    }

    #[test]
    fn backprop_gradient_matches_finite_differences() {
        let (train, _) = tiny_data();
        let config = TrainConfig {
            visemes: VisemeSet::parse("PP,FF,aa,I,U").unwrap(),
            hidden: 4,
            context: 1,
            lookahead: 1,
            ..TrainConfig::default()
        };
        let mut rng = Rng::new(7);
        let mut model = initial_model(&config, &train[..1], &mut rng);
        for b in model.b1.iter_mut().chain(&mut model.b2) {
            *b = rng.next_f32() - 0.5;
        }
        let targets = set_targets(&config.visemes, &config.shapes, &train[..1]).unwrap();
        let mut data = build_dataset(&model, &train[..1], &targets, 3.0, false);
        data.cue_weights = [5.0, 3.0, 4.0];
        let frames: Vec<usize> = (0..data.frames()).step_by(7).collect();
        let mut grad = Params::zeros_like(&model);
        loss_and_gradient(&model, &data, &frames, Some(&mut grad));
        let checked = assert_gradient(&model, &grad, 5, |m| {
            loss_and_gradient(m, &data, &frames, None)
        });
        assert!(checked > 20);
    }

    #[test]
    fn video_loss_gradient_matches_finite_differences_and_pulls_towards_the_lips() {
        use crate::train::video::{VideoClip, VideoTraining};
        let (train, _) = tiny_data();
        let config = TrainConfig {
            visemes: VisemeSet::parse("PP,FF,aa,I,U").unwrap(),
            hidden: 4,
            context: 1,
            lookahead: 1,
            ..TrainConfig::default()
        };
        let mut rng = Rng::new(5);
        let mut model = initial_model(&config, &train[..1], &mut rng);
        for b in model.b1.iter_mut().chain(&mut model.b2) {
            *b = rng.next_f32() - 0.5;
        }
        let clip = |lips: &dyn Fn(usize) -> Option<[f32; 2]>| VideoClip {
            speaker: "s1".into(),
            name: "clip".into(),
            features: train[1].features.clone(),
            lips: (0..train[1].features.len()).map(lips).collect(),
        };
        let training = |clip: VideoClip| VideoTraining {
            clips: std::sync::Arc::new(vec![clip]),
            frame_weight: 2.0,
            cue_weights: [20.0, 10.0],
        };
        let targets = set_targets(&config.visemes, &config.shapes, &train[..1]).unwrap();
        let mut data = build_dataset(&model, &train[..1], &targets, 1.0, false);
        let phone_frames = data.frames();
        let varied =
            clip(&|n| (n % 3 != 0).then_some([0.1 * (n % 7) as f32, 0.05 * (n % 5) as f32]));
        append_video(&mut data, &model, &training(varied));
        assert_eq!(data.frames(), phone_frames + train[1].features.len());
        let frames: Vec<usize> = (0..data.frames()).step_by(5).collect();
        let mut grad = Params::zeros_like(&model);
        loss_and_gradient(&model, &data, &frames, Some(&mut grad));
        let checked = assert_gradient(&model, &grad, 5, |m| {
            loss_and_gradient(m, &data, &frames, None)
        });
        assert!(checked > 20);
        // Lips as wide open as aa's shape everywhere: more aa, less loss.
        let mut open_only = build_dataset(&model, &[], &[], 1.0, false);
        append_video(
            &mut open_only,
            &model,
            &training(clip(&|_| Some([1.0, 0.1]))),
        );
        let all: Vec<usize> = (0..open_only.frames()).collect();
        let before = loss_and_gradient(&model, &open_only, &all, None);
        let aa = model.visemes.position(crate::vocab::Viseme::Aa).unwrap();
        model.b2[aa] += 2.0;
        assert!(loss_and_gradient(&model, &open_only, &all, None) < 0.5 * before);
    }

    /// Three visemes, four hidden units, one context frame: quick to train and to check.
    fn small_config() -> TrainConfig {
        TrainConfig {
            visemes: VisemeSet::reduced(3).unwrap(),
            hidden: 4,
            context: 1,
            ..TrainConfig::default()
        }
    }

    #[test]
    fn look_ahead_datasets_keep_every_frame_and_see_the_next_one() {
        let (train, _) = tiny_data();
        let config = small_config();
        let mut rng = Rng::new(3);
        let causal = initial_model(&config, &train, &mut rng);
        let mut ahead = causal.clone();
        ahead.lookahead = 1;
        let targets = set_targets(&config.visemes, &config.shapes, &train).unwrap();
        let a = build_dataset(&causal, &train, &targets, 1.0, false);
        let b = build_dataset(&ahead, &train, &targets, 1.0, false);
        assert_eq!(a.frames(), b.frames());
        assert_eq!(a.target_cues, b.target_cues);
        // The look-ahead input of frame n is the causal input of frame n + 1.
        assert_eq!(b.input(0), a.input(1));
        assert_eq!(b.input(5), a.input(6));
    }

    #[test]
    fn segment_closure_gradient_matches_finite_differences() {
        let (train, _) = tiny_data();
        let config = small_config();
        let mut rng = Rng::new(11);
        let model = initial_model(&config, &train, &mut rng);
        let targets = set_targets(&config.visemes, &config.shapes, &train).unwrap();
        let data = build_dataset(&model, &train, &targets, 1.0, false);
        assert!(data.segments.len() >= 3, "{:?}", data.segments);
        let segments: Vec<usize> = (0..data.segments.len()).collect();
        let mut grad = Params::zeros_like(&model);
        let loss = segment_loss_and_gradient(&model, &data, &segments, 2.0, Some(&mut grad));
        assert!(loss > 0.0);
        let checked = assert_gradient(&model, &grad, 3, |m| {
            segment_loss_and_gradient(m, &data, &segments, 2.0, None)
        });
        assert!(checked > 20);
        // One closed frame per segment is enough: the loss falls as closures get likelier.
        let mut closing = model.clone();
        let closed = closing.closed_index().unwrap();
        closing.b2[closed] += 3.0;
        assert!(segment_loss_and_gradient(&closing, &data, &segments, 2.0, None) < loss);
    }

    #[test]
    fn neighbouring_seeds_give_different_streams() {
        let first = |seed| Rng::new(seed).next_u64();
        let values: Vec<u64> = (0..64).map(first).collect();
        for (i, a) in values.iter().enumerate() {
            assert!(values[i + 1..].iter().all(|b| b != a), "seed {i} repeats");
        }
    }

    #[test]
    fn warped_lsps_stay_ordered_inside_the_band() {
        let (train, _) = tiny_data();
        let mut rng = Rng::new(3);
        let warped = warp_lsps(&train, 0.2, &mut rng);
        let mut factors = Vec::new();
        for (a, b) in train.iter().zip(&warped) {
            assert_eq!(a.targets, b.targets);
            for (fa, fb) in a.features.iter().zip(&b.features) {
                assert!(fb.lsp.windows(2).all(|w| w[0] < w[1]), "{:?}", fb.lsp);
                assert!(fb.lsp[0] > 0.0 && fb.lsp[9] < std::f32::consts::PI);
                assert_eq!(fa.energy_db, fb.energy_db);
            }
            factors.push(b.features[40].lsp[0] / a.features[40].lsp[0]);
        }
        assert!(
            factors.iter().all(|f| (0.8..=1.2).contains(f)),
            "{factors:?}"
        );
        assert!(
            factors.iter().any(|f| (f - 1.0).abs() > 0.01),
            "{factors:?}"
        );
    }

    /// A small network on `tiny_data` that learns and stops within a few dozen epochs.
    fn tiny_config() -> TrainConfig {
        TrainConfig {
            visemes: VisemeSet::reduced(2).unwrap(),
            hidden: 6,
            context: 1,
            max_epochs: 60,
            patience: 5,
            learning_rate: 0.01,
            show_progress: false,
            ..TrainConfig::default()
        }
    }

    #[test]
    fn one_run_finds_the_epoch_each_validation_set_stops_at() {
        let (train, validation) = tiny_data();
        let config = tiny_config();
        let (fit, held) = train.split_at(2);
        let sets = [&validation[..], held];
        let epochs = best_epochs(&config, fit, &sets).unwrap();
        for (set, epoch) in sets.iter().zip(&epochs) {
            assert_eq!(train_on(&config, fit, set).unwrap().best_epoch, *epoch);
        }
        // The two sets stop apart, so each is followed on its own.
        assert_ne!(epochs[0], epochs[1], "{epochs:?}");
        assert!(matches!(
            best_epochs(&config, fit, &[&validation[..], &[]]),
            Err(TrainError::NoFrames)
        ));
    }

    #[test]
    fn early_stopping_watches_the_other_speakers_lips_when_given_them() {
        use crate::train::video::{VideoClip, VideoTraining};
        let (train, validation) = tiny_data();
        let config = tiny_config();
        let plain = train_on(&config, &train, &validation).unwrap();
        // Lips as open as aa on every frame of a voice the training never heard.
        let lips = |weight| VideoTraining {
            clips: std::sync::Arc::new(vec![VideoClip {
                speaker: "other".into(),
                name: "clip".into(),
                features: validation[0].features.clone(),
                lips: vec![Some([1.0, 0.1]); validation[0].features.len()],
            }]),
            frame_weight: weight,
            cue_weights: [20.0, 20.0],
        };
        let watched = |weight| {
            let config = TrainConfig {
                lip_validation: Some(lips(weight)),
                ..tiny_config()
            };
            train_on(&config, &train, &validation).unwrap()
        };
        let light = watched(0.5);
        // The training itself is the same; the validation loss carries the lips' loss too.
        for (p, l) in plain.curve.iter().zip(&light.curve) {
            assert_eq!(p.train_loss, l.train_loss);
            assert!(l.validation_loss > p.validation_loss, "{p:?} {l:?}");
        }
        let heavy = watched(50.0);
        let [p, l, h] = [&plain, &light, &heavy].map(|r| r.curve[0].validation_loss);
        assert!(h - p > 50.0 * (l - p), "{p} {l} {h}");
        assert!(heavy.best_epoch != plain.best_epoch || heavy.curve.len() != plain.curve.len());
    }

    #[test]
    fn control_loss_gradient_matches_finite_differences_with_partly_known_video_frames() {
        use crate::train::control_targets::{ControlClip, ControlVideo, video_controls};
        let (train, validation) = tiny_data();
        let config = TrainConfig {
            visemes: VisemeSet::parse("PP,FF,aa,I,U").unwrap(),
            hidden: 4,
            context: 1,
            lookahead: 1,
            controls: true,
            ..TrainConfig::default()
        };
        let mut rng = Rng::new(11);
        let mut model = initial_model(&config, &train[..1], &mut rng);
        assert_eq!(model.outputs(), CONTROL_COUNT);
        for b in model.b1.iter_mut().chain(&mut model.b2) {
            *b = rng.next_f32() - 0.5;
        }
        let mut data = prepare_frames(&model, &config, &train[..1]).unwrap();
        // A video clip: lips known (aperture, width, jaw), the activations not (no phones).
        let features = validation[0].features.clone();
        let lips: Vec<Option<[f32; 2]>> = (0..features.len())
            .map(|n| (n % 9 != 0).then_some([0.02 + 0.01 * (n % 7) as f32, 0.6]))
            .collect();
        let video = ControlVideo {
            clips: std::sync::Arc::new(vec![ControlClip {
                speaker: "s1".into(),
                name: "clip".into(),
                targets: video_controls(&lips, None),
                features,
            }]),
            frame_weight: 0.5,
        };
        append_control_video(&mut data, &model, &video);
        assert!(
            control_scale(&data)
                .iter()
                .all(|s| s.is_finite() && *s > 0.0)
        );
        // Unit scales keep the loss smooth enough for central differences at the helper's step.
        data.control_scale = [1.0, 4.0, 0.5, 2.0, 1.0, 3.0];
        let phone_frames = train[0].features.len();
        assert_eq!(data.known[phone_frames + 1], [1.0, 1.0, 1.0, 0.0, 0.0, 0.0]);
        let frames: Vec<usize> = (0..data.frames()).step_by(5).collect();
        let mut grad = Params::zeros_like(&model);
        loss_and_gradient(&model, &data, &frames, Some(&mut grad));
        let checked = assert_gradient(&model, &grad, 3, |m| {
            loss_and_gradient(m, &data, &frames, None)
        });
        assert!(checked > 20);
    }

    #[test]
    fn a_control_network_trains_saves_and_drives_convex_weights() {
        let (train, validation) = tiny_data();
        let config = TrainConfig {
            visemes: VisemeSet::parse("PP,FF,aa,I,U").unwrap(),
            controls: true,
            tune_closure_snap: true,
            ..tiny_config()
        };
        let report = train_on(&config, &train, &validation).unwrap();
        let (first, last) = (&report.curve[0], report.curve.last().unwrap());
        assert!(
            last.train_loss < 0.9 * first.train_loss,
            "{first:?} -> {last:?}"
        );
        let model = &report.model;
        assert!(model.has_control_outputs() && model.closure_snap == 0.0);
        assert_eq!(Model::from_text(&model.to_text()).unwrap(), *model);
        // Its validation scores read the decomposed weights: closures are found.
        assert!(
            report.validation.openness_r > 0.2,
            "{:?}",
            report.validation
        );
    }

    #[test]
    fn tiny_training_run_learns_and_stops_early() {
        let (train, validation) = tiny_data();
        let curves =
            std::env::temp_dir().join(format!("lipcall-curves-{}.csv", std::process::id()));
        let config = TrainConfig {
            curves_csv: Some(curves.clone()),
            ..tiny_config()
        };
        let report = train_on(&config, &train, &validation).unwrap();
        let first = &report.curve[0];
        let last = report.curve.last().unwrap();
        assert!(
            last.train_loss < 0.9 * first.train_loss,
            "{first:?} -> {last:?}"
        );
        let best = &report.curve[report.best_epoch - 1];
        assert!(
            report
                .curve
                .iter()
                .all(|e| e.validation_loss >= best.validation_loss)
        );
        assert!(report.curve.len() - report.best_epoch <= config.patience);
        // Output: convex weights over the chosen set, and same seed, same model.
        assert_eq!(report.model.visemes, config.visemes);
        let again = train_on(&config, &train, &validation).unwrap();
        assert_eq!(again.model, report.model);
        let csv = std::fs::read_to_string(&curves).unwrap();
        assert!(csv.starts_with("epoch,train_loss,validation_loss,"));
        assert_eq!(csv.lines().count(), report.curve.len() + 1);
        std::fs::remove_file(curves).unwrap();
    }

    #[test]
    fn over_budget_networks_are_refused() {
        let config = TrainConfig {
            hidden: 40,
            ..TrainConfig::default()
        };
        assert!(matches!(
            train_on(&config, &[], &[]),
            Err(TrainError::OverBudget { .. })
        ));
    }
}

/// Full experiments on the stand-in features (`cargo test --release --lib experiment -- --ignored
/// --nocapture`): trains on the standard split and scores the TEST speakers.
#[cfg(test)]
mod experiments {
    use super::*;
    use crate::lipsync::decompose::PointTrack;
    use crate::lipsync::mouth::VisemeShapes;
    use crate::train::corpus::tests::timit_root;
    use crate::train::eval::evaluate_prepared;
    use crate::train::stand_in;
    use crate::vocab::VisemeSet;

    #[test]
    #[ignore = "full training run, minutes in release"]
    fn experiment_standard_split() {
        let corpus = Corpus::open(&timit_root()).unwrap();
        let split = SpeakerSplit::standard(&corpus).unwrap();
        let load = |speakers: &[String]| {
            prepare(
                &corpus.utterances_of(speakers).unwrap(),
                &stand_in::features_for_utterance,
            )
            .unwrap()
        };
        let (train, validation, test) = (
            load(&split.train),
            load(&split.validation),
            load(&split.test),
        );
        let shapes = VisemeShapes::point_model();
        let mut track = PointTrack::new(shapes.point_dim(), shapes.coords());
        for utt in &train {
            let full = VisemeSet::full();
            let weights = utt.targets.weights.iter().map(|w| &w[..]);
            for frame in PointTrack::from_weights(&shapes, &full, weights)
                .unwrap()
                .frames()
            {
                track.push(frame).unwrap();
            }
        }
        println!(
            "{}",
            crate::lipsync::decompose::table_i_reduced(&track, &shapes).unwrap()
        );
        let variants: Vec<(usize, usize, usize, f32)> = std::env::var("LIPCALL_VARIANTS")
            .unwrap_or_else(|_| "6:2:10:4".into())
            .split(',')
            .map(|v| {
                let p: Vec<&str> = v.split(':').collect();
                (
                    p[0].parse().unwrap(),
                    p[1].parse().unwrap(),
                    p[2].parse().unwrap(),
                    p[3].parse().unwrap(),
                )
            })
            .collect();
        for (visemes, context, hidden, closure_weight) in variants {
            let config = TrainConfig {
                visemes: VisemeSet::reduced(visemes).unwrap(),
                context,
                hidden,
                closure_weight,
                show_progress: false,
                allow_over_budget: true,
                curves_csv: Some(std::env::temp_dir().join(format!(
                    "lipcall-curves-{visemes}-{context}-{hidden}-{closure_weight}.csv"
                ))),
                ..TrainConfig::default()
            };
            let mut report = train_on(&config, &train, &validation).unwrap();
            report.split = split.clone();
            println!(
                "== visemes {visemes} context {context} hidden {hidden} closure weight {closure_weight}"
            );
            println!("{report}");
            let on_validation = evaluate_prepared(
                &report.model,
                &validation,
                &split.validation,
                &config.shapes,
            );
            println!("{}", on_validation.unwrap());
            if std::env::var("LIPCALL_TEST").is_ok() {
                println!(
                    "{}",
                    evaluate_prepared(&report.model, &test, &split.test, &config.shapes).unwrap()
                );
            }
        }
    }
}
