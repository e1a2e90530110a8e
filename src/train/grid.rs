//! GRID audiovisual clips as training and scoring material: the tracked landmarks of each video
//! frame turned into visual lip targets ([`crate::lipsync::lips`]) and resampled onto the 20 ms
//! audio frames that every codec path's features come in (8 kHz, [`FRAME_SIZE`] samples).
//!
//! The data step (`lipcall grid`) writes, per clip, its audio as a WAV (the codec paths read
//! WAVs) and `NAME.lips.csv`: `frame,time_s,tracked,aperture,width,protrusion,lower_lip_back`,
//! one row per audio frame, the lips at the frame's centre (unshifted; training shifts them by
//! the measured audio-visual lag).

use std::path::{Path, PathBuf};

use crate::lipsync::lips::{LipFrame, LipTargets, landmark};
use crate::vocab::{FRAME_SIZE, SAMPLE_RATE};

/// Seconds per audio frame.
pub const AUDIO_FRAME_S: f64 = FRAME_SIZE as f64 / SAMPLE_RATE as f64;
/// GRID's video frame rate.
pub const VIDEO_FPS: f64 = 25.0;

#[derive(Debug, thiserror::Error)]
pub enum GridError {
    #[error(transparent)]
    Input(#[from] crate::input::InputError),
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

pub(super) fn format_error(path: &Path, message: impl Into<String>) -> GridError {
    GridError::Format {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// One tracked row of a tracks CSV: its fields, and where it is for errors.
pub(super) struct TrackRow<'a> {
    pub fields: Vec<&'a str>,
    line: usize,
    path: &'a Path,
}

impl TrackRow<'_> {
    /// An error about this row.
    pub fn error(&self, message: String) -> GridError {
        format_error(self.path, format!("line {}: {message}", self.line))
    }
}

/// Reads a tracks CSV (a header naming `tracked` and the landmarks' coordinate columns, a row
/// per video frame): `columns` finds what `frame` reads from each tracked row, given a lookup
/// of column names; an untracked row is `None`, a row of another length than the header an
/// error.
pub(super) fn read_tracks<'a, C, T>(
    text: &'a str,
    path: &'a Path,
    columns: impl FnOnce(&dyn Fn(&str) -> Result<usize, GridError>) -> Result<C, GridError>,
    mut frame: impl FnMut(&C, &TrackRow<'a>) -> Result<T, GridError>,
) -> Result<Vec<Option<T>>, GridError> {
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines
        .next()
        .ok_or_else(|| format_error(path, "empty file"))?;
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let column = |name: &str| {
        names
            .iter()
            .position(|c| *c == name)
            .ok_or_else(|| format_error(path, format!("no column {name}")))
    };
    let tracked = column("tracked")?;
    let wanted = columns(&column)?;
    let mut frames = Vec::new();
    for (i, line) in lines {
        let row = TrackRow {
            fields: line.split(',').map(str::trim).collect(),
            line: i + 1,
            path,
        };
        if row.fields.get(tracked).copied() != Some("1") {
            frames.push(None);
            continue;
        }
        if row.fields.len() != names.len() {
            return Err(row.error(format!(
                "{} fields, the header has {}",
                row.fields.len(),
                names.len()
            )));
        }
        frames.push(Some(frame(&wanted, &row)?));
    }
    Ok(frames)
}

/// The lips of each video frame of a track (`None` where no face was found).
pub fn parse_track(text: &str, path: &Path) -> Result<Vec<Option<LipTargets>>, GridError> {
    let coordinates = |column: &dyn Fn(&str) -> Result<usize, GridError>| {
        landmark::USED
            .iter()
            .map(|index| {
                Ok([
                    column(&format!("x_{index}"))?,
                    column(&format!("y_{index}"))?,
                    column(&format!("z_{index}"))?,
                ])
            })
            .collect::<Result<Vec<[usize; 3]>, GridError>>()
    };
    read_tracks(text, path, coordinates, |coordinate_columns, row| {
        let mut points = [[0.0f32; 3]; landmark::USED.len()];
        for (point, cols) in points.iter_mut().zip(coordinate_columns) {
            for (value, &col) in point.iter_mut().zip(cols) {
                *value = row.fields[col]
                    .parse()
                    .map_err(|_| row.error(format!("{:?} is not a number", row.fields[col])))?;
            }
        }
        LipFrame(points)
            .targets()
            .map_err(|e| row.error(e.to_string()))
    })
}

/// The lips at time `t_s` (seconds), linearly between the two nearest video frames; `None`
/// where either is untracked or `t_s` lies outside the video.
pub fn lips_at(video: &[Option<LipTargets>], t_s: f64) -> Option<LipTargets> {
    let position = t_s * VIDEO_FPS - 0.5;
    let last = video.len().checked_sub(1)? as f64;
    if !(-0.5..=last + 0.5).contains(&position) {
        return None;
    }
    let position = position.clamp(0.0, last);
    let i = position.floor() as usize;
    let frac = (position - i as f64) as f32;
    let a = video[i]?;
    if frac == 0.0 {
        return Some(a);
    }
    let b = video.get(i + 1).copied().flatten()?;
    let mix = |x: f32, y: f32| x + frac * (y - x);
    Some(LipTargets {
        aperture: mix(a.aperture, b.aperture),
        width: mix(a.width, b.width),
        protrusion: mix(a.protrusion, b.protrusion),
        lower_lip_back: mix(a.lower_lip_back, b.lower_lip_back),
    })
}

/// The lips at the centre of each of `frames` audio frames, `shift_s` later (negative:
/// earlier).
pub fn audio_frame_lips(
    video: &[Option<LipTargets>],
    frames: usize,
    shift_s: f64,
) -> Vec<Option<LipTargets>> {
    (0..frames)
        .map(|n| lips_at(video, (n as f64 + 0.5) * AUDIO_FRAME_S + shift_s))
        .collect()
}

/// Writes a clip's per-audio-frame lips (see the module docs).
pub fn write_lips_csv(path: &Path, lips: &[Option<LipTargets>]) -> Result<(), GridError> {
    let mut out = String::from("frame,time_s,tracked");
    for name in LipTargets::NAMES {
        out.push(',');
        out.push_str(name);
    }
    out.push('\n');
    for (n, frame) in lips.iter().enumerate() {
        let time = (n as f64 + 0.5) * AUDIO_FRAME_S;
        match frame {
            Some(t) => {
                let [a, w, p, l] = t.values();
                out.push_str(&format!("{n},{time:.3},1,{a:.5},{w:.5},{p:.5},{l:.5}\n"));
            }
            None => out.push_str(&format!("{n},{time:.3},0,,,,\n")),
        }
    }
    std::fs::write(path, out).map_err(|source| GridError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads what [`write_lips_csv`] wrote.
pub fn read_lips_csv(path: &Path) -> Result<Vec<Option<LipTargets>>, GridError> {
    let text = crate::input::read_to_string(path, crate::input::MAX_INPUT_BYTES)?;
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    if lines.next() != Some("frame,time_s,tracked,aperture,width,protrusion,lower_lip_back") {
        return Err(format_error(path, "not a lips CSV (bad header)"));
    }
    lines
        .enumerate()
        .map(|(i, line)| {
            let fields: Vec<&str> = line.split(',').collect();
            let bad = || format_error(path, format!("row {}: {line:?}", i + 1));
            if fields.len() != 7 || fields[0].parse::<usize>() != Ok(i) {
                return Err(bad());
            }
            if fields[2] != "1" {
                return Ok(None);
            }
            let v = |k: usize| -> Result<f32, GridError> {
                fields[k]
                    .parse::<f32>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(bad)
            };
            Ok(Some(LipTargets {
                aperture: v(3)?,
                width: v(4)?,
                protrusion: v(5)?,
                lower_lip_back: v(6)?,
            }))
        })
        .collect()
}

/// One clip the data step prepared: its WAV and its per-audio-frame lips.
#[derive(Debug, Clone)]
pub struct LipClip {
    /// `s1` or `other`: the speaker set.
    pub set: String,
    pub name: String,
    pub wav: PathBuf,
    pub lips: Vec<Option<LipTargets>>,
}

/// Sets the data step writes: s1's clips and the other speakers' (validation only).
pub const SETS: [&str; 2] = ["s1", "other"];

/// Whether an s1 clip is held out of training (every tenth, by name order), to be reported.
pub fn s1_held_out(index_in_name_order: usize) -> bool {
    index_in_name_order.is_multiple_of(10)
}

/// The names of the files in `dir` that end in `suffix`, without it, in name order.
pub fn clip_names(dir: &Path, suffix: &str) -> Result<Vec<String>, GridError> {
    let io = |source| GridError::Io {
        path: dir.to_path_buf(),
        source,
    };
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map_err(io)?
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            e.file_name()
                .to_str()
                .and_then(|n| n.strip_suffix(suffix))
                .map(str::to_string)
        })
        .collect();
    names.sort();
    Ok(names)
}

/// The clips of `set` under the data step's output `root`, in name order.
pub fn load_clips(root: &Path, set: &str) -> Result<Vec<LipClip>, GridError> {
    let dir = root.join(set);
    let names = clip_names(&dir, ".lips.csv")?;
    if names.is_empty() {
        return Err(format_error(
            &dir,
            "no .lips.csv files (run `lipcall grid` first)",
        ));
    }
    names
        .into_iter()
        .map(|name| {
            Ok(LipClip {
                set: set.to_string(),
                lips: read_lips_csv(&dir.join(format!("{name}.lips.csv")))?,
                wav: dir.join(format!("{name}.wav")),
                name,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lips(aperture: f32) -> Option<LipTargets> {
        Some(LipTargets {
            aperture,
            width: 0.7,
            ..LipTargets::default()
        })
    }

    #[test]
    fn audio_frames_take_the_lips_between_video_frames() {
        // Video frame centres at 20, 60, 100 ms; audio frame centres at 10, 30, 50, ... ms.
        let video = vec![lips(0.0), lips(0.4), None, lips(1.0)];
        let at = audio_frame_lips(&video, 8, 0.0);
        let apertures: Vec<Option<f32>> = at.iter().map(|l| l.map(|l| l.aperture)).collect();
        let close = |a: Option<f32>, b: f32| a.is_some_and(|a| (a - b).abs() < 1e-5);
        assert!(close(apertures[0], 0.0), "{apertures:?}");
        assert!(close(apertures[1], 0.1) && close(apertures[2], 0.3));
        assert!(
            apertures[3].is_none() && apertures[5].is_none(),
            "{apertures:?}"
        );
        assert!(close(apertures[7], 1.0), "{apertures:?}");
        // 40 ms later: the lips of two audio frames on.
        let shifted = audio_frame_lips(&video, 3, 0.04);
        assert!(close(shifted[0].map(|l| l.aperture), 0.3));
        assert!(audio_frame_lips(&video, 9, 0.0)[8].is_none());
    }

    #[test]
    fn lips_csv_round_trips_and_rejects_junk() {
        let path = std::env::temp_dir().join(format!("lipcall-lips-{}.csv", std::process::id()));
        let frames = vec![lips(0.123), None, lips(0.5)];
        write_lips_csv(&path, &frames).unwrap();
        let back = read_lips_csv(&path).unwrap();
        assert_eq!(back.len(), 3);
        assert!(back[1].is_none());
        assert!((back[0].unwrap().aperture - 0.123).abs() < 1e-5);
        std::fs::write(&path, "frame,x\n0,1\n").unwrap();
        assert!(read_lips_csv(&path).is_err());
        std::fs::remove_file(&path).unwrap();
    }

    proptest::proptest! {
        /// Any text, or a valid header over junk rows, is lips or an error, never a panic.
        #[test]
        fn parsers_never_panic(rows in "[0-9,.x\\-\n]{0,300}") {
            let _ = parse_track(&rows, Path::new("t.csv"));
            let mut header = String::from("time_s,tracked");
            for index in landmark::USED {
                header.push_str(&format!(",x_{index},y_{index},z_{index}"));
            }
            let _ = parse_track(&format!("{header}\n{rows}"), Path::new("t.csv"));
            let path = std::env::temp_dir()
                .join(format!("lipcall-lips-prop-{}.csv", std::process::id()));
            let text = format!("frame,time_s,tracked,aperture,width,protrusion,lower_lip_back\n{rows}");
            std::fs::write(&path, text).unwrap();
            let _ = read_lips_csv(&path);
            std::fs::remove_file(&path).unwrap();
        }
    }

    #[test]
    fn tracks_parse_into_lips_and_untracked_rows() {
        let mut header = String::from("time_s,tracked");
        let mut row = String::from("0.02,1");
        for (k, index) in landmark::USED.iter().enumerate() {
            header.push_str(&format!(",x_{index},y_{index},z_{index}"));
            // Eyes 60 px apart (landmarks 33 and 263), everything else on a slope.
            let (x, y) = match *index {
                33 => (100.0, 100.0),
                263 => (160.0, 100.0),
                13 => (130.0, 150.0),
                14 => (130.0, 156.0),
                _ => (100.0 + k as f32, 140.0),
            };
            row.push_str(&format!(",{x},{y},0"));
        }
        let empty = ",".repeat(3 * landmark::USED.len());
        let text = format!("{header}\n{row}\n0.06,0{empty}\n");
        let track = parse_track(&text, Path::new("t.csv")).unwrap();
        assert_eq!(track.len(), 2);
        assert!((track[0].unwrap().aperture - 0.1).abs() < 1e-6);
        assert!(track[1].is_none());
        let broken = format!("{header}\n{}\n", row.replace(",130,156", ",x,156"));
        assert!(parse_track(&broken, Path::new("t.csv")).is_err());
        assert!(parse_track("time_s,tracked\n", Path::new("t.csv")).is_err());
    }
}
