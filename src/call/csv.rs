//! The two CSV formats lipcall writes, each in this one place: FEATURES.csv
//! (`frame,time_s,mode,lsp1..lsp10,energy_db`) and WEIGHTS.csv (`frame,time_s,<viseme names>`),
//! one row per 20 ms frame, whether a whole file is written at once (`decode`, `animate`) or
//! streamed as a call plays (`receive`).

use std::io::{self, Write};

use crate::vocab::{FRAME_SIZE, FrameFeatures, LSP_COUNT};

/// FEATURES.csv's header line.
pub fn features_header(out: &mut impl Write) -> io::Result<()> {
    let lsp: Vec<String> = (1..=LSP_COUNT).map(|i| format!("lsp{i}")).collect();
    writeln!(out, "frame,time_s,mode,{},energy_db", lsp.join(","))
}

/// One FEATURES.csv row: frame `frame`, starting `time_s` into the stream (`mode` empty for a
/// concealed frame).
pub fn features_row(
    out: &mut impl Write,
    frame: usize,
    time_s: f64,
    features: &FrameFeatures,
) -> io::Result<()> {
    let mode = features.mode.map(|m| m.to_string()).unwrap_or_default();
    write!(out, "{frame},{time_s:.3},{mode}")?;
    for l in features.lsp {
        write!(out, ",{l:.6}")?;
    }
    writeln!(out, ",{:.2}", features.energy_db)
}

/// WEIGHTS.csv's header line, with the columns of `names`.
pub fn weights_header<S: AsRef<str>>(out: &mut impl Write, names: &[S]) -> io::Result<()> {
    let names: Vec<&str> = names.iter().map(AsRef::as_ref).collect();
    writeln!(out, "frame,time_s,{}", names.join(","))
}

/// One WEIGHTS.csv row (empty `weights`: none came for that frame).
pub fn weights_row(
    out: &mut impl Write,
    frame: usize,
    time_s: f64,
    weights: &[f32],
) -> io::Result<()> {
    write!(out, "{frame},{time_s:.3}")?;
    for w in weights {
        write!(out, ",{w:.4}")?;
    }
    writeln!(out)
}

/// A whole FEATURES.csv of a stream at `rate`: the header, then one row per 20 ms frame.
pub fn write_features(out: &mut impl Write, rate: u32, rows: &[FrameFeatures]) -> io::Result<()> {
    features_header(out)?;
    for (n, row) in rows.iter().enumerate() {
        features_row(out, n, frame_start(n, rate), row)?;
    }
    Ok(())
}

/// A whole WEIGHTS.csv of a stream at `rate`: the header, then one row per 20 ms frame.
pub fn write_weights<S: AsRef<str>>(
    out: &mut impl Write,
    names: &[S],
    rate: u32,
    rows: &[Vec<f32>],
) -> io::Result<()> {
    weights_header(out, names)?;
    for (n, row) in rows.iter().enumerate() {
        weights_row(out, n, frame_start(n, rate), row)?;
    }
    Ok(())
}

/// Where frame `n` of a stream at `rate` starts, in seconds.
fn frame_start(n: usize, rate: u32) -> f64 {
    (n * FRAME_SIZE) as f64 / f64::from(rate)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_read_as_the_readme_says() {
        let mut out = Vec::new();
        weights_header(&mut out, &["PP", "aa"]).unwrap();
        weights_row(&mut out, 3, 0.06, &[0.25, 0.75]).unwrap();
        features_header(&mut out).unwrap();
        let row = FrameFeatures {
            mode: Some(5),
            lsp: [0.5; LSP_COUNT],
            energy_db: -20.0,
            family: crate::vocab::FeatureFamily::Bitstream,
        };
        features_row(&mut out, 1, 0.02, &row).unwrap();
        let text = String::from_utf8(out).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], "frame,time_s,PP,aa");
        assert_eq!(lines[1], "3,0.060,0.2500,0.7500");
        assert!(lines[2].starts_with("frame,time_s,mode,lsp1,"));
        assert!(lines[2].ends_with(",lsp10,energy_db"));
        assert_eq!(
            lines[3],
            format!("1,0.020,5{},-20.00", ",0.500000".repeat(10))
        );
    }
}
