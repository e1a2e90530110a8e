//! `lipcall animate`: audio in, viseme weights per 20 ms frame out (and rendered frames, with
//! the living face the app shows: blinks, saccades, voice-driven head motion).

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

use crate::audio::wav;
use crate::call::csv;
use crate::call::media::MediaFile;
use crate::call::pipeline::{PeerPipeline, Track, stream_track};
use crate::lipsync::LipSyncOptions;
use crate::lipsync::controls::Controls;
use crate::render::head::Expression;
use crate::render::{self, FrameOptions, Framing, HeadModel};
use crate::vocab::FRAME_SIZE;
use crate::vocab::FacePose;
use crate::vocab::FrameFeatures;
use crate::vocab::VISEME_NAMES;
use crate::vocab::VisemeSet;

/// `lipcall animate`'s flags. `baseline_jaw` replaces the network by the jaw baseline;
/// `closure_bias` is [`crate::lipsync::ModelAnimator::with_closure_bias`]'s; `life` off keeps
/// eyes and head still; the same `seed` gives the same living face.
#[derive(Debug, Clone, clap::Args)]
pub struct AnimateArgs {
    pub input: PathBuf,
    /// Write WEIGHTS.csv: frame,time_s,<viseme names>.
    #[arg(long, value_name = "WEIGHTS.csv")]
    pub weights: Option<PathBuf>,
    /// Render numbered PNG frames of the head (plus weights.csv and audio.wav) into DIR.
    #[arg(long, value_name = "DIR")]
    pub frames: Option<PathBuf>,
    /// A glTF/GLB head with viseme or ARKit morph targets instead of the bundled one.
    #[arg(long, value_name = "HEAD.glb")]
    pub head: Option<PathBuf>,
    /// Frames per second of the rendered frames.
    #[arg(long, default_value_t = 25, value_parser = parse_fps)]
    pub fps: u32,
    /// Frame the mouth close-up (the lipreading view) instead of the whole face.
    #[arg(long = "mouth")]
    pub mouth_close_up: bool,
    /// Viseme set: a count (2..6 or 15) or names such as PP,aa,I.
    #[arg(long, value_name = "N|NAMES")]
    pub visemes: Option<String>,
    /// A model file from `lipcall train` instead of the built-in network.
    #[arg(long, value_name = "FILE")]
    pub model: Option<PathBuf>,
    /// A control network (`train --controls`) run beside the viseme network: the head's width
    /// and rounding are its own, everything else the viseme network's (lip-sync v4).
    #[arg(long, value_name = "FILE")]
    pub articulation: Option<PathBuf>,
    /// Compare with a baseline instead of the network: `jaw` opens the jaw with the energy.
    // A bool behind a valued flag: the hidden "" is the default when --baseline is absent.
    #[arg(id = "baseline", long = "baseline", value_name = "BASELINE",
          action = clap::ArgAction::Set, default_value = "", hide_default_value = true,
          value_parser = baseline_parser())]
    pub baseline_jaw: bool,
    /// Lip closures, from -1 (fewer, only the surest) through 0 (the model's balance) to 1
    /// (close for nearly every /p b m/, and more often where there is none).
    #[arg(long = "closures", value_name = "B", default_value_t = 0.0, allow_hyphen_values = true,
          value_parser = crate::lipsync::parse_closure_bias)]
    pub closure_bias: f32,
    /// A still face in the frames: no blinks, no eye or head motion (the mouth still moves).
    #[arg(long = "no-life", action = clap::ArgAction::SetFalse)]
    pub life: bool,
    /// Seed of the living face's blinks, glances and head motion (the same seed and audio
    /// give the same frames).
    #[arg(long, value_name = "N", default_value_t = crate::lipsync::life::DEFAULT_SEED)]
    pub seed: u64,
    /// How the frames' head is driven: `visemes` (the weights as they are) or `controls` (the
    /// frame's articulatory controls fitted to the head's own measured shapes, `render::drive`;
    /// with today's network its controls come from its weights, and that reads worse through the
    /// face: docs/rendering.md).
    #[arg(long = "drive", value_enum, default_value_t = Drive::Visemes)]
    pub drive: Drive,
}

/// How a rendered head is driven by a frame's mouth.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Drive {
    /// The frame's viseme weights straight onto the head's visemes.
    #[default]
    Visemes,
    /// Through the frame's controls and the head's [`render::drive::HeadDrive`].
    Controls,
}

/// Viseme weights for every 20 ms frame of a stream, with the audio they belong to.
pub struct Animation {
    pub visemes: VisemeSet,
    pub rows: Vec<Vec<f32>>,
    /// Each row's articulatory controls (what `--drive controls` shows).
    pub controls: Vec<Controls>,
    /// The living face's pose of each row (empty when it is off).
    pub poses: Vec<FacePose>,
    pub rate: u32,
    pub pcm: Vec<i16>,
}

/// Features as a receiver would see them ([`MediaFile::heard`]): an Ogg Speex or Ogg Opus file
/// decoded, its features read from its bitstream; a WAV resampled to 8 kHz and sent through
/// Speex at the default quality.
pub fn receiver_features(input: &Path) -> Result<(u32, Vec<i16>, Vec<FrameFeatures>)> {
    let heard = MediaFile::open(input)?.heard()?;
    Ok((heard.rate, heard.pcm, heard.features))
}

pub fn weight_track(args: &AnimateArgs) -> Result<Animation> {
    let (rate, pcm, features) = receiver_features(&args.input)?;
    let model = super::lipsync::load_model(args.model.as_deref(), args.articulation.as_deref())?;
    let visemes = match &args.visemes {
        Some(arg) => Some(VisemeSet::parse(arg).with_context(|| format!("--visemes {arg}"))?),
        None => None,
    };
    let options = LipSyncOptions {
        jaw: args.baseline_jaw,
        closure_bias: args.closure_bias,
        visemes,
    };
    // Frame by frame as the app makes them, from the same features and decoded samples.
    let mut pipeline = PeerPipeline::new(&model, &options, args.seed, args.life)?;
    let Track {
        rows,
        controls,
        poses,
    } = stream_track(&mut pipeline, &features, &pcm);
    let target = pipeline.visemes().clone();
    Ok(Animation {
        visemes: target,
        rows,
        controls,
        poses,
        rate,
        pcm,
    })
}

pub fn animate(args: &AnimateArgs) -> Result<()> {
    if args.weights.is_none() && args.frames.is_none() {
        bail!("nothing to do: give --weights FILE and/or --frames DIR");
    }
    // Load the head first: a bad head should fail before any audio work.
    let head = match &args.frames {
        Some(_) => Some(render::load_head_or_default(args.head.as_deref())?),
        None => None,
    };
    let track = weight_track(args)?;
    let weights_path = args
        .weights
        .clone()
        .or_else(|| args.frames.as_ref().map(|dir| dir.join("weights.csv")));
    if let (Some(dir), Some(head)) = (&args.frames, &head) {
        render_frames(dir, head, &track, args)?;
    }
    if let Some(path) = &weights_path {
        write_weights_csv(path, &track)?;
        eprintln!(
            "{}: {} frames of weights over {}",
            path.display(),
            track.rows.len(),
            track
                .visemes
                .members()
                .iter()
                .map(|v| v.name())
                .collect::<Vec<_>>()
                .join(" ")
        );
    }
    Ok(())
}

fn render_frames(
    dir: &Path,
    head: &HeadModel,
    track: &Animation,
    args: &AnimateArgs,
) -> Result<()> {
    let missing: Vec<&str> = track
        .visemes
        .members()
        .iter()
        .map(|v| v.name())
        .filter(|name| head.missing_visemes.iter().any(|m| m == name))
        .collect();
    if !missing.is_empty() {
        bail!(
            "the head has no shape for viseme(s) {} of the model's set",
            missing.join(", ")
        );
    }
    let mut names: Vec<&str> = track.visemes.members().iter().map(|v| v.name()).collect();
    let mut rows: Vec<(f64, Vec<f32>)> = track
        .rows
        .iter()
        .enumerate()
        .map(|(n, w)| ((n * FRAME_SIZE) as f64 / f64::from(track.rate), w.clone()))
        .collect();
    let drive = match args.drive {
        Drive::Controls => render::drive::HeadDrive::new(head).or_else(|| {
            eprintln!(
                "note: the head's mouth cannot be measured (no I and U shapes to find its \
                 corners): its visemes are driven by the weights as they are"
            );
            None
        }),
        Drive::Visemes => None,
    };
    if let Some(drive) = drive {
        for ((_, row), controls) in rows.iter_mut().zip(&track.controls) {
            *row = drive.weights(controls).0.to_vec();
        }
        names = VISEME_NAMES.to_vec();
    }
    let mut weights = render::offscreen::WeightTrack::from_columns(&names, &rows)?;
    if !track.poses.is_empty() {
        weights.set_poses(track.poses.clone())?;
        if !head.has_expression(Expression::Blink) {
            eprintln!(
                "note: the head has no eyeBlinkLeft/eyeBlinkRight morph targets: it will not blink"
            );
        }
    }
    let options = FrameOptions {
        fps: args.fps,
        framing: if args.mouth_close_up {
            Framing::Mouth
        } else {
            Framing::Face
        },
        ..FrameOptions::default()
    };
    let summary = render::offscreen::render_frames(head, &weights, dir, &options)?;
    let audio = dir.join("audio.wav");
    wav::write_mono_i16(&audio, track.rate, &track.pcm)?;
    eprintln!(
        "{}: {} frames at {} fps ({}) and the audio as heard in {}",
        dir.display(),
        summary.frames,
        summary.fps,
        summary.adapter,
        audio.display()
    );
    eprintln!(
        "make a video: ffmpeg -framerate {} -i {}/{} -i {} -c:v libx264 -pix_fmt yuv420p -c:a aac -shortest out.mp4",
        summary.fps,
        dir.display(),
        summary.pattern,
        audio.display()
    );
    Ok(())
}

/// Writes WEIGHTS.csv ([`crate::call::csv`]), one row per 20 ms.
pub fn write_weights_csv(path: &Path, track: &Animation) -> Result<()> {
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    let mut out = std::io::BufWriter::new(file);
    let names: Vec<&str> = track.visemes.members().iter().map(|v| v.name()).collect();
    csv::write_weights(&mut out, &names, track.rate, &track.rows)?;
    out.flush()
        .with_context(|| format!("cannot write {}", path.display()))
}

fn parse_fps(arg: &str) -> Result<u32, String> {
    match arg {
        "25" => Ok(25),
        "50" => Ok(50),
        _ => Err("must be 25 or 50".into()),
    }
}

/// `--baseline`: `jaw` (true); the hidden empty value is the flag left out.
fn baseline_parser() -> impl clap::builder::TypedValueParser<Value = bool> {
    use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser as _};
    PossibleValuesParser::new([PossibleValue::new("jaw"), PossibleValue::new("").hide(true)])
        .map(|name| name == "jaw")
}
