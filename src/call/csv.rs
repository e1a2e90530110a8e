//! The two CSV formats lipcall writes, each in this one place: FEATURES.csv
//! (`frame,time_s,mode,lsp1..lsp10,energy_db`) and WEIGHTS.csv (`frame,time_s,<viseme names>`),
//! one row per 20 ms frame, whether a whole file is written at once (`decode`, `animate`) or
//! streamed as a call plays (`receive`).

use std::io::{self, Write};

use crate::vocab::{FrameFeatures, LSP_COUNT};

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
