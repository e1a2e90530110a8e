//! `lipcall evaluate`: a model and the jaw baseline scored on held-out TIMIT speakers through
//! one codec path, and on measured lips (GRID) where asked.

use std::io::Write as _;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};

use super::lipsync::{DEFAULT_CORPUS, load_model};
use crate::codec::g711::Law;
use crate::codec::speex::codec::EncoderConfig;
use crate::lipsync::mouth::VisemeShapes;
use crate::lipsync::network::Model;
use crate::train::codec_features::{CodecFeatures, CodecPath, EVALUATION_QUALITY};
use crate::train::corpus::{Corpus, SpeakerSplit};
use crate::train::eval::{EvalReport, evaluate_prepared, write_frames};
use crate::train::plan;
use crate::vocab::FeatureFamily;

#[derive(Debug, clap::Args)]
pub struct EvaluateArgs {
    /// Model file (default: the built-in model).
    #[arg(long, value_name = "FILE")]
    pub model: Option<PathBuf>,
    /// A control network (`train --controls`) run beside the viseme network: width and
    /// rounding are its own (lip-sync v4); the weights, and so the TIMIT scores, are unchanged.
    #[arg(long, value_name = "FILE")]
    pub articulation: Option<PathBuf>,
    #[arg(long, value_name = "DIR", default_value = DEFAULT_CORPUS)]
    pub corpus: PathBuf,
    /// The codec path the features come through: Speex (the walker's LSPs), Opus from the
    /// corpus's 16 kHz audio as opusenc codes it (wideband SILK NLSFs) or from 8 kHz as lipcall
    /// sends it (narrowband SILK), PCMU/PCMA or G.722 (LPC analysis of the decoded audio).
    #[arg(long, value_enum, default_value = "speex")]
    pub codec: EvalCodec,
    /// Speex quality of the round trip.
    #[arg(long, value_name = "Q", default_value_t = EVALUATION_QUALITY,
          value_parser = clap::value_parser!(u8).range(0..=10))]
    pub quality: u8,
    #[arg(long)]
    pub vbr: bool,
    /// Opus bitrate in kb/s.
    #[arg(long, value_name = "KBPS", default_value_t = 16,
          value_parser = clap::value_parser!(u32).range(6..=510))]
    pub bitrate: u32,
    /// Which speakers: test (dr5, dr6), validation (dr4), train (dr1-dr3), or a comma list of
    /// speaker names or their prefixes (e.g. dr2 for a cross-validation fold). Default: test,
    /// except with --grid, which then scores the lips alone (so that tuning on lips never
    /// glimpses the test speakers by accident).
    #[arg(long, value_name = "SET")]
    pub speakers: Option<String>,
    /// Utterances per speaker (all by default).
    #[arg(long, value_name = "N")]
    pub utterances: Option<usize>,
    /// Lip closures from -1 (fewer) through 0 (the model's balance) to 1 (more), as `animate
    /// --closures` takes.
    #[arg(long, value_name = "B", default_value_t = 0.0, allow_hyphen_values = true,
          value_parser = crate::lipsync::parse_closure_bias)]
    pub closures: f32,
    /// Also write the per-frame openness and aperture of targets, network and jaw baseline.
    #[arg(long, value_name = "CSV")]
    pub per_frame: Option<PathBuf>,
    #[command(flatten)]
    pub lips: super::grid::LipEvalArgs,
}

/// Codec paths `evaluate` can score.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum EvalCodec {
    Speex,
    Opus,
    OpusNb,
    /// opus-tools' `opusenc --bitrate` on the 16 kHz files, read as `animate` reads .opus.
    Opusenc,
    Pcmu,
    Pcma,
    G722,
}

pub fn evaluate(args: &EvaluateArgs) -> Result<()> {
    let speakers = match (&args.speakers, &args.lips.grid) {
        (Some(set), _) => Some(set.as_str()),
        (None, None) => Some("test"),
        (None, Some(_)) if args.per_frame.is_some() => {
            bail!("--per-frame writes TIMIT frames: with --grid, name them with --speakers")
        }
        (None, Some(_)) => None,
    };
    let mut model = load_model(args.model.as_deref(), args.articulation.as_deref())?;
    let [bitstream, nlsf, analysis] = [
        FeatureFamily::Bitstream,
        FeatureFamily::Nlsf,
        FeatureFamily::Analysis,
    ]
    .map(|family| model.closure_snap_with_bias(family, args.closures));
    (model.closure_snap, model.nlsf_snap, model.analysis_snap) =
        (bitstream, Some(nlsf), Some(analysis));
    let config = EncoderConfig {
        quality: args.quality,
        vbr: args.vbr,
        ..EncoderConfig::default()
    };
    let path = match args.codec {
        EvalCodec::Speex => CodecPath::Speex(config),
        EvalCodec::Opus | EvalCodec::OpusNb => CodecPath::Opus {
            bitrate: args.bitrate * 1000,
            wideband: args.codec == EvalCodec::Opus,
        },
        EvalCodec::Opusenc => CodecPath::Opusenc {
            bitrate: args.bitrate * 1000,
        },
        EvalCodec::Pcmu => CodecPath::G711(Law::Mu),
        EvalCodec::Pcma => CodecPath::G711(Law::A),
        EvalCodec::G722 => CodecPath::G722,
    };
    println!(
        "model: {} ({} visemes: {}; {} multiply-adds/frame; sharpness {}; closure snap {}), {}",
        args.model
            .as_deref()
            .map_or_else(|| "built-in".to_string(), |p| p.display().to_string()),
        model.outputs(),
        model.viseme_names().join(" "),
        model.multiply_adds(),
        model.sharpness,
        model.closure_snap_of(path.family()),
        path
    );
    if let Some(set) = speakers {
        evaluate_speakers(args, &model, set, path)?;
    }
    super::grid::evaluate_lips(&args.lips, &model, path)
}

/// The TIMIT half of `evaluate`: the report on the speakers of `set`, and `--per-frame`.
fn evaluate_speakers(args: &EvaluateArgs, model: &Model, set: &str, path: CodecPath) -> Result<()> {
    let corpus = Corpus::open(&args.corpus)?;
    let split = SpeakerSplit::standard(&corpus)?;
    let Some(speakers) = plan::named_speakers(&corpus, &split, set) else {
        bail!(
            "--speakers {set:?} names no speaker of {}",
            args.corpus.display()
        );
    };
    let speakers = &speakers;
    let utts = plan::pick(&corpus, speakers, args.utterances)?;
    let prepared = plan::prepare_each(
        &CodecFeatures::new(),
        &utts,
        path,
        &format!("{path} round trips"),
        true,
    )?;
    let report: EvalReport =
        evaluate_prepared(model, &prepared, speakers, &VisemeShapes::point_model())?;
    print!("{report}");
    if let Some(path) = &args.per_frame {
        let file = std::fs::File::create(path)
            .with_context(|| format!("cannot create {}", path.display()))?;
        let mut out = std::io::BufWriter::new(file);
        write_frames(&mut out, model, &VisemeShapes::point_model(), &prepared)
            .and_then(|()| Ok(out.flush()?))
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote the per-frame values to {}", path.display());
    }
    Ok(())
}
