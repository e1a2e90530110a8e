//! What gets trained on what: the speakers each run trains, validates and holds out on, the codec
//! settings each utterance is seen at, the folds of the cross-validation (one per dialect
//! region, plus CMU AN4 as a group that only trains) and the closure snaps matched per feature
//! family. `lipcall train` and `lipcall evaluate` drive these and print what they return.

use indicatif::{ProgressBar, ProgressStyle};

use crate::codec::g711::Law;
use crate::lipsync::mouth::VisemeShapes;
use crate::train::an4::AlignmentStats;
use crate::train::card::{cross_validated_notes, loss_note, provenance_notes};
use crate::train::codec_features::{
    CodecFeatures, CodecPath, EVALUATION_QUALITY, augmentation_settings, quality,
};
use crate::train::config::TrainConfig;
use crate::train::corpus::{Corpus, CorpusError, PreparedUtterance, SpeakerSplit, Utterance};
use crate::train::crossval::{CrossValidation, SpeakerGroup, matching_snap, train_final};
use crate::train::error::TrainError;
use crate::train::eval::Scores;
use crate::train::trainer::{TrainReport, train_on};

/// A progress bar for `len` steps of `what`, hidden unless `show`.
pub fn progress_bar(len: usize, what: &str, show: bool) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} {msg} {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(what.to_string());
    bar
}

/// The first `per_speaker` utterances (all when `None`) of each of `speakers`.
pub fn pick<'c>(
    corpus: &'c Corpus,
    speakers: &[String],
    per_speaker: Option<usize>,
) -> Result<Vec<&'c Utterance>, CorpusError> {
    let mut chosen = Vec::new();
    for name in speakers {
        let utts = &corpus.speaker(name)?.utterances;
        let n = per_speaker.unwrap_or(utts.len()).min(utts.len());
        chosen.extend(utts[..n].iter());
    }
    Ok(chosen)
}

/// `utts` through the one codec `path`, a progress step per utterance.
pub fn prepare_each(
    codec: &CodecFeatures,
    utts: &[&Utterance],
    path: CodecPath,
    what: &str,
    show: bool,
) -> Result<Vec<PreparedUtterance>, CorpusError> {
    let progress = progress_bar(utts.len(), what, show);
    let mut out = Vec::with_capacity(utts.len());
    for utt in utts {
        out.extend(codec.prepare_through(std::slice::from_ref(utt), path)?);
        progress.inc(1);
    }
    progress.finish_and_clear();
    Ok(out)
}

/// The speakers `evaluate --speakers` names: `test`, `validation` or `train` of the standard
/// split, or a comma list of names or name prefixes (`None` when the list matches nobody).
pub fn named_speakers(corpus: &Corpus, split: &SpeakerSplit, names: &str) -> Option<Vec<String>> {
    let chosen: Vec<String> = match names {
        "test" => split.test.clone(),
        "validation" => split.validation.clone(),
        "train" => split.train.clone(),
        list => {
            let prefixes: Vec<&str> = list.split(',').map(str::trim).collect();
            corpus
                .speakers
                .iter()
                .map(|s| s.name.clone())
                .filter(|name| {
                    prefixes
                        .iter()
                        .any(|p| !p.is_empty() && name.starts_with(p))
                })
                .collect()
        }
    };
    (!chosen.is_empty() || matches!(names, "test" | "validation" | "train")).then_some(chosen)
}

/// Codec settings per training utterance: `versions` of [`augmentation_settings`], at least 1.
pub fn codec_versions(versions: usize) -> usize {
    versions.clamp(1, augmentation_settings().len())
}

/// A model trained on the split's training speakers at `versions` codec settings each, early
/// stopping on its validation speakers at the evaluation quality.
#[derive(Debug)]
pub struct HeldOutTraining {
    pub report: TrainReport,
    /// The validation speakers' utterances, as prepared for early stopping.
    pub validation: Vec<PreparedUtterance>,
}

/// Trains on `split.train`, stopping early on `split.validation`; the closure snap is `snap`
/// (tuned on the validation speakers when `None`, as `config` says) and the output sharpness
/// `sharpness` (1 when `None`). The model's notes say where it comes from.
pub fn train_held_out(
    corpus: &Corpus,
    split: &SpeakerSplit,
    config: &TrainConfig,
    versions: usize,
    snap: Option<f32>,
    sharpness: Option<f32>,
) -> Result<HeldOutTraining, TrainError> {
    let show = config.show_progress;
    let codec = CodecFeatures::new();
    let settings = augmentation_settings();
    let train_utts = pick(corpus, &split.train, config.utterances_per_speaker)?;
    let validation_utts = pick(corpus, &split.validation, config.utterances_per_speaker)?;
    let versions = codec_versions(versions);
    let progress = progress_bar(
        train_utts.len() * versions,
        "Speex round trips (training)",
        show,
    );
    let train = codec.prepare_augmented(&train_utts, &settings, versions, &|| progress.inc(1))?;
    progress.finish_and_clear();
    let validation = prepare_each(
        &codec,
        &validation_utts,
        CodecPath::Speex(quality(EVALUATION_QUALITY)),
        "Speex round trips (validation)",
        show,
    )?;
    let mut report = train_on(config, &train, &validation)?;
    if let Some(threshold) = snap {
        report.model.closure_snap = threshold;
    }
    report.model.sharpness = sharpness.unwrap_or(1.0);
    report.split = split.clone();
    report.model.notes = provenance_notes(
        versions,
        &format!(", validation at quality {EVALUATION_QUALITY}"),
    );
    report.model.notes.extend([
        format!("training speakers: {}", split.train.join(" ")),
        format!("validation speakers: {}", split.validation.join(" ")),
        format!(
            "seed {}, {}, best epoch {}",
            config.seed,
            loss_note(config),
            report.best_epoch
        ),
    ]);
    Ok(HeldOutTraining { report, validation })
}

/// The non-test speakers grouped by dialect region (`dr4-falr0` -> `dr4`): the folds.
pub fn regions(split: &SpeakerSplit) -> Vec<(String, Vec<String>)> {
    let mut groups: Vec<(String, Vec<String>)> = Vec::new();
    for speaker in split.train.iter().chain(&split.validation) {
        let region = speaker.split('-').next().unwrap_or(speaker).to_string();
        match groups.iter_mut().find(|(name, _)| *name == region) {
            Some((_, members)) => members.push(speaker.clone()),
            None => groups.push((region, vec![speaker.clone()])),
        }
    }
    groups
}

/// The folds' material: per region, its utterances at `versions` codec settings (to train on)
/// and at the evaluation quality (to hold out), and the utterances themselves (for
/// [`family_snaps`]).
pub fn region_groups<'c>(
    corpus: &'c Corpus,
    regions: &[(String, Vec<String>)],
    codec: &CodecFeatures,
    versions: usize,
    config: &TrainConfig,
) -> Result<(Vec<SpeakerGroup>, Vec<Vec<&'c Utterance>>), CorpusError> {
    let settings = augmentation_settings();
    let versions = codec_versions(versions);
    let mut groups = Vec::new();
    let mut region_utts = Vec::new();
    for (name, speakers) in regions {
        let utts = pick(corpus, speakers, config.utterances_per_speaker)?;
        region_utts.push(utts.clone());
        let progress = progress_bar(
            utts.len() * (versions + 1),
            &format!("Speex round trips ({name})"),
            config.show_progress,
        );
        let augmented = codec.prepare_augmented(&utts, &settings, versions, &|| progress.inc(1))?;
        let mut held_out = Vec::with_capacity(utts.len());
        for utt in &utts {
            held_out.extend(codec.prepare_through(
                std::slice::from_ref(utt),
                CodecPath::Speex(quality(EVALUATION_QUALITY)),
            )?);
            progress.inc(1);
        }
        progress.finish_and_clear();
        groups.push(SpeakerGroup {
            name: name.clone(),
            augmented,
            held_out,
        });
    }
    Ok((groups, region_utts))
}

/// What [`an4_group`] took and left out.
#[derive(Debug, Clone)]
pub struct An4Summary {
    pub utterances: usize,
    pub speakers: usize,
    pub versions: usize,
    /// Utterances without alignments.
    pub unlabelled: usize,
    /// `<speaker>/<utt>: why` of each utterance whose labels or audio do not read.
    pub failed: Vec<String>,
}

/// CMU AN4 as a group that only trains: every aligned utterance at `versions` codec settings,
/// its frames weighted by `weight`. Utterances without alignments, or whose labels or audio do
/// not read, are skipped and counted.
pub fn an4_group(
    (corpus, stats): (Corpus, AlignmentStats),
    codec: &CodecFeatures,
    versions: usize,
    weight: f32,
    config: &TrainConfig,
) -> Result<(SpeakerGroup, An4Summary), CorpusError> {
    let settings = augmentation_settings();
    let speakers: Vec<String> = corpus.speakers.iter().map(|s| s.name.clone()).collect();
    let utts = pick(&corpus, &speakers, config.utterances_per_speaker)?;
    let versions = codec_versions(versions);
    let progress = progress_bar(utts.len(), "Speex round trips (AN4)", config.show_progress);
    let mut augmented = Vec::with_capacity(utts.len() * versions);
    let mut failed = Vec::new();
    for (i, utt) in utts.iter().enumerate() {
        let rotated: Vec<CodecPath> = (0..versions)
            .map(|k| settings[(i * versions + k) % settings.len()])
            .collect();
        match codec.prepare_augmented(std::slice::from_ref(utt), &rotated, versions, &|| {}) {
            Ok(prepared) => augmented.extend(prepared),
            Err(e) => failed.push(format!("{}/{}: {e}", utt.speaker, utt.id)),
        }
        progress.inc(1);
    }
    progress.finish_and_clear();
    for utt in &mut augmented {
        utt.weight = weight;
    }
    let summary = An4Summary {
        utterances: utts.len() - failed.len(),
        speakers: speakers.len(),
        versions,
        unlabelled: stats.unlabelled.len(),
        failed,
    };
    let group = SpeakerGroup {
        name: "an4".into(),
        augmented,
        held_out: Vec::new(),
    };
    Ok((group, summary))
}

/// The closure snap of one feature family, matched to the closures of Speex's LSPs.
#[derive(Debug, Clone)]
pub struct FamilySnap {
    pub name: &'static str,
    pub paths: [CodecPath; 2],
    pub snap: f32,
    pub scores: Scores,
}

/// The closure snaps of SILK NLSF rows and of LPC-analysis rows, matched on the folds to the
/// closures of Speex's LSPs (`crossval::matching_snap`): Opus at 16 kb/s from 16 and 8 kHz for
/// the first, PCMU and G.722 for the second.
pub fn family_snaps(
    codec: &CodecFeatures,
    cv: &CrossValidation,
    region_utts: &[Vec<&Utterance>],
    shapes: &VisemeShapes,
) -> Result<[FamilySnap; 2], TrainError> {
    let opus = |wideband| CodecPath::Opus {
        bitrate: 16_000,
        wideband,
    };
    let match_family = |name, paths: [CodecPath; 2]| -> Result<FamilySnap, TrainError> {
        let mut held_out = Vec::with_capacity(region_utts.len());
        for utts in region_utts {
            let mut prepared = Vec::new();
            for path in paths {
                prepared.extend(codec.prepare_through(utts, path)?);
            }
            held_out.push(prepared);
        }
        let (snap, scores) = matching_snap(cv, &held_out, shapes)?;
        Ok(FamilySnap {
            name,
            paths,
            snap,
            scores,
        })
    };
    Ok([
        match_family("SILK NLSFs", [opus(true), opus(false)])?,
        match_family("LPC analysis", [CodecPath::G711(Law::Mu), CodecPath::G722])?,
    ])
}

/// The final model of a cross-validation: trained on every group of `groups` (the [`regions`]
/// of `split`, perhaps AN4) for the folds' epochs, with the feature families' closure snaps and notes that say where it comes from.
pub fn train_on_all_regions(
    config: &TrainConfig,
    groups: &[SpeakerGroup],
    cv: &CrossValidation,
    split: &SpeakerSplit,
    [nlsf_snap, analysis_snap]: [Option<f32>; 2],
    versions: usize,
    an4_weight: f32,
) -> Result<TrainReport, TrainError> {
    let mut report = train_final(config, groups, cv)?;
    (report.model.nlsf_snap, report.model.analysis_snap) = (nlsf_snap, analysis_snap);
    report.split = SpeakerSplit {
        train: regions(split).into_iter().flat_map(|(_, s)| s).collect(),
        validation: Vec::new(),
        test: split.test.clone(),
    };
    report.model.notes =
        cross_validated_notes(config, &report, cv, codec_versions(versions), an4_weight);
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn split(train: &[&str], validation: &[&str]) -> SpeakerSplit {
        let names = |list: &[&str]| list.iter().map(|s| s.to_string()).collect();
        SpeakerSplit {
            train: names(train),
            validation: names(validation),
            test: vec!["dr5-x".into()],
        }
    }

    #[test]
    fn regions_group_the_non_test_speakers_by_dialect_region() {
        let split = split(&["dr1-a", "dr2-b", "dr1-c"], &["dr4-d"]);
        assert_eq!(
            regions(&split),
            [
                ("dr1".to_string(), vec!["dr1-a".to_string(), "dr1-c".into()]),
                ("dr2".into(), vec!["dr2-b".into()]),
                ("dr4".into(), vec!["dr4-d".into()]),
            ]
        );
    }
}
