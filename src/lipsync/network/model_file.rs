//! The model file: text, UTF-8, fit for `include_str!`; version 3 written for viseme outputs,
//! 4 for articulatory ones; 1 to 4 read.
//!
//! ```text
//! # any number of comment lines (kept as notes), e.g. what the weights were trained on
//! lipcall-viseme-mlp 3
//! visemes PP aa I O E FF        names from the 15, in output order (version 4: the shapes the
//!                               controls are decomposed onto)
//! outputs controls              (version 4 only) the output layer gives the 6 controls
//!                               (lipsync::controls order) instead of the softmax over visemes
//! context 2                     frames fed besides the newest one
//! lookahead 1                   (version 3) of those frames, how many lie after the frame the
//!                               output describes (0: the output describes the newest frame)
//! normalise 150 <10 numbers>    (version 3) per-speaker LSP normalisation: the running mean of
//!                               the speech frames' LSPs (over about 150 of them, starting
//!                               from the 10 prior means) is replaced by the prior; `off`
//! dynamics 0.15 6               (version 2) peak decay dB/frame, extra energy-only past frames;
//!                               `dynamics off` for the 11 raw features only
//! closure_snap 0.55             (version 2) closed-viseme weight that snaps to a full closure;
//!                               0 = off; optionally followed by `nlsf 0.6 analysis 0.5`, the
//!                               thresholds for rows of those feature families (else the same)
//! sharpness 1.6                 (optional; absent = 1) the logits are multiplied by this
//!                               before the softmax (the convex weights raised to this power
//!                               and renormalised), so the dominant shape leads more decisively;
//!                               from 0.25 to 4; `sharpness 1.6 open-shapes`: the closed
//!                               shape keeps its weight and only the others are sharpened
//!                               among themselves (the closures stay the closure snap's)
//! smoothing 0.5                 (optional; absent = 0) the weights shown are a running mean:
//!                               each frame's own weights count 1 - this, from 0 to 0.9
//! hidden 10                     hidden units
//! input_offset <11 numbers>     scaled input = clamp((x - offset) * scale, -1, 1)
//! input_scale <11 numbers>      in the order lsp1..lsp10, energy_db
//! w1 <hidden x inputs numbers>  row-major, one row per hidden unit
//! b1 <hidden numbers>
//! w2 <outputs x hidden numbers> row-major, one row per viseme
//! b2 <outputs numbers>
//! end
//! ```
//!
//! Version 1 files (no `dynamics` and `closure_snap` lines) still load, as raw-feature models;
//! version 2 files (no `lookahead` line) as models without look-ahead.
//!
//! Numbers are written in Rust's shortest round-trip form, so a save and load gives
//! bit-identical weights. Anything malformed, missing or trailing is a [`ModelError`].

use std::fmt::Write as _;
use std::path::Path;

use super::normalise::{MAX_ENERGY_CONTEXT, MAX_NORM_FRAMES};
use super::{
    Dynamics, FEATURES_PER_FRAME, InputScaling, MAX_LOOKAHEAD, MAX_SHARPNESS, MAX_SMOOTHING,
    MIN_SHARPNESS, Model, OutputKind, SpeakerNorm, input_count,
};
use crate::lipsync::controls::CONTROL_COUNT;
use crate::vocab::LSP_COUNT;
use crate::vocab::{VisemeError, VisemeSet};

const MAGIC: &str = "lipcall-viseme-mlp";
const VERSION: &str = "3";
/// Articulatory outputs (lip-sync v4).
const VERSION_FOUR: &str = "4";
const CONTROL_OUTPUTS: &str = "controls";
const VERSION_TWO: &str = "2";
const OLD_VERSION: &str = "1";
/// The largest weight, bias or scale a model file may hold.
const MAX_PARAMETER: f32 = 1.0e4;
const MAX_CONTEXT: usize = 32;
const MAX_HIDDEN: usize = 1024;
/// Largest model file read: the largest network allowed (1024 hidden units over 32 frames of
/// context) writes about 7 MB of text.
const MAX_MODEL_BYTES: u64 = 32 << 20;

impl Model {
    /// The model in its text file format (version 2).
    pub fn to_text(&self) -> String {
        let mut text = String::new();
        for note in &self.notes {
            let _ = writeln!(text, "# {note}");
        }
        if self.has_control_outputs() {
            let _ = writeln!(text, "{MAGIC} {VERSION_FOUR}");
            let _ = writeln!(text, "visemes {}", self.viseme_names().join(" "));
            let _ = writeln!(text, "outputs {CONTROL_OUTPUTS}");
        } else {
            let _ = writeln!(text, "{MAGIC} {VERSION}");
            let _ = writeln!(text, "visemes {}", self.viseme_names().join(" "));
        }
        let _ = writeln!(text, "context {}", self.context);
        let _ = writeln!(text, "lookahead {}", self.lookahead);
        match &self.speaker_norm {
            Some(norm) => {
                let _ = write!(text, "normalise {}", norm.frames);
                for p in norm.prior {
                    let _ = write!(text, " {p}");
                }
                text.push('\n');
            }
            None => text.push_str("normalise off\n"),
        }
        match self.dynamics {
            Some(d) => {
                let _ = writeln!(text, "dynamics {} {}", d.peak_decay_db, d.energy_context);
            }
            None => text.push_str("dynamics off\n"),
        }
        let _ = write!(text, "closure_snap {}", self.closure_snap);
        for (name, snap) in [("nlsf", self.nlsf_snap), ("analysis", self.analysis_snap)] {
            if let Some(snap) = snap {
                let _ = write!(text, " {name} {snap}");
            }
        }
        text.push('\n');
        if self.sharpness != 1.0 || self.sharpen_open_shapes_only {
            let _ = write!(text, "sharpness {}", self.sharpness);
            if self.sharpen_open_shapes_only {
                text.push_str(" open-shapes");
            }
            text.push('\n');
        }
        if self.smoothing != 0.0 {
            let _ = writeln!(text, "smoothing {}", self.smoothing);
        }
        let _ = writeln!(text, "hidden {}", self.hidden);
        for (key, values) in [
            ("input_offset", &self.scaling.offset[..]),
            ("input_scale", &self.scaling.scale[..]),
            ("w1", &self.w1),
            ("b1", &self.b1),
            ("w2", &self.w2),
            ("b2", &self.b2),
        ] {
            text.push_str(key);
            for v in values {
                let _ = write!(text, " {v}");
            }
            text.push('\n');
        }
        text.push_str("end\n");
        text
    }

    /// Parses the text file format (versions 1 to 4).
    pub fn from_text(text: &str) -> Result<Self, ModelError> {
        let mut lines = KeyedLines::new(text);
        let mut next = |key| lines.next(key);

        let (line, version) = next(MAGIC).map_err(|e| match e {
            ModelError::UnexpectedKey { .. } | ModelError::Truncated(_) => ModelError::NotAModel,
            other => other,
        })?;
        let version_four = version[..] == [VERSION_FOUR];
        let (version_two, version_three) = match version[..] {
            [v] if v == VERSION || v == VERSION_FOUR => (true, true),
            [v] if v == VERSION_TWO => (true, false),
            [v] if v == OLD_VERSION => (false, false),
            _ => {
                return Err(ModelError::Version {
                    line,
                    found: version.join(" "),
                });
            }
        };
        let (line, names) = next("visemes")?;
        let visemes = VisemeSet::parse(&names.join(","))
            .map_err(|error| ModelError::Visemes { line, error })?;
        let output_kind = if version_four {
            let (line, words) = next("outputs")?;
            if words[..] != [CONTROL_OUTPUTS] {
                return Err(ModelError::BadNumber {
                    line,
                    key: "outputs",
                    text: words.join(" "),
                });
            }
            OutputKind::Controls
        } else {
            OutputKind::Visemes
        };
        let context = parse_size(next("context")?, "context", MAX_CONTEXT)?;
        let lookahead = if version_three {
            let (line, words) = next("lookahead")?;
            let lookahead = parse_size((line, words), "lookahead", MAX_LOOKAHEAD)?;
            if lookahead > context {
                return Err(ModelError::OutOfRange {
                    line,
                    key: "lookahead",
                    value: lookahead,
                    max: context,
                });
            }
            lookahead
        } else {
            0
        };
        let speaker_norm = if version_three {
            let (line, words) = next("normalise")?;
            match words[..] {
                ["off"] => None,
                [frames, ..] => {
                    let frames =
                        parse_size((line, vec![frames]), "normalise", MAX_NORM_FRAMES as usize)?;
                    let prior = parse_floats((line, words[1..].to_vec()), "normalise", LSP_COUNT)?;
                    if frames == 0
                        || prior
                            .iter()
                            .any(|p| !(0.0..=std::f32::consts::PI).contains(p))
                    {
                        return Err(ModelError::BadNumber {
                            line,
                            key: "normalise",
                            text: words.join(" "),
                        });
                    }
                    let mut norm = SpeakerNorm {
                        frames: frames as u32,
                        prior: [0.0; LSP_COUNT],
                    };
                    norm.prior.copy_from_slice(&prior);
                    Some(norm)
                }
                [] => {
                    return Err(ModelError::WrongCount {
                        line,
                        key: "normalise",
                        expected: 1 + LSP_COUNT,
                        found: 0,
                    });
                }
            }
        } else {
            None
        };
        let (dynamics, closure_snaps) = if version_two {
            let (line, words) = next("dynamics")?;
            let dynamics = match words[..] {
                ["off"] => None,
                [decay, extra] => {
                    let decay = parse_floats((line, vec![decay]), "dynamics", 1)?[0];
                    if !(0.0..=10.0).contains(&decay) {
                        return Err(ModelError::BadNumber {
                            line,
                            key: "dynamics",
                            text: decay.to_string(),
                        });
                    }
                    let energy_context = parse_size(
                        (line, vec![extra]),
                        "dynamics energy context",
                        MAX_ENERGY_CONTEXT,
                    )?;
                    Some(Dynamics {
                        peak_decay_db: decay,
                        energy_context,
                    })
                }
                _ => {
                    return Err(ModelError::WrongCount {
                        line,
                        key: "dynamics",
                        expected: 2,
                        found: words.len(),
                    });
                }
            };
            let (line, words) = next("closure_snap")?;
            (dynamics, parse_closure_snaps(line, &words)?)
        } else {
            (None, [Some(0.0), None, None])
        };
        let [closure_snap, nlsf_snap, analysis_snap] = closure_snaps;
        let closure_snap = closure_snap.unwrap_or(0.0);
        let (sharpness, sharpen_open_shapes_only) = match lines.optional("sharpness") {
            Some(found) if version_three => parse_sharpness(found)?,
            Some((line, _)) => {
                return Err(ModelError::UnexpectedKey {
                    line,
                    expected: "hidden",
                    found: "sharpness".into(),
                });
            }
            None => (1.0, false),
        };
        let smoothing = match lines.optional("smoothing") {
            Some(found) if version_three => parse_smoothing(found)?,
            Some((line, _)) => {
                return Err(ModelError::UnexpectedKey {
                    line,
                    expected: "hidden",
                    found: "smoothing".into(),
                });
            }
            None => 0.0,
        };
        let mut next = |key| lines.next(key);
        let hidden = parse_size(next("hidden")?, "hidden", MAX_HIDDEN)?;
        let inputs = input_count(context, dynamics);
        let outputs = match output_kind {
            OutputKind::Visemes => visemes.len(),
            OutputKind::Controls => CONTROL_COUNT,
        };
        let offset = parse_floats(next("input_offset")?, "input_offset", FEATURES_PER_FRAME)?;
        let scale = parse_floats(next("input_scale")?, "input_scale", FEATURES_PER_FRAME)?;
        let w1 = parse_floats(next("w1")?, "w1", hidden * inputs)?;
        let b1 = parse_floats(next("b1")?, "b1", hidden)?;
        let w2 = parse_floats(next("w2")?, "w2", outputs * hidden)?;
        let b2 = parse_floats(next("b2")?, "b2", outputs)?;
        let (line, rest) = next("end")?;
        if !rest.is_empty() {
            return Err(ModelError::TrailingData { line });
        }
        if let Some((line, _)) = lines.rest() {
            return Err(ModelError::TrailingData { line });
        }
        let mut scaling = InputScaling::new(-1.0, 1.0);
        scaling.offset.copy_from_slice(&offset);
        scaling.scale.copy_from_slice(&scale);
        Ok(Self {
            visemes,
            output_kind,
            scaling,
            context,
            lookahead,
            speaker_norm,
            dynamics,
            closure_snap,
            nlsf_snap,
            analysis_snap,
            sharpness,
            sharpen_open_shapes_only,
            smoothing,
            hidden,
            w1,
            b1,
            w2,
            b2,
            notes: lines.notes,
            articulation: None,
        })
    }

    pub fn load(path: &Path) -> Result<Self, ModelError> {
        let in_file = |error| ModelError::InFile {
            path: path.display().to_string(),
            error: Box::new(error),
        };
        let bytes = crate::input::read(path, MAX_MODEL_BYTES)?;
        let text = String::from_utf8(bytes).map_err(|_| in_file(ModelError::NotAModel))?;
        Self::from_text(&text).map_err(in_file)
    }

    /// Writes the model file; a model its own loader would refuse (the NaN or huge weights of
    /// a training that diverged) is not written.
    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        let text = self.to_text();
        Self::from_text(&text).map_err(|error| ModelError::WouldNotLoad(Box::new(error)))?;
        std::fs::write(path, text).map_err(|error| ModelError::Io {
            path: path.display().to_string(),
            error,
        })
    }
}

/// A model file's lines, each read as `key value...`; comment lines are kept as notes and
/// blank lines skipped.
struct KeyedLines<'t> {
    lines: std::iter::Peekable<std::iter::Enumerate<std::str::Lines<'t>>>,
    notes: Vec<String>,
}

impl<'t> KeyedLines<'t> {
    fn new(text: &'t str) -> Self {
        Self {
            lines: text.lines().enumerate().peekable(),
            notes: Vec::new(),
        }
    }

    /// The next line that is neither a comment nor blank, left unread: (line number, text).
    fn peek(&mut self) -> Option<(usize, &'t str)> {
        while let Some(&(i, line)) = self.lines.peek() {
            let line = line.trim();
            if let Some(note) = line.strip_prefix('#') {
                self.notes.push(note.trim().to_string());
            } else if !line.is_empty() {
                return Some((i + 1, line));
            }
            self.lines.next();
        }
        None
    }

    /// The next line, which must start with `key`: its number and the words after the key.
    fn next(&mut self, key: &'static str) -> Result<(usize, Vec<&'t str>), ModelError> {
        let (line, text) = self.peek().ok_or(ModelError::Truncated(key))?;
        let mut words = text.split_whitespace();
        let found = words.next().unwrap_or_default();
        if found != key {
            return Err(ModelError::UnexpectedKey {
                line,
                expected: key,
                found: found.to_string(),
            });
        }
        self.lines.next();
        Ok((line, words.collect()))
    }

    /// The next line if it starts with `key`, else nothing read.
    fn optional(&mut self, key: &'static str) -> Option<(usize, Vec<&'t str>)> {
        let (_, text) = self.peek()?;
        if text.split_whitespace().next() != Some(key) {
            return None;
        }
        self.next(key).ok()
    }

    /// Whatever is left.
    fn rest(&mut self) -> Option<(usize, &'t str)> {
        self.peek()
    }
}

const OPEN_SHAPES_ONLY: &str = "open-shapes";

/// `smoothing S`: a finite number from 0 to [`MAX_SMOOTHING`].
fn parse_smoothing((line, words): (usize, Vec<&str>)) -> Result<f32, ModelError> {
    let [word] = words[..] else {
        return Err(ModelError::WrongCount {
            line,
            key: "smoothing",
            expected: 1,
            found: words.len(),
        });
    };
    match word.parse::<f32>() {
        Ok(s) if (0.0..=MAX_SMOOTHING).contains(&s) => Ok(s),
        _ => Err(ModelError::Smoothing {
            line,
            text: word.to_string(),
        }),
    }
}

/// `sharpness G [open-shapes]`: a finite number from [`MIN_SHARPNESS`] to [`MAX_SHARPNESS`].
fn parse_sharpness((line, words): (usize, Vec<&str>)) -> Result<(f32, bool), ModelError> {
    let (word, open_shapes_only) = match words[..] {
        [word] => (word, false),
        [word, OPEN_SHAPES_ONLY] => (word, true),
        [_, other] => {
            return Err(ModelError::UnexpectedKey {
                line,
                expected: OPEN_SHAPES_ONLY,
                found: other.to_string(),
            });
        }
        _ => {
            return Err(ModelError::WrongCount {
                line,
                key: "sharpness",
                expected: 1,
                found: words.len(),
            });
        }
    };
    match word.parse::<f32>() {
        Ok(g) if (MIN_SHARPNESS..=MAX_SHARPNESS).contains(&g) => Ok((g, open_shapes_only)),
        _ => Err(ModelError::Sharpness {
            line,
            text: word.to_string(),
        }),
    }
}

fn parse_size(
    (line, words): (usize, Vec<&str>),
    key: &'static str,
    max: usize,
) -> Result<usize, ModelError> {
    let [word] = words[..] else {
        return Err(ModelError::WrongCount {
            line,
            key,
            expected: 1,
            found: words.len(),
        });
    };
    let value: usize = word.parse().map_err(|_| ModelError::BadNumber {
        line,
        key,
        text: word.to_string(),
    })?;
    if value > max || (key == "hidden" && value == 0) {
        return Err(ModelError::OutOfRange {
            line,
            key,
            value,
            max,
        });
    }
    Ok(value)
}

fn parse_floats(
    (line, words): (usize, Vec<&str>),
    key: &'static str,
    expected: usize,
) -> Result<Vec<f32>, ModelError> {
    if words.len() != expected {
        return Err(ModelError::WrongCount {
            line,
            key,
            expected,
            found: words.len(),
        });
    }
    words
        .iter()
        .map(|word| match word.parse::<f32>() {
            // Larger weights overflow the logits into NaN; no trained network comes near.
            Ok(v) if v.abs() <= MAX_PARAMETER => Ok(v),
            _ => Err(ModelError::BadNumber {
                line,
                key,
                text: word.to_string(),
            }),
        })
        .collect()
}

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("not a lipcall viseme model (the first line must be `{MAGIC} {VERSION}`)")]
    NotAModel,
    #[error(
        "line {line}: unsupported model version {found:?} (this build reads 1 to {VERSION_FOUR})"
    )]
    Version { line: usize, found: String },
    #[error("model file ends early: `{0}` is missing")]
    Truncated(&'static str),
    #[error("line {line}: expected `{expected}`, found {found:?}")]
    UnexpectedKey {
        line: usize,
        expected: &'static str,
        found: String,
    },
    #[error("line {line}: `{key}` has {found} values, expected {expected}")]
    WrongCount {
        line: usize,
        key: &'static str,
        expected: usize,
        found: usize,
    },
    #[error("line {line}: bad number {text:?} in `{key}`")]
    BadNumber {
        line: usize,
        key: &'static str,
        text: String,
    },
    #[error("line {line}: `{key}` {value} is out of range (at most {max})")]
    OutOfRange {
        line: usize,
        key: &'static str,
        value: usize,
        max: usize,
    },
    #[error("line {line}: {error}")]
    Visemes { line: usize, error: VisemeError },
    #[error(
        "line {line}: sharpness {text:?} is not a number from {MIN_SHARPNESS} to {MAX_SHARPNESS}"
    )]
    Sharpness { line: usize, text: String },
    #[error("line {line}: smoothing {text:?} is not a number from 0 to {MAX_SMOOTHING}")]
    Smoothing { line: usize, text: String },
    #[error("line {line}: data after `end`")]
    TrailingData { line: usize },
    #[error("{path}: {error}")]
    Io { path: String, error: std::io::Error },
    #[error(transparent)]
    Input(#[from] crate::input::InputError),
    #[error("the model would not load back (did training diverge?): {0}")]
    WouldNotLoad(Box<ModelError>),
    #[error("{path}: {error}")]
    InFile {
        path: String,
        error: Box<ModelError>,
    },
}

/// `closure_snap S [nlsf S] [analysis S]`: the default threshold and those of two families.
fn parse_closure_snaps(line: usize, words: &[&str]) -> Result<[Option<f32>; 3], ModelError> {
    let bad = |text: &str| ModelError::BadNumber {
        line,
        key: "closure_snap",
        text: text.to_string(),
    };
    let value = |text: &str| match text.parse::<f32>() {
        Ok(snap) if (0.0..=1.0).contains(&snap) => Ok(snap),
        _ => Err(bad(text)),
    };
    let Some((first, rest)) = words.split_first() else {
        return Err(ModelError::WrongCount {
            line,
            key: "closure_snap",
            expected: 1,
            found: 0,
        });
    };
    let mut snaps = [Some(value(first)?), None, None];
    if rest.len() % 2 != 0 {
        return Err(bad(&rest.join(" ")));
    }
    for pair in rest.chunks_exact(2) {
        let slot = match pair[0] {
            "nlsf" => 1,
            "analysis" => 2,
            other => return Err(bad(other)),
        };
        if snaps[slot].is_some() {
            return Err(bad(pair[0]));
        }
        snaps[slot] = Some(value(pair[1])?);
    }
    Ok(snaps)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lipsync::network::fixtures::sample_model;
    use crate::vocab::FeatureFamily;

    #[test]
    fn a_model_file_larger_than_any_model_is_not_read() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("huge.lipmodel");
        let file = std::fs::File::create(&path).unwrap();
        file.set_len(MAX_MODEL_BYTES + 1).unwrap();
        let e = Model::load(&path).unwrap_err();
        assert!(
            matches!(
                e,
                ModelError::Input(crate::input::InputError::TooLarge { .. })
            ),
            "{e}"
        );
    }

    #[test]
    fn a_model_the_loader_would_refuse_is_not_saved() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("diverged.lipmodel");
        let mut model = sample_model();
        model.w2[3] = f32::NAN;
        let e = model.save(&path).unwrap_err();
        assert!(matches!(e, ModelError::WouldNotLoad(_)), "{e}");
        assert!(e.to_string().contains("w2"), "{e}");
        assert!(!path.exists());
        model.w2[3] = 2.0 * MAX_PARAMETER;
        assert!(model.save(&path).is_err());
        model.w2[3] = 0.5;
        model.save(&path).unwrap();
        assert_eq!(Model::load(&path).unwrap().w2, model.w2);
    }

    #[test]
    fn model_file_round_trips_exactly() {
        let model = sample_model();
        let text = model.to_text();
        assert!(text.starts_with("# test weights\nlipcall-viseme-mlp 3\nvisemes PP aa I\n"));
        assert_eq!(Model::from_text(&text).unwrap(), model);
        let mut ahead = model.clone();
        ahead.lookahead = 1;
        ahead.speaker_norm = Some(SpeakerNorm {
            frames: 150,
            prior: crate::vocab::FrameFeatures::silent().lsp,
        });
        assert_eq!(Model::from_text(&ahead.to_text()).unwrap(), ahead);
        let mut families = model.clone();
        families.closure_snap = 0.6;
        families.nlsf_snap = Some(0.75);
        assert!(
            families
                .to_text()
                .contains("\nclosure_snap 0.6 nlsf 0.75\n")
        );
        assert_eq!(Model::from_text(&families.to_text()).unwrap(), families);
        families.analysis_snap = Some(0.5);
        assert_eq!(Model::from_text(&families.to_text()).unwrap(), families);
        assert_eq!(families.closure_snap_of(FeatureFamily::Bitstream), 0.6);
        assert_eq!(families.closure_snap_of(FeatureFamily::Nlsf), 0.75);
        assert_eq!(families.closure_snap_of(FeatureFamily::Analysis), 0.5);
        families.analysis_snap = None;
        assert_eq!(families.closure_snap_of(FeatureFamily::Analysis), 0.6);
    }

    #[test]
    fn control_models_are_version_four_and_viseme_models_stay_version_three() {
        let mut controls = sample_model().with_control_outputs();
        for (i, w) in controls.w2.iter_mut().enumerate() {
            *w = (i as f32 * 0.37).sin();
        }
        let text = controls.to_text();
        assert!(text.contains("lipcall-viseme-mlp 4\nvisemes PP aa I\noutputs controls\n"));
        let loaded = Model::from_text(&text).unwrap();
        assert_eq!(loaded, controls);
        assert_eq!(loaded.outputs(), CONTROL_COUNT);
        // Version 3 has no outputs line; version 4 needs a known one.
        assert!(Model::from_text(&text.replace(" 4\n", " 3\n")).is_err());
        assert!(Model::from_text(&text.replace("outputs controls", "outputs weights")).is_err());
        assert!(sample_model().to_text().contains("lipcall-viseme-mlp 3\n"));
        // The shipped v2 network still loads and is a viseme network.
        assert!(!crate::lipsync::default_model().has_control_outputs());
    }

    #[test]
    fn sharpness_round_trips_and_one_writes_nothing() {
        let model = sample_model();
        assert_eq!(model.sharpness, 1.0);
        assert!(!model.to_text().contains("sharpness"));
        let mut sharp = model.clone();
        sharp.sharpness = 1.6;
        let text = sharp.to_text();
        assert!(
            text.contains("\nclosure_snap 0\nsharpness 1.6\nhidden 4\n"),
            "{text}"
        );
        assert_eq!(Model::from_text(&text).unwrap(), sharp);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sharp.lipmodel");
        sharp.save(&path).unwrap();
        assert_eq!(Model::load(&path).unwrap().sharpness, 1.6);
        // The shipped file reads back byte for byte.
        let shipped = crate::lipsync::builtin::shipped();
        let file = include_str!("../../../assets/models/default.lipmodel");
        assert_eq!(shipped.to_text(), file);
    }

    #[test]
    fn smoothing_round_trips_and_a_bad_one_is_refused() {
        let model = sample_model();
        assert!(!model.to_text().contains("smoothing"));
        let mut smooth = model.clone();
        smooth.smoothing = 0.4;
        let text = smooth.to_text();
        assert!(text.contains("\nsmoothing 0.4\nhidden 4\n"), "{text}");
        assert_eq!(Model::from_text(&text).unwrap(), smooth);
        let plain = model.to_text();
        for bad in ["-0.1", "0.95", "NaN", "x", "0.5 0.5"] {
            let with = plain.replacen("hidden 4\n", &format!("smoothing {bad}\nhidden 4\n"), 1);
            let message = Model::from_text(&with).unwrap_err().to_string();
            assert!(message.contains("smoothing"), "{bad}: {message}");
        }
    }

    #[test]
    fn a_bad_sharpness_is_refused_with_its_line() {
        let text = sample_model().to_text();
        let with = |line: &str| text.replacen("hidden 4\n", &format!("{line}\nhidden 4\n"), 1);
        for bad in ["0", "-1", "0.2", "4.5", "NaN", "inf", "1e39", "x"] {
            let message = Model::from_text(&with(&format!("sharpness {bad}")))
                .unwrap_err()
                .to_string();
            assert!(
                message.contains(&format!(
                    "sharpness \"{bad}\" is not a number from 0.25 to 4"
                )),
                "{message}"
            );
        }
        assert!(matches!(
            Model::from_text(&with("sharpness 1 2")),
            Err(ModelError::UnexpectedKey {
                expected: "open-shapes",
                ..
            })
        ));
        for wrong in ["sharpness", "sharpness 1 open-shapes 2"] {
            assert!(
                matches!(
                    Model::from_text(&with(wrong)),
                    Err(ModelError::WrongCount {
                        key: "sharpness",
                        ..
                    })
                ),
                "accepted {wrong:?}"
            );
        }
        // Only where the format puts it, and not twice.
        assert!(Model::from_text(&with("sharpness 2\nsharpness 2")).is_err());
        let misplaced = text.replacen("context 2\n", "context 2\nsharpness 2\n", 1);
        assert!(Model::from_text(&misplaced).is_err());
        let v2 = with("sharpness 2")
            .replace("lipcall-viseme-mlp 3", "lipcall-viseme-mlp 2")
            .replace("lookahead 0\n", "")
            .replace("normalise off\n", "");
        assert!(Model::from_text(&v2).is_err());
        // The loader names the file.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.lipmodel");
        std::fs::write(&path, with("sharpness 9")).unwrap();
        let message = Model::load(&path).unwrap_err().to_string();
        assert!(
            message.contains("bad.lipmodel") && message.contains("sharpness \"9\""),
            "{message}"
        );
        // Nor is such a model written.
        let mut model = sample_model();
        model.sharpness = f32::NAN;
        assert!(model.save(&dir.path().join("nan.lipmodel")).is_err());
    }

    #[test]
    fn corrupt_model_files_are_typed_errors() {
        let text = sample_model().to_text();
        let cut = &text[..text.len() / 2];
        let truncated_at_line = cut.rfind('\n').map_or(cut, |i| &cut[..i]);
        assert!(matches!(
            Model::from_text(truncated_at_line),
            Err(ModelError::Truncated(_))
        ));
        assert!(matches!(
            Model::from_text(cut),
            Err(ModelError::WrongCount { .. } | ModelError::BadNumber { .. })
        ));
        assert!(matches!(Model::from_text(""), Err(ModelError::NotAModel)));
        assert!(matches!(
            Model::from_text("GIF89a"),
            Err(ModelError::NotAModel)
        ));
        let cases = [
            ("lipcall-viseme-mlp 3\n", "lipcall-viseme-mlp 4\n"),
            ("lookahead 0", "lookahead 3"),
            ("lookahead 0", "lookahead 1 1"),
            ("normalise off", "normalise 150 1 2"),
            ("normalise off", "normalise 0 1 2 3 4 5 6 7 8 9 10"),
            ("normalise off", "normalise"),
            ("dynamics off", "dynamics 1"),
            ("closure_snap 0", "closure_snap 2"),
            ("closure_snap 0", "closure_snap 0.5 nlsf"),
            ("closure_snap 0", "closure_snap 0.5 nlsf 1.5"),
            ("closure_snap 0", "closure_snap 0.5 speex 0.5"),
            ("closure_snap 0", "closure_snap 0.5 nlsf 0.4 nlsf 0.6"),
            ("closure_snap 0", "closure_snap"),
            ("visemes PP aa I", "visemes PP xx I"),
            ("hidden 4", "hidden 99999999"),
            ("hidden 4", "hidden 0"),
            ("context 2", "context -1"),
            ("end\n", "end\nw1 1\n"),
        ];
        for (from, to) in cases {
            let broken = text.replacen(from, to, 1);
            assert!(Model::from_text(&broken).is_err(), "accepted {to:?}");
        }
        for bad in ["1e999", "NaN", "x", "3e38"] {
            let broken: Vec<String> = text
                .lines()
                .map(|line| match line.strip_prefix("b1 ") {
                    Some(values) => {
                        let rest = values.split_once(' ').map_or("", |(_, r)| r);
                        format!("b1 {bad} {rest}")
                    }
                    None => line.to_string(),
                })
                .collect();
            let message = Model::from_text(&broken.join("\n"))
                .unwrap_err()
                .to_string();
            assert!(
                message.contains(&format!("bad number \"{bad}\" in `b1`")),
                "{message}"
            );
        }
    }

    #[test]
    fn version_one_files_load_as_raw_feature_models() {
        let v3 = sample_model().to_text();
        let v2 = v3
            .replace("lipcall-viseme-mlp 3", "lipcall-viseme-mlp 2")
            .replace("lookahead 0\n", "")
            .replace("normalise off\n", "");
        assert_eq!(Model::from_text(&v2).unwrap(), sample_model());
        let v1 = v2
            .replace("lipcall-viseme-mlp 2", "lipcall-viseme-mlp 1")
            .replace("dynamics off\n", "")
            .replace("closure_snap 0\n", "");
        let model = Model::from_text(&v1).unwrap();
        assert_eq!(model, sample_model());
        assert_eq!(model.dynamics, None);
    }
}
