//! `lipcall grid`: the GRID data step. Turns the tracked video of each clip into per-20-ms-frame
//! lip targets beside its audio as a WAV (what the codec paths read), and measures s1's
//! audio-visual lag.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

use anyhow::{Context, Result, bail};

use crate::audio::wav;
use crate::lipsync::decompose::table_i;
use crate::lipsync::jaw::JawBaseline;
use crate::lipsync::lips::LipTargets;
use crate::lipsync::network::Model;
use crate::lipsync::{Animator, ModelAnimator, recipe};
use crate::train::codec_features::{
    CodecFeatures, CodecPath, EVALUATION_QUALITY, augmentation_settings, quality,
};
use crate::train::control_targets::{ControlVideo, control_clips};
use crate::train::grid::{self, AUDIO_FRAME_S, LipClip};
use crate::train::grid_shapes::{self, ContourClip, KeyRule};
use crate::train::lag::{self, ClipSeries};
use crate::train::video::{
    VideoClip, VideoTraining, centre_each_clip, map_onto_head, mix_calls, prepare_clips,
    score_clips, score_controls, vary_voices,
};
use crate::vocab::{Viseme, VisemeSet};

#[derive(Debug, clap::Args)]
pub struct GridArgs {
    /// The GRID data: s1/{audio,tracks}, other-speakers/{audio,tracks}.
    #[arg(long, value_name = "DIR", default_value = "../shared/data/grid")]
    pub data: PathBuf,
    /// Where the clips' WAVs and lips CSVs go (s1/, other/) and lag.csv.
    #[arg(long, value_name = "DIR", default_value = "target/grid")]
    pub out: PathBuf,
}

/// Decodes a FLAC to a 16-bit WAV at its own rate with sox.
fn flac_to_wav(flac: &Path, wav_path: &Path) -> Result<()> {
    let status = Command::new("sox")
        .arg(flac)
        .args(["-b", "16"])
        .arg(wav_path)
        .status()
        .context("cannot run sox (apt install sox)")?;
    if !status.success() {
        bail!("sox could not decode {}", flac.display());
    }
    Ok(())
}

pub fn grid(args: &GridArgs) -> Result<()> {
    let mut s1_series = Vec::new();
    for (set, source) in grid::SETS.iter().zip(["s1", "other-speakers"]) {
        let tracks = args.data.join(source).join("tracks");
        let audio = args.data.join(source).join("audio");
        let out = args.out.join(set);
        std::fs::create_dir_all(&out)
            .with_context(|| format!("cannot create {}", out.display()))?;
        let names = crate::train::grid::clip_names(&tracks, ".csv")?;
        let (mut frames, mut tracked) = (0usize, 0usize);
        for name in &names {
            let wav_path = out.join(format!("{name}.wav"));
            flac_to_wav(&audio.join(format!("{name}.flac")), &wav_path)?;
            let sound = wav::read_mono(&wav_path)?;
            let track_path = tracks.join(format!("{name}.csv"));
            let text = crate::input::read_to_string(&track_path, crate::input::MAX_INPUT_BYTES)?;
            let video = grid::parse_track(&text, &track_path)?;
            let audio_frames =
                (sound.samples.len() as f64 / sound.rate as f64 / AUDIO_FRAME_S) as usize;
            let lips = grid::audio_frame_lips(&video, audio_frames, 0.0);
            frames += lips.len();
            tracked += lips.iter().flatten().count();
            grid::write_lips_csv(&out.join(format!("{name}.lips.csv")), &lips)?;
            if *set == "s1" {
                s1_series.push(ClipSeries {
                    aperture: lips.iter().map(|l| l.map(|l| l.aperture)).collect(),
                    energy_db: lag::frame_energy_db(&sound.samples, sound.rate),
                });
            }
        }
        eprintln!(
            "{set}: {} clips, {frames} audio frames of 20 ms, {tracked} with tracked lips -> {}",
            names.len(),
            out.display()
        );
    }
    report_lag(&s1_series, &args.out.join("lag.csv"))
}

fn report_lag(clips: &[ClipSeries], path: &Path) -> Result<()> {
    let level = lag::cross_correlation(clips, 10, false);
    let onsets = lag::cross_correlation(clips, 10, true);
    let mut csv = String::from("lag_ms,r_aperture_energy,r_aperture_change_energy_change\n");
    for ((k, r), (_, d)) in level.iter().zip(&onsets) {
        csv.push_str(&format!(
            "{},{r:.4},{d:.4}\n",
            (*k as f64 * AUDIO_FRAME_S * 1000.0).round()
        ));
    }
    std::fs::write(path, csv).with_context(|| format!("cannot write {}", path.display()))?;
    let ms = |frames: Option<f64>| frames.map_or(f64::NAN, |f| f * AUDIO_FRAME_S * 1000.0);
    println!(
        "s1 audio-visual lag (positive: the lips lead the sound): aperture vs energy peaks at \
         {:.0} ms, aperture change vs energy change (onsets) at {:.0} ms; curves in {}",
        ms(lag::peak_lag(&level)),
        ms(lag::peak_lag(&onsets)),
        path.display()
    );
    Ok(())
}

/// `train`'s options for measured lips.
#[derive(Debug, clap::Args)]
pub struct LipTrainArgs {
    /// The data step's output (`lipcall grid --out DIR`): train on s1's measured lips too
    /// (his held-out clips and the other speakers' never).
    #[arg(long, value_name = "DIR")]
    pub grid: Option<PathBuf>,
    /// Loss weight of a video frame against a phone-labelled frame's 1.
    #[arg(long, value_name = "W", default_value_t = recipe::LIP_WEIGHT)]
    pub lip_weight: f32,
    /// s1 training clips used (of his 898 not held out).
    #[arg(long, value_name = "N", default_value_t = recipe::LIP_CLIPS)]
    pub lip_clips: usize,
    /// Codec versions of each of them.
    #[arg(long, value_name = "N", default_value_t = recipe::LIP_VERSIONS)]
    pub lip_versions: usize,
    /// The lips each audio frame is trained towards are this much earlier than the frame
    /// (a multiple of 20 ms), for lips that lead their sound by more than the one frame the
    /// network sees ahead (s1's trail it: 0).
    #[arg(long, value_name = "MS", default_value_t = recipe::LIP_SHIFT_MS)]
    pub lip_shift_ms: u32,
    /// Vocal-tract-length augmentation of s1's voice: each clip version's LSPs scaled by its
    /// own factor in [1 - W, 1 + W]; 0 = off.
    #[arg(long, value_name = "W", default_value_t = 0.0)]
    pub lip_warp: f32,
    /// Each s1 clip a call of its own (the speaker normalisation starts afresh, as for a
    /// newcomer's first seconds) instead of all of them one long call.
    #[arg(long)]
    pub lip_calls: bool,
    /// Every second s1 clip version a call of its own, the rest one long call: the network
    /// meets the speaker normalisation both unsettled (a call's first seconds, each of the
    /// other speakers' clips) and settled.
    #[arg(long, conflicts_with = "lip_calls")]
    pub lip_mixed_calls: bool,
    /// Early stopping also watches the other speakers' lips (the clips never trained on, each
    /// mapped onto the head's scale by its own mean and spread): validation across speakers.
    #[arg(long)]
    pub lip_validation: bool,
    /// Each clip's lips moved to the mean of all clips (what differs between recordings is
    /// not what the voice says).
    #[arg(long)]
    pub lip_centre: bool,
    /// s1's phone alignments (NAME.phn): with `train --controls`, the rounding, closure and
    /// lower-lip targets of his video frames, and the rest his lips are measured from.
    #[arg(long, value_name = "DIR", default_value = "tools/alignments/grid-s1")]
    pub lip_alignments: PathBuf,
}

/// `evaluate`'s options for measured lips.
#[derive(Debug, clap::Args)]
pub struct LipEvalArgs {
    /// Also score aperture and width against the measured lips of the GRID clips the data
    /// step wrote here (s1's held-out clips and the other speakers').
    #[arg(long, value_name = "DIR")]
    pub grid: Option<PathBuf>,
    /// Which of those clips: s1's held-out ones (cheap to tune on), the other speakers'
    /// (validation: look sparingly), or both.
    #[arg(long, value_name = "SET", value_enum, default_value_t = LipSet::Both)]
    pub lip_set: LipSet,
    /// Also score the network's width against the lips of up to this many frames before and
    /// after each audio frame (does the tracked width lead or trail the sound?).
    #[arg(long, value_name = "FRAMES", default_value_t = 0, value_parser = clap::value_parser!(u8).range(0..=5))]
    pub lip_lags: u8,
    /// Each of s1's held-out clips a call of its own (the speaker normalisation starts afresh,
    /// as it does for each other speaker's clip) instead of all of them one long call.
    #[arg(long)]
    pub lip_calls: bool,
}

/// The GRID clips `evaluate --grid` scores.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LipSet {
    HeldOut,
    Others,
    Both,
}

/// The training clip versions as calls: each its own (`--lip-calls`, and with `--lip-warp`
/// each its own voice), or every second one (`--lip-mixed-calls`); else one long call.
fn split_into_calls(prepared: &mut Vec<VideoClip>, args: &LipTrainArgs) {
    if args.lip_calls || args.lip_warp > 0.0 {
        vary_voices(prepared, args.lip_warp, recipe::SEED);
    }
    if args.lip_mixed_calls {
        mix_calls(prepared);
    }
}

/// s1's training clips (all but the held-out tenth), the first `limit`.
fn s1_training_clips(root: &Path, limit: usize) -> Result<Vec<LipClip>> {
    Ok(grid::load_clips(root, "s1")?
        .into_iter()
        .enumerate()
        .filter(|(i, _)| !grid::s1_held_out(*i))
        .map(|(_, c)| c)
        .take(limit)
        .collect())
}

/// The video half of training and, with `--lip-validation`, the other speakers' lips for
/// early stopping; `None`s without `--grid`.
pub fn video_training(
    args: &LipTrainArgs,
    codec: &CodecFeatures,
) -> Result<(Option<VideoTraining>, Option<VideoTraining>)> {
    let Some(root) = &args.grid else {
        return Ok((None, None));
    };
    if !(args.lip_weight.is_finite() && args.lip_weight >= 0.0) {
        bail!("--lip-weight must be a finite number of 0 or more");
    }
    if !args.lip_shift_ms.is_multiple_of(20) || args.lip_shift_ms > 100 {
        bail!("--lip-shift-ms must be a multiple of 20 ms up to 100");
    }
    if !(args.lip_warp.is_finite() && (0.0..0.5).contains(&args.lip_warp)) {
        bail!("--lip-warp must be in [0, 0.5), not {}", args.lip_warp);
    }
    let clips = s1_training_clips(root, args.lip_clips)?;
    let shift = -((args.lip_shift_ms / 20) as i32);
    let mut prepared = prepare_clips(
        codec,
        &clips,
        &augmentation_settings(),
        args.lip_versions,
        shift,
    )?;
    split_into_calls(&mut prepared, args);
    if args.lip_centre {
        centre_each_clip(&mut prepared);
    }
    let map = map_onto_head(
        &mut ModelAnimator::new(&crate::lipsync::default_model()),
        &mut prepared,
    );
    eprintln!(
        "measured lips: {} of s1's training clips at {} codec setting(s), {} ms earlier than \
         their audio frames, weight {}, warp {}{}; aperture x{:.2}{:+.3}, width x{:.2}{:+.3} \
         onto the head's scale",
        clips.len(),
        args.lip_versions,
        args.lip_shift_ms,
        args.lip_weight,
        args.lip_warp,
        if args.lip_calls {
            ", each clip its own call"
        } else {
            ""
        },
        map[0].0,
        map[0].1,
        map[1].0,
        map[1].1
    );
    let validation = if args.lip_validation {
        let speex = CodecPath::Speex(quality(EVALUATION_QUALITY));
        let mut others = prepare_clips(codec, &grid::load_clips(root, "other")?, &[speex], 1, 0)?;
        let shipped_model = crate::lipsync::default_model();
        let mut shipped = ModelAnimator::new(&shipped_model);
        for clip in &mut others {
            map_onto_head(&mut shipped, std::slice::from_mut(clip));
        }
        eprintln!(
            "early stopping also watches the lips of {} other speakers' clips",
            others.len()
        );
        Some(others)
    } else {
        None
    };
    let training = |clips| VideoTraining {
        clips: Arc::new(clips),
        frame_weight: args.lip_weight,
        cue_weights: [recipe::LIP_CUE_WEIGHT; 2],
    };
    Ok((Some(training(prepared)), validation.map(training)))
}

/// A control network's video half (`train --controls --grid DIR`): s1's training clips through
/// the codec paths, their lips as measured (each clip above its own rest), his phones for the
/// other controls; `None` without `--grid`.
pub fn control_video(args: &LipTrainArgs, codec: &CodecFeatures) -> Result<Option<ControlVideo>> {
    let Some(root) = &args.grid else {
        return Ok(None);
    };
    if !(args.lip_weight.is_finite() && args.lip_weight >= 0.0) {
        bail!("--lip-weight must be a finite number of 0 or more");
    }
    if !args.lip_shift_ms.is_multiple_of(20) || args.lip_shift_ms > 100 {
        bail!("--lip-shift-ms must be a multiple of 20 ms up to 100");
    }
    let clips = s1_training_clips(root, args.lip_clips)?;
    let shift = -((args.lip_shift_ms / 20) as i32);
    let mut prepared = prepare_clips(
        codec,
        &clips,
        &augmentation_settings(),
        args.lip_versions,
        shift,
    )?;
    split_into_calls(&mut prepared, args);
    let clips = control_clips(&prepared, Some(&args.lip_alignments))?;
    let frames = clips.iter().flat_map(|c| &c.targets).flatten().count();
    eprintln!(
        "measured lips as control targets: {} clip versions of s1's training clips, {frames} \
         tracked frames, weight {}, {} ms earlier than their audio frames, warp {}{}",
        clips.len(),
        args.lip_weight,
        args.lip_shift_ms,
        args.lip_warp,
        if args.lip_calls {
            ", each clip its own call"
        } else if args.lip_mixed_calls {
            ", every second clip version its own call"
        } else {
            ""
        }
    );
    Ok(Some(ControlVideo {
        clips: Arc::new(clips),
        frame_weight: args.lip_weight,
    }))
}

/// Prints aperture and width r of `model` (and of the jaw baseline) against the measured lips
/// of s1's held-out clips and of the other speakers' clips, through `path`.
pub fn evaluate_lips(args: &LipEvalArgs, model: &Model, path: CodecPath) -> Result<()> {
    let Some(root) = &args.grid else {
        return Ok(());
    };
    let codec = CodecFeatures::new();
    let held_out: Vec<LipClip> = grid::load_clips(root, "s1")?
        .into_iter()
        .enumerate()
        .filter(|(i, _)| grid::s1_held_out(*i))
        .map(|(_, c)| c)
        .collect();
    let others = match args.lip_set {
        LipSet::HeldOut => Vec::new(),
        _ => grid::load_clips(root, "other")?,
    };
    let sets = [("s1 held out", &held_out), ("9 other speakers", &others)];
    let sets = match args.lip_set {
        LipSet::HeldOut => &sets[..1],
        LipSet::Others => &sets[1..],
        LipSet::Both => &sets[..],
    };
    println!("measured lips (GRID), {path}: Pearson r of the face's lips against the video's");
    println!("| clips | animator | aperture r | width r | per-clip mean aperture r / width r |");
    println!("|---|---|---|---|---|");
    for &(name, clips) in sets {
        let mut prepared = prepare_clips(&codec, clips, &[path], 1, 0)?;
        if args.lip_calls {
            vary_voices(&mut prepared, 0.0, recipe::SEED);
        }
        let rows: [(&str, Box<dyn Animator>); 2] = [
            ("network", Box::new(ModelAnimator::new(model))),
            ("jaw baseline", Box::new(JawBaseline::from_model(model))),
        ];
        for (animator_name, mut animator) in rows {
            let s = score_clips(animator.as_mut(), &prepared);
            println!(
                "| {name} ({} clips, {} frames) | {animator_name} | {:.3} | {:.3} | {:.3} / {:.3} |",
                s.clips, s.frames, s.aperture_r, s.width_r, s.clip_aperture_r, s.clip_width_r
            );
        }
        let most = i32::from(args.lip_lags);
        let lags: Vec<i32> = std::iter::once(0)
            .chain((-most..=most).filter(|&lag| lag != 0))
            .collect();
        let scores = score_controls(model, &prepared, &lags)?;
        let s = &scores[0];
        println!(
            "| {name} ({} clips, {} frames) | network's controls (aperture, width) | {:.3} | {:.3} | {:.3} / {:.3} |",
            s.clips, s.frames, s.aperture_r, s.width_r, s.clip_aperture_r, s.clip_width_r
        );
        for (lag, s) in lags.iter().zip(&scores).skip(1) {
            println!(
                "| {name} | network's controls against the lips {lag:+} frames on | {:.3} | {:.3} | {:.3} / {:.3} |",
                s.aperture_r, s.width_r, s.clip_aperture_r, s.clip_width_r
            );
        }
    }
    Ok(())
}

/// `decompose --grid`'s options.
#[derive(Debug, clap::Args)]
pub struct RealLipsArgs {
    /// Table I on GRID s1's tracked lips instead (the GRID data folder).
    #[arg(long, value_name = "DIR", conflicts_with = "markers")]
    pub grid: Option<PathBuf>,
    /// s1's phone alignments for --grid (tools/align_grid.py).
    #[arg(long, value_name = "DIR", default_value = "tools/alignments/grid-s1")]
    pub phones: PathBuf,
    /// With --grid: write how each viseme shapes s1's lips (aperture, width, protrusion, lower
    /// lip; relative to his rest, from his training clips) to OUT.csv, instead of Table I.
    #[arg(long, value_name = "OUT.csv", requires = "grid")]
    pub viseme_lips: Option<PathBuf>,
}

/// `lipcall decompose --grid`: Table I on GRID s1's real lips (see [`grid_shapes`]): key shapes
/// from the phone centres of his training clips, every frame of his held-out clips and of the
/// other speakers decomposed onto them.
pub fn decompose_grid(args: &RealLipsArgs, chosen: Option<&str>) -> Result<()> {
    let phones = args.phones.as_path();
    let data = args
        .grid
        .as_deref()
        .context("decompose --grid needs the GRID folder")?;
    let clips = grid_shapes::load_s1(data, phones)?;
    let training: Vec<&ContourClip> = clips.iter().filter(|c| !c.1).map(|c| &c.0).collect();
    if let Some(out) = &args.viseme_lips {
        return write_viseme_lips(&training, out);
    }
    let held_out: Vec<&ContourClip> = clips.iter().filter(|c| c.1).map(|c| &c.0).collect();
    let others = grid_shapes::load_other(data)?;
    let others: Vec<&ContourClip> = others.iter().collect();
    let rules = [KeyRule::Mean, KeyRule::ClearestQuarter];
    let keyed: Vec<_> = rules
        .iter()
        .map(|&rule| grid_shapes::key_shapes(&training, 0.0, KEY_SHAPE_MIN_CENTRES, rule))
        .collect::<Result<_, _>>()?;
    println!(
        "Table I on real lips: GRID s1's lip contour ({} points, eye line level, eye width \
         unit, centred on the outer lip); key shapes from the phone centres of {} training \
         clips ({}): the mean contour, or the mean of the clearest quarter; decomposed: every \
         frame of s1's {} held-out clips and of the {} other-speaker clips",
        grid_shapes::CONTOUR.len(),
        training.len(),
        phones.display(),
        held_out.len(),
        others.len()
    );
    println!("key shape  centres  lip gap, width (eye widths): mean / clearest quarter");
    let (shapes, counts) = &keyed[0];
    for v in shapes.visemes() {
        let (gap, width) = grid_shapes::gap_and_width(shapes.shape(v)?);
        let (gap_q, width_q) = grid_shapes::gap_and_width(keyed[1].0.shape(v)?);
        println!(
            "{:<9} {:>8}  {gap:.3} {width:.3} / {gap_q:.3} {width_q:.3}",
            v.name(),
            counts[v.index()],
        );
    }
    let mut sets: Vec<VisemeSet> = (2..=6)
        .filter_map(|n| VisemeSet::reduced(n).ok())
        .filter(|s| shapes.for_set(s).is_ok())
        .collect();
    // The shipped network's set where the clips show all of it, the chosen one (which must),
    // and every viseme that has a key shape.
    let shipped = VisemeSet::parse(recipe::VISEMES)?;
    let mut extra: Vec<VisemeSet> = Vec::new();
    extra.extend(shapes.for_set(&shipped).is_ok().then_some(shipped));
    if let Some(names) = chosen {
        let set = VisemeSet::parse(names)?;
        shapes
            .for_set(&set)
            .with_context(|| format!("{set}: a viseme has no key shape"))?;
        extra.push(set);
    }
    let all: Vec<Viseme> = shapes
        .visemes()
        .into_iter()
        .filter(|v| *v != Viseme::Sil)
        .collect();
    extra.extend(VisemeSet::new(all).ok());
    for set in extra {
        if !sets.contains(&set) {
            sets.push(set);
        }
    }
    let s1_track = grid_shapes::contour_track(&held_out)?;
    let other_track = grid_shapes::contour_track(&others)?;
    let mut tables = Vec::new();
    for (shapes, _) in &keyed {
        tables.push(table_i(&s1_track, shapes, &sets)?);
        tables.push(table_i(&other_track, shapes, &sets)?);
    }
    println!(
        "Eq. 1 error on the important points: s1 held out ({} of {} points, {} frames), other \
         speakers ({} points, {} frames)",
        tables[0].important_points.len(),
        grid_shapes::CONTOUR.len(),
        tables[0].frames,
        tables[1].important_points.len(),
        tables[1].frames
    );
    println!(
        "{:>3}  {:<40} {:>19} {:>19}",
        "No.", "Visemes", "mean: s1 / others", "clearest: s1 / others"
    );
    for (i, row) in tables[0].rows.iter().enumerate() {
        let e = |t: usize| 100.0 * tables[t].rows[i].error;
        println!(
            "{:>3}  {:<40} {:>7.2}% / {:>6.2}%  {:>7.2}% / {:>6.2}%",
            row.set.len(),
            row.set.to_string().replace(',', " "),
            e(0),
            e(1),
            e(2),
            e(3)
        );
    }
    Ok(())
}

/// `decompose --grid --viseme-lips OUT.csv`: each viseme's lip measures at its phone centres in
/// s1's training clips, relative to each clip's rest ([`grid_shapes::viseme_lips`]); a first
/// row `rest` holds his rest shape itself.
fn write_viseme_lips(training: &[&ContourClip], out: &Path) -> Result<()> {
    let (rest, rows) = grid_shapes::viseme_lips(training, 0.0, KEY_SHAPE_MIN_CENTRES);
    let names = LipTargets::NAMES;
    let mut csv = format!(
        "viseme,centres,{},{},{}\n",
        names.join(","),
        names.map(|n| format!("{n}_sd")).join(","),
        names.map(|n| format!("{n}_clear")).join(",")
    );
    let values = |v: &[f32; 4]| v.map(|x| format!("{x:.5}")).join(",");
    csv.push_str(&format!(
        "rest,{},{},{},{}\n",
        training.len(),
        values(&rest),
        values(&[0.0; 4]),
        values(&rest)
    ));
    println!(
        "s1's lips per viseme at the phone centres of his {} training clips, relative to each \
         clip's rest (silence centres), eye widths; rest: aperture {:.3} width {:.3} protrusion \
         {:.3} lower_lip_back {:.3}",
        training.len(),
        rest[0],
        rest[1],
        rest[2],
        rest[3]
    );
    println!(
        "viseme  centres  mean (sd) / clearest quarter: {}",
        names.join(", ")
    );
    for row in &rows {
        csv.push_str(&format!(
            "{},{},{},{},{}\n",
            row.viseme.name(),
            row.centres,
            values(&row.mean),
            values(&row.sd),
            values(&row.clear)
        ));
        let cells: Vec<String> = (0..4)
            .map(|k| {
                format!(
                    "{:+.3} ({:.3}) / {:+.3}",
                    row.mean[k], row.sd[k], row.clear[k]
                )
            })
            .collect();
        println!(
            "{:<7} {:>7}  {}",
            row.viseme.name(),
            row.centres,
            cells.join("   ")
        );
    }
    std::fs::write(out, csv).with_context(|| format!("cannot write {}", out.display()))?;
    println!("-> {}", out.display());
    Ok(())
}

/// A viseme needs this many phone centres for a key shape (GRID's small vocabulary leaves some,
/// such as /ch/, nearly unseen).
const KEY_SHAPE_MIN_CENTRES: usize = 30;
