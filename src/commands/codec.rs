//! `lipcall encode` and `lipcall decode`.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

use crate::audio::wav;
use crate::call::csv;
use crate::call::media::{MediaFile, MediaKind};
use crate::codec::opus;
use crate::codec::speex::codec::EncoderConfig;
use crate::codec::speex::stream;
use crate::vocab::FrameFeatures;
use crate::vocab::SAMPLE_RATE;

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

/// `lipcall encode`'s flags; [`EncodeArgs::settings`] checks that they fit the codec.
#[derive(Debug, Clone, clap::Args)]
pub struct EncodeArgs {
    pub input: PathBuf,
    pub output: PathBuf,
    /// The codec (default: opus for an .opus output, otherwise speex).
    #[arg(long, value_enum)]
    pub codec: Option<FileCodec>,
    /// Speex quality, 0 (lowest) to 10 (highest); default 8.
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..=10))]
    pub quality: Option<u8>,
    /// Speex: variable bit rate.
    #[arg(long)]
    pub vbr: bool,
    /// Encoder complexity: Speex 1 to 10 (default 3), Opus 0 to 10 (default 10).
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..=10))]
    pub complexity: Option<u8>,
    /// Speex: frames (20 ms each) per Ogg packet; default 1.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=8))]
    pub frames_per_packet: Option<u8>,
    /// Opus bitrate in kb/s, 6 to 510; default 16.
    #[arg(long, value_name = "KBPS", value_parser = parse_kbps)]
    pub bitrate: Option<u32>,
    /// Opus: expected packet loss in percent; turns on in-band FEC (which libopus codes
    /// from 18 kb/s in narrowband).
    #[arg(long, value_name = "PERCENT", value_parser = clap::value_parser!(u8).range(0..=100))]
    pub expect_loss: Option<u8>,
    /// Opus: discontinuous transmission (tiny packets in silence).
    #[arg(long)]
    pub dtx: bool,
}

/// `lipcall decode`'s flags.
#[derive(Debug, Clone, clap::Args)]
pub struct DecodeArgs {
    pub input: PathBuf,
    pub output: PathBuf,
    /// Write FEATURES.csv: frame,time_s,mode,lsp1..lsp10,energy_db.
    #[arg(long, value_name = "FEATURES.csv")]
    pub features: Option<PathBuf>,
    /// Speex: turn the perceptual enhancer off (speexdec --no-enh).
    #[arg(long)]
    pub no_enh: bool,
    /// OUT.wav's sample rate, Hz (default: the stream's own, 48000 for Opus as opusdec
    /// writes, 8000 for Speex narrowband). Opus decodes straight to 8, 12, 16, 24 or 48 kHz;
    /// other rates are resampled.
    #[arg(long, value_name = "HZ", value_parser = parse_rate)]
    pub rate: Option<u32>,
}

fn parse_rate(s: &str) -> Result<u32, String> {
    let rate: u32 = s.trim().parse().map_err(|e| format!("{e}"))?;
    if wav::RATES.contains(&rate) && rate <= 192_000 {
        Ok(rate)
    } else {
        Err(format!("{rate} Hz: expected 4000 to 192000"))
    }
}

/// `pcm` at `from` as it is, or resampled to `to`.
fn at_rate(pcm: Vec<i16>, from: u32, to: Option<u32>) -> Result<(u32, Vec<i16>)> {
    match to {
        Some(to) if to != from => {
            let audio = wav::MonoAudio {
                rate: from,
                samples: pcm.iter().map(|&s| f32::from(s) / 32768.0).collect(),
            };
            Ok((to, wav::to_i16(&wav::resample(&audio, to)?)))
        }
        _ => Ok((from, pcm)),
    }
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
pub fn decode(args: &DecodeArgs) -> Result<()> {
    let (input, output) = (&args.input, &args.output);
    let (features, enhancer) = (args.features.as_deref(), !args.no_enh);
    let file = MediaFile::open(input)?;
    if file.kind() == Some(MediaKind::OggOpus) {
        if features.is_some() {
            bail!("--features is not available for Opus files yet (only for Speex)");
        }
        return decode_opus(input, output, &file, args.rate);
    }
    let decoded = file.speex(enhancer)?;
    // As animate: a stream without a frame of audio is an error, not an empty WAV.
    if decoded.pcm.is_empty() {
        bail!("{}: holds no audio frame", input.display());
    }
    let (rate, pcm) = at_rate(decoded.pcm.clone(), decoded.header.rate, args.rate)?;
    wav::write_mono_i16(output, rate, &pcm)?;
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

fn decode_opus(input: &Path, output: &Path, file: &MediaFile, rate: Option<u32>) -> Result<()> {
    let opus_rate = rate
        .filter(|r| opus::codec::RATES.contains(r))
        .unwrap_or(opus::codec::OPUS_CLOCK_RATE);
    let decoded = file.opus_at(opus_rate)?;
    if decoded.pcm.is_empty() {
        bail!("{}: holds no audio frame", input.display());
    }
    let (rate, pcm) = at_rate(decoded.pcm, opus_rate, rate)?;
    wav::write_mono_i16(output, rate, &pcm)?;
    if decoded.corrupt_packets > 0 {
        eprintln!(
            "warning: {} damaged packet(s) were concealed",
            decoded.corrupt_packets
        );
    }
    if decoded.bad_granules > 0 {
        eprintln!(
            "warning: {} page(s) carry granule positions that disagree with their audio \
             (a cut or badly written file); the packets were decoded as they are",
            decoded.bad_granules
        );
    }
    eprintln!(
        "{}: {:.2} s of audio at {} Hz, {} Opus packets{}",
        output.display(),
        pcm.len() as f64 / f64::from(rate),
        rate,
        decoded.packets.len(),
        match decoded.head.channels {
            1 => String::new(),
            2 => " (stereo mixed to mono)".to_string(),
            n => format!(" ({n} channels mixed to mono)"),
        }
    );
    Ok(())
}

/// Writes FEATURES.csv ([`crate::call::csv`]), one row per 20 ms.
pub fn write_features_csv(path: &Path, rate: u32, rows: &[FrameFeatures]) -> Result<()> {
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    let mut out = std::io::BufWriter::new(file);
    csv::write_features(&mut out, rate, rows)?;
    out.flush()
        .with_context(|| format!("cannot write {}", path.display()))
}

/// kb/s as opusenc's --bitrate takes them, to bits per second.
fn parse_kbps(arg: &str) -> Result<u32, String> {
    match arg.parse::<f64>() {
        Ok(k) if (6.0..=510.0).contains(&k) => Ok((k * 1000.0).round() as u32),
        _ => Err("must be a number of kb/s from 6 to 510".into()),
    }
}

impl EncodeArgs {
    /// The codec and its settings, or the usage error of a flag that belongs to the other
    /// codec.
    pub fn settings(&self) -> Result<EncodeSettings, &'static str> {
        let codec = self
            .codec
            .unwrap_or_else(|| FileCodec::for_path(&self.output));
        match codec {
            FileCodec::Speex => {
                if self.bitrate.is_some() || self.expect_loss.is_some() || self.dtx {
                    return Err("--bitrate, --expect-loss and --dtx are Opus settings \
                                (use --codec opus or an .opus output)");
                }
                if self.complexity == Some(0) {
                    return Err("Speex complexity is 1 to 10");
                }
                let d = EncoderConfig::default();
                Ok(EncodeSettings::Speex(EncoderConfig {
                    quality: self.quality.unwrap_or(d.quality),
                    vbr: self.vbr,
                    complexity: self.complexity.unwrap_or(d.complexity),
                    frames_per_packet: self
                        .frames_per_packet
                        .map_or(d.frames_per_packet, usize::from),
                }))
            }
            FileCodec::Opus => {
                if self.quality.is_some() || self.vbr || self.frames_per_packet.is_some() {
                    return Err(
                        "--quality, --vbr and --frames-per-packet are Speex settings; \
                                Opus takes --bitrate",
                    );
                }
                let d = opus::codec::EncoderConfig::default();
                Ok(EncodeSettings::Opus(opus::codec::EncoderConfig {
                    bitrate: self.bitrate.unwrap_or(d.bitrate),
                    complexity: self.complexity.unwrap_or(d.complexity),
                    fec: self.expect_loss.is_some_and(|l| l > 0),
                    loss_percent: self.expect_loss.unwrap_or(0),
                    dtx: self.dtx,
                    ..d
                }))
            }
        }
    }
}
