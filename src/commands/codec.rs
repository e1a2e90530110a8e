//! `lipcall encode` and `lipcall decode`.

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result};

use crate::audio::wav;
use crate::codec::speex::codec::EncoderConfig;
use crate::codec::speex::features::FrameFeatures;
use crate::codec::speex::{FRAME_SIZE, SAMPLE_RATE, stream};

pub fn encode(input: &Path, output: &Path, config: EncoderConfig) -> Result<()> {
    let pcm = wav::read_narrowband(input)?;
    let bytes = stream::encode(&pcm, config)?;
    std::fs::write(output, &bytes).with_context(|| format!("cannot write {}", output.display()))?;
    eprintln!(
        "{}: {:.2} s of audio, quality {}{}, {} bytes",
        output.display(),
        pcm.len() as f64 / f64::from(SAMPLE_RATE),
        config.quality,
        if config.vbr { " VBR" } else { "" },
        bytes.len()
    );
    Ok(())
}

pub fn decode(input: &Path, output: &Path, features: Option<&Path>, enhancer: bool) -> Result<()> {
    let bytes = std::fs::read(input).with_context(|| format!("cannot read {}", input.display()))?;
    let decoded =
        stream::decode(&bytes, enhancer).with_context(|| format!("{}", input.display()))?;
    wav::write_mono_i16(output, decoded.header.rate, &decoded.pcm)?;
    if decoded.corrupt_packets > 0 {
        eprintln!(
            "warning: {} damaged packet(s) were partly skipped",
            decoded.corrupt_packets
        );
    }
    if let Some(path) = features {
        write_features_csv(path, decoded.header.rate, &decoded.features)?;
    }
    eprintln!(
        "{}: {:.2} s of audio, {} frames",
        output.display(),
        decoded.pcm.len() as f64 / f64::from(decoded.header.rate),
        decoded.features.len()
    );
    Ok(())
}

/// Writes FEATURES.csv: `frame,time_s,mode,lsp1..lsp10,energy_db`, one row per 20 ms.
pub fn write_features_csv(path: &Path, rate: u32, rows: &[FrameFeatures]) -> Result<()> {
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    let mut out = std::io::BufWriter::new(file);
    let lsp_names: Vec<String> = (1..=10).map(|i| format!("lsp{i}")).collect();
    writeln!(out, "frame,time_s,mode,{},energy_db", lsp_names.join(","))?;
    for (n, row) in rows.iter().enumerate() {
        let time = (n * FRAME_SIZE) as f64 / f64::from(rate);
        let mode = row.mode.map(|m| m.to_string()).unwrap_or_default();
        write!(out, "{n},{time:.3},{mode}")?;
        for l in row.lsp {
            write!(out, ",{l:.6}")?;
        }
        writeln!(out, ",{:.2}", row.energy_db)?;
    }
    out.flush()
        .with_context(|| format!("cannot write {}", path.display()))
}
