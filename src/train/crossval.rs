//! Model selection by speaker: k-fold cross-validation over the non-test speakers, and the
//! final model trained on all of them.
//!
//! With two validation speakers one /p b m/ segment is several points of closure share and a
//! different seed moves the scores more than most recipe changes; holding out every dialect
//! region in turn scores each recipe on all eight non-test speakers instead. The final model
//! then trains on all of them for the folds' median best epoch, with the closure-snap
//! threshold tuned on the folds' pooled held-out predictions.
//!
//! By default a fold stops early on the group it holds out, so that group chooses the fold
//! model's epoch and the pooled scores flatter the recipe (docs/model.md: openness r 0.014 on
//! the shipped recipe). With [`TrainConfig::nested_fold_epochs`] each fold's epochs come from an
//! inner cross-validation over the other groups instead, and the held-out group chooses nothing.

use std::fmt;

use crate::lipsync::network::Model;
use crate::lipsync::phones::CueClass;
use crate::train::config::TrainConfig;
use crate::train::corpus::PreparedUtterance;
use crate::train::error::TrainError;
use crate::train::eval::Scores;
use crate::train::sharpness::{Calibration, calibrate};
use crate::train::trainer::{HeldOutPredictions, TrainReport, best_epochs, train_on};

/// The speakers held out by one fold, prepared twice: as training material (codec-augmented)
/// and as held-out material (at the evaluation setting). A group with nothing held out (another
/// corpus whose labels are not good enough to score on) only ever trains.
#[derive(Debug, Clone)]
pub struct SpeakerGroup {
    pub name: String,
    pub augmented: Vec<PreparedUtterance>,
    pub held_out: Vec<PreparedUtterance>,
}

#[derive(Debug, Clone)]
pub struct FoldResult {
    pub held_out: String,
    pub best_epoch: usize,
    /// Scores on the held-out group at the pooled sharpness and closure-snap threshold.
    pub scores: Scores,
    /// The fold's model (with the pooled sharpness and closure snap).
    pub model: Model,
}

#[derive(Debug, Clone)]
pub struct CrossValidation {
    pub folds: Vec<FoldResult>,
    /// All held-out predictions scored as one set.
    pub pooled: Scores,
    pub closure_snap: f32,
    /// Pooled scores at every candidate closure-snap threshold (at the chosen sharpness).
    pub snap_curve: Vec<(f32, Scores)>,
    /// The output sharpness and the closure snap, tuned together on the pooled predictions.
    pub calibration: Calibration,
    /// Median of the folds' best epochs: how long the final model trains.
    pub epochs: usize,
}

/// Trains one model per group with that group held out (early stopping on it, or for the inner
/// cross-validation's epochs when nested), in parallel on the machine's cores; the closure snap
/// is `snap` and the output sharpness `sharpness`, each tuned on the pooled held-out
/// predictions when `None` (`train::sharpness::calibrate`).
pub fn cross_validate(
    config: &TrainConfig,
    groups: &[SpeakerGroup],
    snap: Option<f32>,
    sharpness: Option<f32>,
) -> Result<CrossValidation, TrainError> {
    let folds: Vec<usize> = (0..groups.len())
        .filter(|&k| !groups[k].held_out.is_empty())
        .collect();
    let least = if config.nested_fold_epochs { 3 } else { 2 };
    if folds.len() < least {
        return Err(TrainError::BadConfig(format!(
            "cross-validation needs at least {least} speaker groups"
        )));
    }
    let fold_config = TrainConfig {
        tune_closure_snap: false,
        show_progress: false,
        curves_csv: None,
        keep_last: false,
        ..config.clone()
    };
    let training = |left_out: &[usize]| -> Vec<PreparedUtterance> {
        groups
            .iter()
            .enumerate()
            .filter(|(i, _)| !left_out.contains(i))
            .flat_map(|(_, g)| g.augmented.iter().cloned())
            .collect()
    };
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get());
    // Nested: a fold's epochs come from early stopping on the other groups in turn (an inner
    // cross-validation), so that its held-out group chooses nothing of its model. Folds k and
    // j share the inner training without both groups; one run stops on each of them.
    let pairs: Vec<(usize, usize)> = if config.nested_fold_epochs {
        folds
            .iter()
            .flat_map(|&k| folds.iter().filter(move |&&j| j > k).map(move |&j| (k, j)))
            .collect()
    } else {
        Vec::new()
    };
    let pair_epochs = in_parallel(&pairs, workers, |&(k, j)| {
        best_epochs(
            &fold_config,
            &training(&[k, j]),
            &[&groups[j].held_out, &groups[k].held_out],
        )
    })?;
    // A pair's first epoch stopped on its second group, so it is one of its first fold's
    // inner epochs, and the other way round.
    let mut inner_epochs = vec![Vec::new(); groups.len()];
    for (&(k, j), epochs) in pairs.iter().zip(&pair_epochs) {
        inner_epochs[k].push(epochs[0]);
        inner_epochs[j].push(epochs[1]);
    }
    for epochs in &mut inner_epochs {
        epochs.sort_unstable();
    }
    let train_fold = |&k: &usize| -> Result<TrainReport, TrainError> {
        if !config.nested_fold_epochs {
            return train_on(&fold_config, &training(&[k]), &groups[k].held_out);
        }
        let inner = &inner_epochs[k];
        let fixed = TrainConfig {
            max_epochs: inner.get(inner.len() / 2).copied().unwrap_or(1).max(1),
            keep_last: true,
            ..fold_config.clone()
        };
        train_on(&fixed, &training(&[k]), &groups[k].held_out)
    };
    let reports = in_parallel(&folds, workers, train_fold)?;
    let scored: Vec<&SpeakerGroup> = folds.iter().map(|&k| &groups[k]).collect();
    let held_out: Vec<HeldOutPredictions> = reports
        .iter()
        .zip(&scored)
        .map(|(r, g)| HeldOutPredictions::new(&r.model, &g.held_out))
        .collect();
    let pooled = HeldOutPredictions::pool(&held_out)?;
    // A control network's closures and sharpness are its own outputs': nothing to tune.
    let (snap, sharpness) = if config.controls {
        (Some(0.0), Some(1.0))
    } else {
        (snap, sharpness)
    };
    let calibration = calibrate(&pooled, snap, sharpness, &config.shapes)?;
    let closure_snap = calibration.closure_snap;
    let folds = held_out
        .iter()
        .zip(&scored)
        .zip(&reports)
        .map(|((predictions, group), report)| {
            let mut model = report.model.clone();
            model.closure_snap = closure_snap;
            calibration.apply(&mut model);
            Ok(FoldResult {
                held_out: group.name.clone(),
                best_epoch: report.best_epoch,
                scores: predictions
                    .sharpened(calibration.sharpness, calibration.form)
                    .scores(closure_snap, &config.shapes)?,
                model,
            })
        })
        .collect::<Result<Vec<_>, TrainError>>()?;
    let mut epochs: Vec<usize> = reports.iter().map(|r| r.best_epoch).collect();
    epochs.sort_unstable();
    Ok(CrossValidation {
        folds,
        pooled: calibration.scores.clone(),
        closure_snap,
        snap_curve: calibration.snap_curve.clone(),
        calibration,
        epochs: epochs[epochs.len() / 2].max(1),
    })
}

/// `work` on every item, `workers` at a time on scoped threads, results in the items' order.
fn in_parallel<T: Sync, R: Send>(
    items: &[T],
    workers: usize,
    work: impl Fn(&T) -> Result<R, TrainError> + Sync,
) -> Result<Vec<R>, TrainError> {
    let mut results = Vec::with_capacity(items.len());
    for chunk in items.chunks(workers.max(1)) {
        std::thread::scope(|scope| {
            let handles: Vec<_> = chunk
                .iter()
                .map(|item| scope.spawn(|| work(item)))
                .collect();
            for handle in handles {
                results.push(handle.join().unwrap_or_else(|_| {
                    Err(TrainError::BadConfig("a training thread panicked".into()))
                }));
            }
        });
    }
    results.into_iter().collect()
}

/// The final model: all groups' augmented utterances, trained for the cross-validated number of
/// epochs, with the cross-validated closure snap (the held-out sets only draw the curves).
/// How far a family's closure share may stay from the reference's (2 points): closer than the
/// folds can tell apart (142 segments).
pub const SHARE_TOLERANCE: f64 = 0.02;

/// The closure snap for rows of another feature family than the one `cv` was scored on:
/// `held_out[i]` holds fold i's held-out utterances through that family's codec paths, and the
/// snap is the one at which the fold models close about the share of /p b m/ segments they
/// close on `cv`'s own features (within [`SHARE_TOLERANCE`], the one with the fewest false
/// closures; else the closest). A lipreader thus
/// sees the same closures whichever codec a peer speaks. Returns the snap and its scores.
pub fn matching_snap(
    cv: &CrossValidation,
    held_out: &[Vec<PreparedUtterance>],
    shapes: &crate::lipsync::mouth::VisemeShapes,
) -> Result<(f32, Scores), TrainError> {
    if held_out.len() != cv.folds.len() {
        return Err(TrainError::BadConfig(format!(
            "{} held-out sets for {} folds",
            held_out.len(),
            cv.folds.len()
        )));
    }
    let parts: Vec<HeldOutPredictions> = cv
        .folds
        .iter()
        .zip(held_out)
        .map(|(fold, utts)| HeldOutPredictions::new(&fold.model, utts))
        .collect();
    let pooled = HeldOutPredictions::pool(&parts)?;
    let target = cv.pooled.closure_share();
    let curve: Vec<(f32, Scores)> = pooled
        .snap_curve(shapes)?
        .into_iter()
        .filter(|(snap, _)| *snap > 0.0)
        .collect();
    let distance = |s: &Scores| (s.closure_share() - target).abs();
    let close_enough = curve
        .iter()
        .filter(|(_, s)| distance(s) <= SHARE_TOLERANCE)
        .min_by(|a, b| a.1.false_closure_rate.total_cmp(&b.1.false_closure_rate));
    close_enough
        .or_else(|| {
            curve
                .iter()
                .min_by(|a, b| distance(&a.1).total_cmp(&distance(&b.1)))
        })
        .cloned()
        .ok_or(TrainError::NoFrames)
}

pub fn train_final(
    config: &TrainConfig,
    groups: &[SpeakerGroup],
    cv: &CrossValidation,
) -> Result<TrainReport, TrainError> {
    let train: Vec<PreparedUtterance> = groups
        .iter()
        .flat_map(|g| g.augmented.iter().cloned())
        .collect();
    let curves_on: Vec<PreparedUtterance> = groups
        .iter()
        .flat_map(|g| g.held_out.iter().cloned())
        .collect();
    let final_config = TrainConfig {
        max_epochs: cv.epochs,
        keep_last: true,
        tune_closure_snap: false,
        ..config.clone()
    };
    let mut report = train_on(&final_config, &train, &curves_on)?;
    report.model.closure_snap = cv.closure_snap;
    cv.calibration.apply(&mut report.model);
    Ok(report)
}

fn row(f: &mut fmt::Formatter<'_>, name: &str, epoch: &str, s: &Scores) -> fmt::Result {
    writeln!(
        f,
        "{:<18} {:>6} {:>7} {:>11.3} {:>6.1}% {:>3}/{:<3} {:>9.1}% {:>7.2}%",
        name,
        epoch,
        s.frames,
        s.openness_r,
        100.0 * s.closure_share(),
        s.closed_segments,
        s.bilabial_segments,
        100.0 * s.false_closure_rate,
        100.0 * s.eq1_error
    )
}

impl fmt::Display for CrossValidation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{:<18} {:>6} {:>7} {:>11} {:>14} {:>10} {:>8}",
            "held out", "epoch", "frames", "openness r", "/p b m/ closed", "false cl.", "Eq.1"
        )?;
        for fold in &self.folds {
            row(
                f,
                &fold.held_out,
                &fold.best_epoch.to_string(),
                &fold.scores,
            )?;
        }
        row(f, "pooled", &self.epochs.to_string(), &self.pooled)?;
        let p = &self.pooled;
        writeln!(
            f,
            "pooled cues: width r {:.3}, rounding r {:.3}, open vowels {:.1}%, rounded {:.1}%, \
             /f v/ shown {:.1}% (false {:.1}%)",
            p.width_r,
            p.rounding_r,
            100.0 * p.cue_share(CueClass::OpenVowel),
            100.0 * p.cue_share(CueClass::Rounded),
            100.0 * p.cue_share(CueClass::Labiodental),
            100.0 * p.false_labiodental_rate
        )?;
        writeln!(f, "closure-snap trade-off on the pooled folds:")?;
        for (snap, s) in &self.snap_curve {
            let snap = if *snap > 0.0 {
                format!("{snap:.3}")
            } else {
                "off".into()
            };
            writeln!(
                f,
                "  snap {snap:<4} closed {:>5.1}%  false closures {:>4.1}%  openness r {:.3}",
                100.0 * s.closure_share(),
                100.0 * s.false_closure_rate,
                s.openness_r
            )?;
        }
        writeln!(f, "{}", self.calibration)?;
        write!(
            f,
            "closure snap (tuned on the pooled folds): {}",
            self.closure_snap
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::corpus::tests::timit_root;
    use crate::train::corpus::{Corpus, prepare};
    use crate::train::stand_in;
    use crate::vocab::VisemeSet;

    fn group(corpus: &Corpus, speaker: &str) -> SpeakerGroup {
        let prepared = utterances(corpus, speaker, 0..2);
        SpeakerGroup {
            name: speaker.into(),
            augmented: prepared.clone(),
            held_out: prepared,
        }
    }

    fn utterances(
        corpus: &Corpus,
        speaker: &str,
        which: std::ops::Range<usize>,
    ) -> Vec<PreparedUtterance> {
        let utts: Vec<_> = corpus.speaker(speaker).unwrap().utterances[which]
            .iter()
            .collect();
        prepare(&utts, &stand_in::features_for_utterance).unwrap()
    }

    fn small_config() -> TrainConfig {
        TrainConfig {
            visemes: VisemeSet::reduced(3).unwrap(),
            hidden: 4,
            context: 1,
            max_epochs: 12,
            patience: 4,
            learning_rate: 0.01,
            show_progress: false,
            ..TrainConfig::default()
        }
    }

    #[test]
    fn nested_folds_owe_nothing_to_the_group_they_hold_out() {
        let corpus = Corpus::open(&timit_root()).unwrap();
        let speakers = ["dr1-fvmh0", "dr2-marc0", "dr4-maeb0"];
        let groups: Vec<SpeakerGroup> = speakers.iter().map(|s| group(&corpus, s)).collect();
        // The same training material, but other utterances held out by the first group.
        let mut other = groups.clone();
        other[0].held_out = utterances(&corpus, speakers[0], 2..4);
        let config = TrainConfig {
            nested_fold_epochs: true,
            ..small_config()
        };
        let a = cross_validate(&config, &groups, None, None).unwrap();
        let b = cross_validate(&config, &other, None, None).unwrap();
        let (fa, fb) = (&a.folds[0], &b.folds[0]);
        assert_eq!(fa.best_epoch, fb.best_epoch);
        assert_eq!(
            (&fa.model.w1, &fa.model.b1, &fa.model.w2, &fa.model.b2),
            (&fb.model.w1, &fb.model.b1, &fb.model.w2, &fb.model.b2)
        );
        assert!(cross_validate(&config, &groups[..2], None, None).is_err());
    }

    #[test]
    fn every_group_is_held_out_once_and_the_final_model_trains_the_median_epochs() {
        let corpus = Corpus::open(&timit_root()).unwrap();
        let groups: Vec<SpeakerGroup> = ["dr1-fvmh0", "dr2-marc0", "dr4-maeb0"]
            .iter()
            .map(|s| group(&corpus, s))
            .collect();
        let config = small_config();
        let cv = cross_validate(&config, &groups, None, None).unwrap();
        let names: Vec<&str> = cv.folds.iter().map(|f| f.held_out.as_str()).collect();
        assert_eq!(names, ["dr1-fvmh0", "dr2-marc0", "dr4-maeb0"]);
        let frames: usize = groups
            .iter()
            .flat_map(|g| &g.held_out)
            .map(|u| u.features.len())
            .sum();
        assert_eq!(cv.pooled.frames, frames);
        let segments: usize = cv.folds.iter().map(|f| f.scores.bilabial_segments).sum();
        assert_eq!(cv.pooled.bilabial_segments, segments);
        let mut epochs: Vec<usize> = cv.folds.iter().map(|f| f.best_epoch).collect();
        epochs.sort_unstable();
        assert_eq!(cv.epochs, epochs[1]);

        let last = train_final(&config, &groups, &cv).unwrap();
        assert_eq!(last.curve.len(), cv.epochs);
        assert_eq!(last.best_epoch, cv.epochs);
        assert_eq!(last.model.closure_snap, cv.closure_snap);
        assert_eq!(last.model.sharpness, cv.calibration.sharpness);
        assert!(
            cv.folds
                .iter()
                .all(|f| f.model.sharpness == last.model.sharpness)
        );
        assert!(cross_validate(&config, &groups[..1], None, None).is_err());
    }
}
