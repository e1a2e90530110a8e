//! Real marker recordings, so a lab with tracked faces can run the paper's pipeline: a track of
//! 2D (or 3D) marker points per video frame and a list of key frames that show each viseme.
//!
//! Marker CSV: a header `frame,<p>_x,<p>_y,<q>_x,<q>_y,...` (or `_x,_y,_z` triples), then one row
//! per video frame: its frame number and the coordinates, e.g. pixels. An optional origin marker
//! (the paper uses the nose) is subtracted from every point of its row and dropped.
//!
//! Key-frame CSV: a header `viseme,frame`, then rows like `PP,120`: the viseme shape is the
//! track's points at that frame number.

use std::path::Path;

use super::decompose::PointTrack;
use super::mouth::{ShapeError, VisemeShapes};
use crate::vocab::{Viseme, VisemeError};

#[derive(Debug, thiserror::Error)]
pub enum MarkerError {
    #[error(transparent)]
    Input(#[from] crate::input::InputError),
    #[error("empty file: no header line")]
    Empty,
    #[error("bad header: {0}")]
    BadHeader(String),
    #[error("line {line}: {message}")]
    Row { line: usize, message: String },
    #[error("no marker named {0:?}")]
    UnknownMarker(String),
    #[error("key frame {0} is not in the track")]
    UnknownFrame(u64),
    #[error("line {line}: {source}")]
    Viseme { line: usize, source: VisemeError },
    #[error(transparent)]
    Shape(#[from] ShapeError),
}

/// A marker track with the frame number of every row.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerTrack {
    pub marker_names: Vec<String>,
    pub frame_numbers: Vec<u64>,
    pub points: PointTrack,
}

fn read(path: &Path) -> Result<String, MarkerError> {
    Ok(crate::input::read_to_string(
        path,
        crate::input::MAX_INPUT_BYTES,
    )?)
}

fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty())
}

impl MarkerTrack {
    pub fn load(path: &Path, origin: Option<&str>) -> Result<Self, MarkerError> {
        Self::parse(&read(path)?, origin)
    }

    pub fn parse(text: &str, origin: Option<&str>) -> Result<Self, MarkerError> {
        let mut lines = data_lines(text);
        let (_, header) = lines.next().ok_or(MarkerError::Empty)?;
        let columns: Vec<&str> = header.split(',').map(str::trim).collect();
        if columns.first() != Some(&"frame") {
            return Err(MarkerError::BadHeader(
                "the first column must be `frame`".into(),
            ));
        }
        let coords = &columns[1..];
        let point_dim = if coords.get(2).is_some_and(|c| c.ends_with("_z")) {
            3
        } else {
            2
        };
        let axes = ["_x", "_y", "_z"];
        if coords.is_empty() || !coords.len().is_multiple_of(point_dim) {
            return Err(MarkerError::BadHeader(format!(
                "{} coordinate columns do not make whole {point_dim}D points",
                coords.len()
            )));
        }
        let mut names = Vec::new();
        for group in coords.chunks(point_dim) {
            let name = group[0].strip_suffix("_x").unwrap_or_default();
            for (c, axis) in group.iter().zip(axes) {
                if name.is_empty() || c.strip_suffix(axis) != Some(name) {
                    return Err(MarkerError::BadHeader(format!(
                        "expected column {name}{axis}, found {c:?}"
                    )));
                }
            }
            names.push(name.to_string());
        }
        let origin_index = match origin {
            Some(o) => Some(
                names
                    .iter()
                    .position(|n| n == o)
                    .ok_or_else(|| MarkerError::UnknownMarker(o.to_string()))?,
            ),
            None => None,
        };
        let kept: Vec<usize> = (0..names.len())
            .filter(|&i| Some(i) != origin_index)
            .collect();
        let mut points = PointTrack::new(point_dim, kept.len() * point_dim);
        let mut frame_numbers = Vec::new();
        let mut row = Vec::with_capacity(coords.len());
        let mut frame = vec![0.0; kept.len() * point_dim];
        for (line, text) in lines {
            let fields: Vec<&str> = text.split(',').map(str::trim).collect();
            if fields.len() != columns.len() {
                return Err(MarkerError::Row {
                    line,
                    message: format!("{} fields, the header has {}", fields.len(), columns.len()),
                });
            }
            let number: u64 = fields[0].parse().map_err(|_| MarkerError::Row {
                line,
                message: format!("bad frame number {:?}", fields[0]),
            })?;
            row.clear();
            for field in &fields[1..] {
                match field.parse::<f32>() {
                    Ok(v) if v.is_finite() => row.push(v),
                    _ => {
                        return Err(MarkerError::Row {
                            line,
                            message: format!("bad coordinate {field:?}"),
                        });
                    }
                }
            }
            for (slot, &i) in kept.iter().enumerate() {
                for d in 0..point_dim {
                    let base = origin_index.map_or(0.0, |o| row[o * point_dim + d]);
                    let relative = row[i * point_dim + d] - base;
                    // Two finite coordinates far apart can differ by more than an f32 holds.
                    if !relative.is_finite() {
                        return Err(MarkerError::Row {
                            line,
                            message: format!(
                                "marker {} is too far from the origin marker",
                                names[i]
                            ),
                        });
                    }
                    frame[slot * point_dim + d] = relative;
                }
            }
            points.push(&frame).map_err(|e| MarkerError::Row {
                line,
                message: e.to_string(),
            })?;
            frame_numbers.push(number);
        }
        Ok(Self {
            marker_names: kept.iter().map(|&i| names[i].clone()).collect(),
            frame_numbers,
            points,
        })
    }

    /// Viseme shapes taken from the track at the key frames listed in a key-frame CSV.
    pub fn key_frame_shapes(&self, key_frames_csv: &str) -> Result<VisemeShapes, MarkerError> {
        let mut lines = data_lines(key_frames_csv);
        let (_, header) = lines.next().ok_or(MarkerError::Empty)?;
        if header.replace(' ', "") != "viseme,frame" {
            return Err(MarkerError::BadHeader(format!(
                "expected `viseme,frame`, found {header:?}"
            )));
        }
        let mut shapes = Vec::new();
        for (line, text) in lines {
            let Some((name, frame)) = text.split_once(',') else {
                return Err(MarkerError::Row {
                    line,
                    message: "expected `viseme,frame`".into(),
                });
            };
            let viseme: Viseme = name
                .trim()
                .parse()
                .map_err(|source| MarkerError::Viseme { line, source })?;
            let number: u64 = frame.trim().parse().map_err(|_| MarkerError::Row {
                line,
                message: format!("bad frame number {:?}", frame.trim()),
            })?;
            let index = self
                .frame_numbers
                .iter()
                .position(|&n| n == number)
                .ok_or(MarkerError::UnknownFrame(number))?;
            if shapes.iter().any(|(v, _)| *v == viseme) {
                return Err(MarkerError::Viseme {
                    line,
                    source: VisemeError::Duplicate(viseme),
                });
            }
            shapes.push((viseme, self.points.frame(index).to_vec()));
        }
        Ok(VisemeShapes::new(self.points.point_dim(), shapes)?)
    }

    pub fn load_key_frame_shapes(&self, path: &Path) -> Result<VisemeShapes, MarkerError> {
        self.key_frame_shapes(&read(path)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lipsync::decompose::table_i;
    use crate::vocab::VisemeSet;

    const TRACK: &str = "frame,nose_x,nose_y,lip_x,lip_y,chin_x,chin_y\n\
        10,100,50,100,80,100,120\n\
        11,101,50,101,90,101,140\n\
        12,100,50,100,85,100,130\n";

    #[test]
    fn reads_markers_relative_to_the_origin() {
        let track = MarkerTrack::parse(TRACK, Some("nose")).unwrap();
        assert_eq!(track.marker_names, ["lip", "chin"]);
        assert_eq!(track.frame_numbers, [10, 11, 12]);
        assert_eq!(track.points.frame(1), &[0.0, 40.0, 0.0, 90.0]);
        let shapes = track
            .key_frame_shapes("viseme,frame\nPP,10\naa,11\n")
            .unwrap();
        let set = VisemeSet::reduced(2).unwrap();
        let table = table_i(&track.points, &shapes, &[set]).unwrap();
        // Frame 12 is exactly halfway: every frame is a convex blend of the key frames.
        assert!(table.rows[0].error < 1e-4, "{table}");
    }

    #[test]
    fn malformed_marker_files_are_errors() {
        let bad = [
            "",
            "time,a_x,a_y\n",
            "frame,a_x,b_y\n",
            "frame,a_x,a_y,b_x\n",
            "frame,a_x,a_y\n1,2\n",
            "frame,a_x,a_y\n1,2,zz\n",
            "frame,a_x,a_y\nx,2,3\n",
        ];
        for text in bad {
            assert!(MarkerTrack::parse(text, None).is_err(), "accepted {text:?}");
        }
        assert!(matches!(
            MarkerTrack::parse(TRACK, Some("ear")),
            Err(MarkerError::UnknownMarker(_))
        ));
        let track = MarkerTrack::parse(TRACK, None).unwrap();
        assert!(matches!(
            track.key_frame_shapes("viseme,frame\nPP,99\n"),
            Err(MarkerError::UnknownFrame(99))
        ));
        assert!(track.key_frame_shapes("viseme,frame\nXX,10\n").is_err());
        assert!(
            track
                .key_frame_shapes("viseme,frame\nPP,10\nPP,11\n")
                .is_err()
        );
    }
}
