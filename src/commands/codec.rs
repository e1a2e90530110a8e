//! `lipcall encode` and `lipcall decode`.

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result, bail};

use crate::audio::wav;
use crate::call::csv;
use crate::call::media::{MediaFile, MediaKind};
use crate::codec::opus;
use crate::codec::speex::codec::EncoderConfig;
use crate::codec::speex::stream;
use crate::vocab::FrameFeatures;
use crate::vocab::{FRAME_SIZE, SAMPLE_RATE};

/// The codecs lipcall writes files in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum FileCodec {
    Speex,
    Opus,
}

impl FileCodec {
    /// Opus for a `.opus` file, Speex otherwise.
    pub fn for_path(path: &Path) -> Self {
        if has_opus_extension(path) {
            FileCodec::Opus
        } else {
            FileCodec::Speex
        }
    }
}

fn has_opus_extension(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("opus"))
}

/// What `encode` writes: the codec and its settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EncodeSettings {
    Speex(EncoderConfig),
    Opus(opus::codec::EncoderConfig),
}

pub fn encode(input: &Path, output: &Path, settings: EncodeSettings) -> Result<()> {
    let pcm = wav::read_narrowband(input)?;
    let (bytes, described) = match settings {
        EncodeSettings::Speex(config) => (
            stream::encode(&pcm, config)?,
            format!(
                "Speex quality {}{}",
                config.quality,
                if config.vbr { " VBR" } else { "" }
            ),
        ),
        EncodeSettings::Opus(config) => (
            opus::stream::encode(&pcm, config)?,
            format!(
                "Opus {} kb/s{}{}",
                f64::from(config.bitrate) / 1000.0,
                if config.fec { " FEC" } else { "" },
                if config.dtx { " DTX" } else { "" }
            ),
        ),
    };
    std::fs::write(output, &bytes).with_context(|| format!("cannot write {}", output.display()))?;
    eprintln!(
        "{}: {:.2} s of audio, {described}, {} bytes",
        output.display(),
        pcm.len() as f64 / f64::from(SAMPLE_RATE),
        bytes.len()
    );
    Ok(())
}

/// Decodes an Ogg Speex or Ogg Opus file, told apart by its content (an `.opus` name that
/// holds no Opus gets the Opus reader's account of what it holds).
pub fn decode(input: &Path, output: &Path, features: Option<&Path>, enhancer: bool) -> Result<()> {
    let file = MediaFile::open(input)?;
    if file.kind() == Some(MediaKind::OggOpus) {
        if features.is_some() {
            bail!("--features is not available for Opus files yet (only for Speex)");
        }
        return decode_opus(input, output, &file);
    }
    let decoded = file.speex(enhancer)?;
    // As animate: a stream without a frame of audio is an error, not an empty WAV.
    if decoded.pcm.is_empty() {
        bail!("{}: holds no audio frame", input.display());
    }
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
    // Speex stereo is intensity stereo: a mono stream plus in-band balance, so the mono
    // decode is the downmix. Said, as for Opus.
    eprintln!(
        "{}: {:.2} s of audio, {} frames{}",
        output.display(),
        decoded.pcm.len() as f64 / f64::from(decoded.header.rate),
        decoded.features.len(),
        if decoded.header.channels > 1 {
            " (stereo mixed to mono)"
        } else {
            ""
        }
    );
    Ok(())
}

fn decode_opus(input: &Path, output: &Path, file: &MediaFile) -> Result<()> {
    let decoded = file.opus()?;
    if decoded.pcm.is_empty() {
        bail!("{}: holds no audio frame", input.display());
    }
    wav::write_mono_i16(output, SAMPLE_RATE, &decoded.pcm)?;
    if decoded.corrupt_packets > 0 {
        eprintln!(
            "warning: {} damaged packet(s) were concealed",
            decoded.corrupt_packets
        );
    }
    eprintln!(
        "{}: {:.2} s of audio at 8 kHz, {} Opus packets{}",
        output.display(),
        decoded.pcm.len() as f64 / f64::from(SAMPLE_RATE),
        decoded.packets.len(),
        if decoded.head.channels > 1 {
            " (stereo mixed to mono)"
        } else {
            ""
        }
    );
    Ok(())
}

/// Writes FEATURES.csv ([`crate::call::csv`]), one row per 20 ms.
pub fn write_features_csv(path: &Path, rate: u32, rows: &[FrameFeatures]) -> Result<()> {
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    let mut out = std::io::BufWriter::new(file);
    csv::features_header(&mut out)?;
    for (n, row) in rows.iter().enumerate() {
        let time = (n * FRAME_SIZE) as f64 / f64::from(rate);
        csv::features_row(&mut out, n, time, row)?;
    }
    out.flush()
        .with_context(|| format!("cannot write {}", path.display()))
}
