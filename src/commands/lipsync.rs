//! `lipcall train` and `lipcall decompose`, and the model loading every command that reads a model shares.

use std::io::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

use crate::lipsync::controls::{CONTROL_COUNT, CONTROL_NAMES};
use crate::lipsync::decompose::{decompose_track, table_i, table_i_reduced};
use crate::lipsync::markers::MarkerTrack;
use crate::lipsync::mouth::VisemeShapes;
use crate::lipsync::network::{Dynamics, Model};
use crate::lipsync::{self, recipe};
use crate::train::card::{CardSources, model_card};
use crate::train::codec_features::{
    CodecFeatures, CodecPath, EVALUATION_QUALITY, LOW_QUALITY, quality,
};
use crate::train::config::TrainConfig;
use crate::train::corpus::{Corpus, SpeakerSplit};
use crate::train::crossval::cross_validate;
use crate::train::eval::evaluate_prepared;
use crate::train::trainer::EpochStats;
use crate::train::{an4, plan, plot, table_i};
use crate::vocab::VisemeSet;

pub(super) const DEFAULT_CORPUS: &str = "../shared/data/timit-sample";

#[derive(Debug, clap::Args)]
pub struct TrainArgs {
    /// TIMIT-style corpus: <speaker>/<utt>.wav with <utt>.phn beside it.
    #[arg(long, value_name = "DIR", default_value = DEFAULT_CORPUS)]
    pub corpus: PathBuf,
    /// Viseme set: a count (2..6, the paper's reduced sets) or names, e.g. PP,aa,I.
    #[arg(long, value_name = "N|NAMES", default_value = recipe::VISEMES)]
    pub visemes: String,
    #[arg(long, value_name = "H", default_value_t = recipe::HIDDEN)]
    pub hidden: usize,
    /// Frames fed besides the newest one.
    #[arg(long, value_name = "C", default_value_t = recipe::CONTEXT)]
    pub context: usize,
    /// Of those, frames after the one the output describes (0..=2; each is 20 ms the
    /// receiver's buffers hide).
    #[arg(long, value_name = "L", default_value_t = recipe::LOOKAHEAD)]
    pub lookahead: usize,
    /// Per-speaker LSP normalisation over about this many speech frames; 0 = off.
    #[arg(long, value_name = "FRAMES", default_value_t = recipe::SPEAKER_NORM_FRAMES)]
    pub normalise: u32,
    /// Extra past frames of peak-relative energy (with dynamics).
    #[arg(long, value_name = "E", default_value_t = recipe::ENERGY_CONTEXT)]
    pub energy_context: usize,
    /// Fall of the running energy peak, dB per frame.
    #[arg(long, value_name = "DB", default_value_t = recipe::PEAK_DECAY_DB)]
    pub peak_decay: f32,
    /// Only the paper's 11 raw features per frame (no energy dynamics).
    #[arg(long)]
    pub no_dynamics: bool,
    /// Loss weight of frames inside /p b m/ segments.
    #[arg(long, value_name = "W", default_value_t = recipe::CLOSURE_WEIGHT)]
    pub closure_weight: f32,
    /// Loss weight of frames inside /f v/ segments.
    #[arg(long, value_name = "W", default_value_t = recipe::LABIODENTAL_WEIGHT)]
    pub labiodental_weight: f32,
    /// Weight of the segment closure loss: per /p b m/ segment, -ln P(the lips close in at
    /// least one frame); 0 = off.
    #[arg(long, value_name = "W", default_value_t = recipe::SEGMENT_CLOSURE_WEIGHT)]
    pub segment_closure_weight: f32,
    /// Vocal-tract-length augmentation: LSPs of each training utterance scaled by a factor in
    /// [1 - W, 1 + W]; 0 = off.
    #[arg(long, value_name = "W", default_value_t = recipe::WARP)]
    pub warp: f32,
    /// Weight of a squared-error term on mouth openness beside the KL loss; 0 = off.
    #[arg(long, value_name = "W", default_value_t = recipe::OPENNESS_WEIGHT)]
    pub openness_weight: f32,
    /// The same for lip width (spread vs narrowed).
    #[arg(long, value_name = "W", default_value_t = recipe::WIDTH_WEIGHT)]
    pub width_weight: f32,
    /// The same for lip rounding (protrusion).
    #[arg(long, value_name = "W", default_value_t = recipe::ROUNDING_WEIGHT)]
    pub rounding_weight: f32,
    /// Decoupled weight decay (AdamW), per step as a fraction of the learning rate; 0 = off.
    #[arg(long, value_name = "D", default_value_t = recipe::WEIGHT_DECAY)]
    pub weight_decay: f32,
    /// Keep the coarticulated targets inside /p b m/ (default: a full closure there).
    #[arg(long)]
    pub soft_closures: bool,
    /// Closure snap: `auto` (tuned on the validation speakers), `off`, or a threshold in (0, 1].
    #[arg(long, value_name = "auto|off|T", default_value = "auto")]
    pub snap: String,
    /// Output sharpness (the logits times this before the softmax): `auto` (with
    /// --cross-validate, tuned with the closure snap on the pooled folds; else 1) or a number
    /// from 0.25 to 4 (1 = the network as trained).
    #[arg(long, value_name = "auto|G", default_value = "auto")]
    pub sharpness: String,
    /// Codec versions of each training utterance (settings rotate over Speex qualities 3..10
    /// and VBR interleaved with Opus, G.711 and G.722).
    #[arg(long, value_name = "N", default_value_t = recipe::CODEC_VERSIONS)]
    pub versions: usize,
    #[arg(long, default_value_t = 400)]
    pub epochs: usize,
    /// Epochs without a better validation loss before stopping.
    #[arg(long, default_value_t = 40)]
    pub patience: usize,
    #[arg(long, default_value_t = 0.003)]
    pub learning_rate: f32,
    #[arg(long, default_value_t = 32)]
    pub batch: usize,
    #[arg(long, value_name = "S", default_value_t = recipe::SEED)]
    pub seed: u64,
    /// Utterances per speaker (all by default), for quick runs.
    #[arg(long, value_name = "N")]
    pub utterances: Option<usize>,
    /// Where the trained model goes.
    #[arg(long, value_name = "MODEL", default_value = "lipsync.lipmodel")]
    pub out: PathBuf,
    /// Learning curves as CSV.
    #[arg(long, value_name = "CSV")]
    pub curves: Option<PathBuf>,
    /// Learning curves as a PNG plot.
    #[arg(long, value_name = "PNG")]
    pub plot: Option<PathBuf>,
    /// Accept a network over the multiply-add budget (400; 2,000 with --controls).
    #[arg(long)]
    pub allow_over_budget: bool,
    /// The network outputs the articulatory controls (lip-sync v4, model file version 4),
    /// decomposed onto --visemes in the receiver; with --grid, s1's lips are control targets.
    #[arg(long)]
    pub controls: bool,
    /// With --controls: the controls the loss teaches, comma-separated (aperture, width, jaw,
    /// rounding, closure, lower_lip_tuck; default all). `width,rounding` trains an articulation
    /// network for `--articulation` beside a viseme network.
    #[arg(long, value_name = "NAMES", requires = "controls", value_parser = parse_learnt_controls)]
    pub learn_controls: Option<[bool; CONTROL_COUNT]>,
    /// With --controls: multiply the trained network's width output by K (docs/model.md: the
    /// articulation network is shipped to heads at x4, so that their width moves visibly).
    #[arg(long, value_name = "K", requires = "controls")]
    pub width_gain: Option<f32>,
    /// The trained network's outputs shown as a running mean, each frame's own counting
    /// 1 - S (the model file's `smoothing`; docs/model.md: the articulation network ships at
    /// 0.6); 0 = none.
    #[arg(long, value_name = "S", default_value_t = 0.0, value_parser = parse_smoothing)]
    pub smoothing: f32,
    /// Hold out each dialect region of the non-test speakers in turn, report the pooled
    /// held-out scores, then train the model on all of them for the folds' median best epoch.
    #[arg(long)]
    pub cross_validate: bool,
    /// With --cross-validate: each fold takes its epochs from an inner cross-validation over
    /// the other regions instead of early stopping on the region it holds out, so that the
    /// pooled scores are out of sample in every choice (about 1.2 times as long: one inner
    /// training per pair of regions serves both).
    #[arg(long, requires = "cross_validate")]
    pub nested_epochs: bool,
    /// AN4's audio (wav/an4_clstk, wav/an4test_clstk).
    #[arg(long, value_name = "DIR", default_value_os_t = an4::default_audio_root())]
    pub an4_audio: PathBuf,
    /// AN4's phone alignments (<speaker>/<utt>.phn, from tools/align_an4.py).
    #[arg(long, value_name = "DIR", default_value_os_t = an4::default_labels_root())]
    pub an4_labels: PathBuf,
    /// With --cross-validate: loss weight of CMU AN4's frames (84 more speakers, force-aligned
    /// labels, never held out or scored) against TIMIT's hand-labelled ones; 0 = no AN4.
    #[arg(long, value_name = "W", default_value_t = recipe::AN4_WEIGHT)]
    pub an4_weight: f32,
    /// Codec versions of each AN4 utterance.
    #[arg(long, value_name = "N", default_value_t = recipe::AN4_CODEC_VERSIONS)]
    pub an4_versions: usize,
    /// No progress bars.
    #[arg(long)]
    pub quiet: bool,
    #[command(flatten)]
    pub lips: super::grid::LipTrainArgs,
}

#[derive(Debug, clap::Args)]
pub struct DecomposeArgs {
    /// Corpus whose phone-derived targets make the Table I track (without --markers).
    #[arg(long, value_name = "DIR", default_value = DEFAULT_CORPUS)]
    pub corpus: PathBuf,
    /// Marker tracks CSV: frame,<p>_x,<p>_y,...
    #[arg(long, value_name = "TRACKS.csv", requires = "key_frames")]
    pub markers: Option<PathBuf>,
    /// Key frames CSV: viseme,frame (the viseme shapes).
    #[arg(long, value_name = "KEYS.csv", requires = "markers")]
    pub key_frames: Option<PathBuf>,
    /// Marker subtracted from every point of its row (e.g. the nose).
    #[arg(long, value_name = "NAME")]
    pub origin: Option<String>,
    /// Decompose onto this set: a count or names (with --markers: default all key-frame visemes).
    #[arg(long, value_name = "N|NAMES")]
    pub visemes: Option<String>,
    /// Utterances per speaker for Table I (all by default).
    #[arg(long, value_name = "N")]
    pub utterances: Option<usize>,
    /// Write the weights per marker frame: frame,<viseme names>.
    #[arg(long, value_name = "OUT.csv", requires = "markers")]
    pub weights: Option<PathBuf>,
    #[command(flatten)]
    pub lips: super::grid::RealLipsArgs,
}

fn parse_snap(text: &str) -> Result<Option<f32>> {
    match text {
        "auto" => Ok(None),
        "off" => Ok(Some(0.0)),
        _ => match text.parse::<f32>() {
            Ok(t) if t > 0.0 && t <= 1.0 => Ok(Some(t)),
            _ => bail!("--snap takes auto, off or a threshold in (0, 1], not {text:?}"),
        },
    }
}

/// Saves the trained model to `--out` with what the command line asks of its file (the width
/// output's gain, the smoothing).
fn save_trained(model: &mut Model, args: &TrainArgs) -> Result<()> {
    if let Some(gain) = args.width_gain {
        model.scale_width_output(gain);
    }
    model.smoothing = args.smoothing;
    model
        .save(&args.out)
        .with_context(|| format!("cannot save the model to {}", args.out.display()))
}

fn parse_smoothing(text: &str) -> Result<f32, String> {
    use crate::lipsync::network::MAX_SMOOTHING;
    match text.parse::<f32>() {
        Ok(s) if (0.0..=MAX_SMOOTHING).contains(&s) => Ok(s),
        _ => Err(format!(
            "{text:?} is not a number from 0 to {MAX_SMOOTHING}"
        )),
    }
}

fn parse_sharpness(text: &str) -> Result<Option<f32>> {
    use crate::lipsync::network::{MAX_SHARPNESS, MIN_SHARPNESS};
    match text {
        "auto" => Ok(None),
        _ => match text.parse::<f32>() {
            Ok(g) if (MIN_SHARPNESS..=MAX_SHARPNESS).contains(&g) => Ok(Some(g)),
            _ => bail!(
                "--sharpness takes auto or a number from {MIN_SHARPNESS} to {MAX_SHARPNESS}, \
                 not {text:?}"
            ),
        },
    }
}

/// Every number of the recipe must be finite and in range: a NaN learning rate trains a model
/// that no loader accepts.
fn check_numbers(args: &TrainArgs) -> Result<()> {
    let non_negative = [
        ("--closure-weight", args.closure_weight),
        ("--labiodental-weight", args.labiodental_weight),
        ("--segment-closure-weight", args.segment_closure_weight),
        ("--openness-weight", args.openness_weight),
        ("--width-weight", args.width_weight),
        ("--rounding-weight", args.rounding_weight),
        ("--weight-decay", args.weight_decay),
        ("--an4-weight", args.an4_weight),
        ("--peak-decay", args.peak_decay),
    ];
    for (flag, value) in non_negative {
        if !(value.is_finite() && value >= 0.0) {
            bail!("{flag} must be a finite number of 0 or more, not {value}");
        }
    }
    if !(args.learning_rate.is_finite() && args.learning_rate > 0.0 && args.learning_rate <= 1.0) {
        bail!(
            "--learning-rate must be in (0, 1], not {}",
            args.learning_rate
        );
    }
    if !(args.warp.is_finite() && (0.0..0.5).contains(&args.warp)) {
        bail!("--warp must be in [0, 0.5), not {}", args.warp);
    }
    if args.peak_decay > 10.0 {
        bail!("--peak-decay must be at most 10 dB per frame");
    }
    Ok(())
}

fn train_config(args: &TrainArgs, split: &SpeakerSplit, snap: Option<f32>) -> Result<TrainConfig> {
    check_numbers(args)?;
    Ok(TrainConfig {
        corpus_root: args.corpus.clone(),
        split: Some(split.clone()),
        visemes: VisemeSet::parse(&args.visemes).context("--visemes")?,
        shapes: VisemeShapes::point_model(),
        context: args.context,
        lookahead: args.lookahead,
        speaker_norm_frames: (args.normalise > 0).then_some(args.normalise),
        dynamics: (!args.no_dynamics).then_some(Dynamics {
            peak_decay_db: args.peak_decay,
            energy_context: args.energy_context,
        }),
        sharp_closures: !args.soft_closures,
        tune_closure_snap: snap.is_none(),
        hidden: args.hidden,
        max_epochs: args.epochs,
        patience: args.patience,
        keep_last: false,
        learning_rate: args.learning_rate,
        batch_size: args.batch,
        seed: args.seed,
        closure_weight: args.closure_weight,
        labiodental_weight: args.labiodental_weight,
        segment_closure_weight: args.segment_closure_weight,
        warp: args.warp,
        weight_decay: args.weight_decay,
        openness_weight: args.openness_weight,
        width_weight: args.width_weight,
        rounding_weight: args.rounding_weight,
        utterances_per_speaker: args.utterances,
        curves_csv: args.curves.clone(),
        show_progress: !args.quiet,
        allow_over_budget: args.allow_over_budget,
        nested_fold_epochs: args.nested_epochs,
        controls: args.controls,
        learnt_controls: args.learn_controls.unwrap_or([true; CONTROL_COUNT]),
        ..TrainConfig::default()
    })
}

/// The video half of training: measured lips through the viseme shapes, or as control targets.
fn set_video(config: &mut TrainConfig, args: &TrainArgs, codec: &CodecFeatures) -> Result<()> {
    if args.controls {
        config.control_video = super::grid::control_video(&args.lips, codec)?;
    } else {
        (config.video, config.lip_validation) = super::grid::video_training(&args.lips, codec)?;
    }
    Ok(())
}

pub fn train(args: &TrainArgs) -> Result<()> {
    if args.cross_validate {
        return train_cross_validated(args);
    }
    let snap = parse_snap(&args.snap)?;
    let sharpness = parse_sharpness(&args.sharpness)?;
    let corpus = Corpus::open(&args.corpus)?;
    let split = SpeakerSplit::standard(&corpus)?;
    let mut config = train_config(args, &split, snap)?;
    set_video(&mut config, args, &CodecFeatures::new())?;
    eprintln!(
        "Training the viseme network ({}) on the Speex-decoded features of {} \
         (training speakers {}; validation speakers {} steer early stopping; the test speakers {} \
         are not touched). Each training utterance is seen at {} codec settings.",
        config.visemes,
        args.corpus.display(),
        split.train.join(" "),
        split.validation.join(" "),
        split.test.join(" "),
        plan::codec_versions(args.versions)
    );
    let trained = plan::train_held_out(&corpus, &split, &config, args.versions, snap, sharpness)?;
    let mut report = trained.report;
    save_trained(&mut report.model, args)?;
    let validation_utts = plan::pick(&corpus, &split.validation, args.utterances)?;
    let low = plan::prepare_each(
        &CodecFeatures::new(),
        &validation_utts,
        CodecPath::Speex(quality(LOW_QUALITY)),
        "Speex round trips (validation, low quality)",
        !args.quiet,
    )?;
    println!("{report}");
    let shapes = VisemeShapes::point_model();
    println!("validation at quality {EVALUATION_QUALITY}:");
    println!(
        "{}",
        evaluate_prepared(
            &report.model,
            &trained.validation,
            &split.validation,
            &shapes
        )?
    );
    println!("validation at quality {LOW_QUALITY}:");
    println!(
        "{}",
        evaluate_prepared(&report.model, &low, &split.validation, &shapes)?
    );
    eprintln!("wrote the model to {}", args.out.display());
    if let Some(path) = &args.curves {
        eprintln!("wrote the learning curves to {}", path.display());
    }
    plot_curves(args.plot.as_deref(), &report.curve)
}

fn plot_curves(path: Option<&Path>, curve: &[EpochStats]) -> Result<()> {
    if let Some(path) = path {
        plot::learning_curves(path, curve)
            .with_context(|| format!("cannot plot to {}", path.display()))?;
        eprintln!(
            "wrote the learning-curve plot to {} (losses top, validation closure share and \
             openness r bottom)",
            path.display()
        );
    }
    Ok(())
}

fn train_cross_validated(args: &TrainArgs) -> Result<()> {
    let snap = parse_snap(&args.snap)?;
    let sharpness = parse_sharpness(&args.sharpness)?;
    let corpus = Corpus::open(&args.corpus)?;
    let split = SpeakerSplit::standard(&corpus)?;
    let config = train_config(args, &split, snap)?;
    let regions = plan::regions(&split);
    // AN4's folders are checked before any work starts.
    let an4 = if args.an4_weight > 0.0 {
        Some(an4::open_aligned(&args.an4_audio, &args.an4_labels)?)
    } else {
        None
    };
    eprintln!(
        "Cross-validating the viseme network ({}) over {} folds, each holding out one dialect \
         region of {} (the test speakers {} are not touched); then training it on all of them.",
        config.visemes,
        regions.len(),
        regions
            .iter()
            .map(|(name, speakers)| format!("{name}: {}", speakers.join(" ")))
            .collect::<Vec<_>>()
            .join(", "),
        split.test.join(" ")
    );
    let codec = CodecFeatures::new();
    let mut config = config;
    set_video(&mut config, args, &codec)?;
    let (mut groups, region_utts) =
        plan::region_groups(&corpus, &regions, &codec, args.versions, &config)?;
    if let Some(aligned) = an4 {
        let (group, summary) =
            plan::an4_group(aligned, &codec, args.an4_versions, args.an4_weight, &config)?;
        print_an4_summary(&summary, args.an4_weight);
        groups.push(group);
    }
    let progress = plan::progress_bar(regions.len(), "folds", !args.quiet);
    progress.enable_steady_tick(std::time::Duration::from_secs(1));
    let mut cv = cross_validate(&config, &groups, snap, sharpness)?;
    progress.finish_and_clear();
    println!("cross-validation, Speex quality {EVALUATION_QUALITY}:");
    println!("{cv}");
    let family_snaps = if snap.is_none() {
        let matched = plan::family_snaps(&codec, &cv, &region_utts, &config.shapes)?;
        for m in &matched {
            println!(
                "closure snap for {} ({} and {}): {}, /p b m/ closed {:.1}% \
                 ({}/{}), false closures {:.1}%, openness r {:.3}",
                m.name,
                m.paths[0],
                m.paths[1],
                m.snap,
                100.0 * m.scores.closure_share(),
                m.scores.closed_segments,
                m.scores.bilabial_segments,
                100.0 * m.scores.false_closure_rate,
                m.scores.openness_r
            );
        }
        matched.map(|m| Some(m.snap))
    } else {
        [None, None]
    };
    for fold in &mut cv.folds {
        [fold.model.nlsf_snap, fold.model.analysis_snap] = family_snaps;
    }
    for fold in &cv.folds {
        let path = args
            .out
            .with_extension(format!("fold-{}.lipmodel", fold.held_out));
        fold.model
            .save(&path)
            .with_context(|| format!("cannot save a fold model to {}", path.display()))?;
    }
    eprintln!(
        "wrote the fold models beside it ({})",
        args.out.with_extension("fold-*.lipmodel").display()
    );
    eprintln!(
        "Training on all {} speakers for {} epochs.",
        regions.iter().map(|(_, s)| s.len()).sum::<usize>(),
        cv.epochs
    );
    let mut report = plan::train_on_all_regions(
        &config,
        &groups,
        &cv,
        &split,
        family_snaps,
        args.versions,
        args.an4_weight,
    )?;
    save_trained(&mut report.model, args)?;
    eprintln!("wrote the model to {}", args.out.display());
    let card = args.out.with_extension("card.md");
    let sources = CardSources {
        model_file: &args.out,
        corpus: &args.corpus,
        an4_audio: &args.an4_audio,
        an4_weight: args.an4_weight,
        grid: args
            .lips
            .grid
            .as_deref()
            .map(|root| (root, args.lips.lip_weight)),
    };
    std::fs::write(&card, model_card(&sources, &report.model, &cv))
        .with_context(|| format!("cannot write {}", card.display()))?;
    eprintln!("wrote the model card to {}", card.display());
    if let Some(path) = &args.curves {
        eprintln!(
            "wrote the learning curves to {} (its validation columns are the training speakers \
             at quality {EVALUATION_QUALITY}: in-sample)",
            path.display()
        );
    }
    plot_curves(args.plot.as_deref(), &report.curve)
}

fn print_an4_summary(summary: &plan::An4Summary, weight: f32) {
    eprintln!(
        "AN4: {} utterances of {} speakers at {} codec setting(s), weight {}; {} without \
         alignments and {} unreadable, skipped",
        summary.utterances,
        summary.speakers,
        summary.versions,
        weight,
        summary.unlabelled,
        summary.failed.len()
    );
    for f in summary.failed.iter().take(5) {
        eprintln!("  skipped {f}");
    }
}

/// The model `--model` names, or the built-in one.
/// Control names (`CONTROL_NAMES`), comma-separated, as a mask in control order.
fn parse_learnt_controls(text: &str) -> Result<[bool; CONTROL_COUNT], String> {
    let mut mask = [false; CONTROL_COUNT];
    for name in text.split(',').map(str::trim) {
        let Some(i) = CONTROL_NAMES.iter().position(|n| *n == name) else {
            return Err(format!(
                "{name:?} is no control (one of {})",
                CONTROL_NAMES.join(", ")
            ));
        };
        mask[i] = true;
    }
    Ok(mask)
}

pub fn load_model(path: Option<&Path>, articulation: Option<&Path>) -> Result<Model> {
    let model = match path {
        Some(path) => Model::load(path).context("cannot load the model")?,
        None => lipsync::default_model(),
    };
    match articulation {
        Some(path) => {
            let articulation = Model::load(path).context("cannot load the articulation network")?;
            model
                .with_articulation(articulation)
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
        }
        None => Ok(model),
    }
}

pub fn decompose(args: &DecomposeArgs) -> Result<()> {
    match (&args.lips.grid, &args.markers, &args.key_frames) {
        (Some(_), ..) => super::grid::decompose_grid(&args.lips, args.visemes.as_deref()),
        (None, Some(markers), Some(keys)) => decompose_markers(args, markers, keys),
        _ => decompose_targets(args),
    }
}

fn decompose_targets(args: &DecomposeArgs) -> Result<()> {
    let corpus = Corpus::open(&args.corpus)?;
    let shapes = VisemeShapes::point_model();
    let (track, utterances) = table_i::phone_target_track(&corpus, &shapes, args.utterances)?;
    println!(
        "Table I: phone-derived viseme targets of {} ({} utterances, {} speakers) through the \
         point model, decomposed onto the reduced sets",
        args.corpus.display(),
        utterances,
        corpus.speakers.len()
    );
    let table = match &args.visemes {
        Some(names) => table_i(&track, &shapes, &[VisemeSet::parse(names)?])?,
        None => table_i_reduced(&track, &shapes)?,
    };
    print!("{table}");
    Ok(())
}

fn decompose_markers(args: &DecomposeArgs, markers: &Path, keys: &Path) -> Result<()> {
    let track = MarkerTrack::load(markers, args.origin.as_deref())?;
    let shapes = track
        .load_key_frame_shapes(keys)
        .with_context(|| format!("{}", keys.display()))?;
    let key_set = VisemeSet::new(shapes.visemes())
        .context("the key frames must name at least 2 different visemes")?;
    let set = match &args.visemes {
        Some(names) => VisemeSet::parse(names)?,
        None => key_set.clone(),
    };
    shapes
        .for_set(&set)
        .context("a viseme of --visemes has no key frame")?;
    // Table I over the reduced sets the key frames cover, then the chosen set.
    let mut sets: Vec<VisemeSet> = (2..=6)
        .filter_map(|n| VisemeSet::reduced(n).ok())
        .filter(|s| shapes.for_set(s).is_ok())
        .collect();
    if !sets.contains(&set) {
        sets.push(set.clone());
    }
    println!(
        "{} marker frames of {} markers, shapes from {} key frames",
        track.points.len(),
        track.marker_names.len(),
        key_set.len()
    );
    print!("{}", table_i(&track.points, &shapes, &sets)?);
    if let Some(out) = &args.weights {
        let sigmas = track.points.point_sigmas();
        let weights = decompose_track(&track.points, &shapes, &set, &sigmas)?;
        let file = std::fs::File::create(out)
            .with_context(|| format!("cannot write {}", out.display()))?;
        let mut w = std::io::BufWriter::new(file);
        table_i::write_frame_weights(&mut w, &set, &track.frame_numbers, &weights)?;
        w.flush()
            .with_context(|| format!("cannot write {}", out.display()))?;
        eprintln!("wrote the weights over {set} to {}", out.display());
    }
    Ok(())
}
