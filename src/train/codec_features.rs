//! The production feature source: training audio goes through the real codec, exactly as a
//! receiver hears it. Each WAV is read and resampled to 8 kHz once (kept in memory), then Speex
//! encoded at a setting, decoded, and the decoder's LSPs + energy are read per 20 ms frame.
//!
//! Augmentation: the training speakers' utterances are seen at several codec settings, so the
//! network does not learn one bit rate's quantisation. Evaluation uses one fixed setting
//! ([`EVALUATION_QUALITY`]) and reports [`LOW_QUALITY`] beside it.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use crate::audio::wav;
use crate::codec::g711::Law;
use crate::codec::g722;
use crate::codec::lpc::LpcAnalyser;
use crate::codec::opus;
use crate::codec::speex::codec::EncoderConfig;
use crate::codec::speex::stream;
use crate::train::corpus::{BoxError, CorpusError, PreparedUtterance, Utterance, prepare};
use crate::vocab::FrameFeatures;
use crate::vocab::{FRAME_SIZE, FeatureFamily};

/// The way a receiver gets its features: which codec, at what setting, from which input rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CodecPath {
    /// Speex narrowband: the walker's LSPs.
    Speex(EncoderConfig),
    /// Opus at `bitrate` b/s, fed at 16 kHz as opusenc feeds it speech of that rate (wideband
    /// SILK) or at 8 kHz as lipcall's own sender does (narrowband SILK): the SILK NLSFs mapped
    /// onto narrowband LSPs, CELT-only frames analysed.
    Opus { bitrate: u32, wideband: bool },
    /// Opus as the `opusenc` command of opus-tools writes it (`--bitrate`, its other defaults)
    /// from 16 kHz audio, read as `animate` reads a .opus file. Needs opusenc on the PATH.
    Opusenc { bitrate: u32 },
    /// G.711 at 8 kHz: LPC analysis of the decoded audio.
    G711(Law),
    /// G.722 from 16 kHz: LPC analysis of its lower band.
    G722,
}

impl CodecPath {
    /// Where most of its rows' LSPs come from.
    pub fn family(&self) -> FeatureFamily {
        match self {
            CodecPath::Speex(_) => FeatureFamily::Bitstream,
            CodecPath::Opus { .. } | CodecPath::Opusenc { .. } => FeatureFamily::Nlsf,
            CodecPath::G711(_) | CodecPath::G722 => FeatureFamily::Analysis,
        }
    }

    /// The rate the codec's input is taken at.
    fn input_rate(&self) -> u32 {
        match self {
            CodecPath::Opus { wideband: true, .. }
            | CodecPath::Opusenc { .. }
            | CodecPath::G722 => 16_000,
            _ => crate::vocab::SAMPLE_RATE,
        }
    }
}

impl std::fmt::Display for CodecPath {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CodecPath::Speex(c) => {
                write!(
                    f,
                    "Speex quality {}{}",
                    c.quality,
                    if c.vbr { " VBR" } else { "" }
                )
            }
            CodecPath::Opus { bitrate, wideband } => write!(
                f,
                "Opus {} kb/s from {} kHz (SILK NLSFs)",
                f64::from(*bitrate) / 1000.0,
                if *wideband { 16 } else { 8 }
            ),
            CodecPath::Opusenc { bitrate } => write!(
                f,
                "opusenc --bitrate {} from 16 kHz (SILK NLSFs)",
                f64::from(*bitrate) / 1000.0
            ),
            CodecPath::G711(Law::Mu) => write!(f, "PCMU (LPC analysis)"),
            CodecPath::G711(Law::A) => write!(f, "PCMA (LPC analysis)"),
            CodecPath::G722 => write!(f, "G.722 lower band (LPC analysis)"),
        }
    }
}

/// The features a receiver of `pcm` (at `path`'s input rate) sent through `path` sees.
fn features_through(pcm: &[i16], path: CodecPath) -> Result<Vec<FrameFeatures>, BoxError> {
    Ok(match path {
        CodecPath::Speex(config) => features_of_pcm(pcm, config)?,
        CodecPath::Opus { bitrate, .. } => {
            let config = opus::codec::EncoderConfig {
                bitrate,
                input_rate: path.input_rate(),
                ..Default::default()
            };
            let decoded = opus::stream::decode(&opus::stream::encode(pcm, config)?)?;
            opus::features::stream_features(&decoded)
        }
        CodecPath::Opusenc { bitrate } => {
            opus::features::stream_features(&opus::stream::decode(&opusenc(pcm, bitrate)?)?)
        }
        CodecPath::G711(law) => {
            let decoded: Vec<i16> = pcm
                .iter()
                .map(|&x| law.decode_sample(law.encode_sample(x)))
                .collect();
            analysed(&decoded)
        }
        CodecPath::G722 => {
            let mut encoder = g722::WidebandEncoder::new();
            let mut decoder = g722::LowBandDecoder::new();
            let mut low = Vec::with_capacity(pcm.len() / 2);
            for frame in pcm.chunks_exact(g722::WIDEBAND_FRAME) {
                let frame: &[i16; g722::WIDEBAND_FRAME] = frame.try_into()?;
                low.extend_from_slice(&decoder.decode_frame(&encoder.encode_frame(frame)));
            }
            analysed(&low)
        }
    })
}

/// The Ogg Opus file `opusenc --bitrate` makes of 16 kHz `pcm`.
fn opusenc(pcm: &[i16], bitrate: u32) -> Result<Vec<u8>, BoxError> {
    static FILES: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = FILES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let stem = std::env::temp_dir().join(format!("lipcall-opusenc-{}-{n}", std::process::id()));
    let (input, output) = (stem.with_extension("wav"), stem.with_extension("opus"));
    let result = (|| -> Result<Vec<u8>, BoxError> {
        wav::write_mono_i16(&input, 16_000, pcm)?;
        let status = std::process::Command::new("opusenc")
            .args(["--quiet", "--bitrate"])
            .arg(format!("{}", f64::from(bitrate) / 1000.0))
            .arg(&input)
            .arg(&output)
            .status()
            .map_err(|e| format!("cannot run opusenc (opus-tools): {e}"))?;
        if !status.success() {
            return Err(format!("opusenc failed ({status})").into());
        }
        Ok(std::fs::read(&output)?)
    })();
    let _ = std::fs::remove_file(&input);
    let _ = std::fs::remove_file(&output);
    result
}

/// Rows of LPC-analysed features of 8 kHz audio.
fn analysed(pcm: &[i16]) -> Vec<FrameFeatures> {
    let mut analyser = LpcAnalyser::new();
    pcm.chunks_exact(FRAME_SIZE)
        .filter_map(|row| <&[i16; FRAME_SIZE]>::try_from(row).ok())
        .map(|row| analyser.analyse(row).features(None))
        .collect()
}

/// The quality every reported score uses unless said otherwise (speexenc's default).
pub const EVALUATION_QUALITY: u8 = 8;
/// The low quality reported beside it (mode 3, 8 kbit/s).
pub const LOW_QUALITY: u8 = 3;

/// Codec paths the training utterances are augmented with, interleaved so that any run of
/// consecutive settings mixes codecs: Speex CBR qualities 3 to 10 and VBR, and as many other
/// paths: Opus (SILK NLSFs from 8 and 16 kHz input, 12 to 32 kb/s), and the LPC analysis of
/// G.711 and G.722 audio. The network thus learns each path's features, not one codec's.
pub fn augmentation_settings() -> Vec<CodecPath> {
    let speex = (3..=10)
        .map(|q| CodecPath::Speex(quality(q)))
        .chain([4, 8].map(|q| {
            CodecPath::Speex(EncoderConfig {
                quality: q,
                vbr: true,
                ..EncoderConfig::default()
            })
        }));
    let opus = |kbps: u32, wideband| CodecPath::Opus {
        bitrate: kbps * 1000,
        wideband,
    };
    let others = [
        opus(16, false),
        opus(16, true),
        CodecPath::G711(Law::Mu),
        opus(12, false),
        opus(24, true),
        CodecPath::G722,
        opus(24, false),
        opus(12, true),
        CodecPath::G711(Law::A),
        opus(32, true),
    ];
    speex.zip(others).flat_map(|(a, b)| [a, b]).collect()
}

/// A CBR setting at `quality` with speexenc's other defaults.
pub fn quality(quality: u8) -> EncoderConfig {
    EncoderConfig {
        quality,
        ..EncoderConfig::default()
    }
}

fn features_of_pcm(pcm: &[i16], config: EncoderConfig) -> Result<Vec<FrameFeatures>, BoxError> {
    Ok(stream::round_trip(pcm, config)?.features)
}

/// A file's audio at one rate, read once.
type SharedPcm = Arc<Vec<i16>>;

/// Codec features with the audio of every file read once (per rate) and kept.
#[derive(Debug, Default)]
pub struct CodecFeatures {
    audio: Mutex<HashMap<(PathBuf, u32), SharedPcm>>,
}

impl CodecFeatures {
    pub fn new() -> Self {
        Self::default()
    }

    fn pcm(&self, path: &Path, rate: u32) -> Result<Arc<Vec<i16>>, BoxError> {
        let mut audio = self.audio.lock().map_err(|_| "audio cache poisoned")?;
        let key = (path.to_path_buf(), rate);
        if let Some(pcm) = audio.get(&key) {
            return Ok(Arc::clone(pcm));
        }
        let pcm = Arc::new(wav::to_i16(&wav::resample(&wav::read_mono(path)?, rate)?));
        audio.insert(key, Arc::clone(&pcm));
        Ok(pcm)
    }

    /// The features of `path` through `codec`.
    pub fn features_through(
        &self,
        path: &Path,
        codec: CodecPath,
    ) -> Result<Vec<FrameFeatures>, BoxError> {
        features_through(&self.pcm(path, codec.input_rate())?, codec)
    }

    /// Prepares `utterances` through `codec`.
    pub fn prepare_through(
        &self,
        utterances: &[&Utterance],
        codec: CodecPath,
    ) -> Result<Vec<PreparedUtterance>, CorpusError> {
        prepare(utterances, &|path: &Path| {
            self.features_through(path, codec)
        })
    }

    /// Prepares each utterance at `versions` of `settings` (rotating through them, so every
    /// setting is used about equally often): `versions` times as many training utterances.
    pub fn prepare_augmented(
        &self,
        utterances: &[&Utterance],
        settings: &[CodecPath],
        versions: usize,
        on_done: &dyn Fn(),
    ) -> Result<Vec<PreparedUtterance>, CorpusError> {
        let versions = versions.clamp(1, settings.len().max(1));
        let mut out = Vec::with_capacity(utterances.len() * versions);
        for (i, utt) in utterances.iter().enumerate() {
            for k in 0..versions {
                let path = settings
                    .get((i * versions + k) % settings.len().max(1))
                    .copied()
                    .unwrap_or(CodecPath::Speex(EncoderConfig::default()));
                out.extend(self.prepare_through(std::slice::from_ref(utt), path)?);
                on_done();
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::corpus::Corpus;
    use crate::train::corpus::tests::timit_root;

    #[test]
    fn codec_features_line_up_with_the_targets() {
        let corpus = Corpus::open(&timit_root()).unwrap();
        let utt = &corpus.speaker("dr4-maeb0").unwrap().utterances[0];
        let codec = CodecFeatures::new();
        let prepared = codec
            .prepare_through(&[utt], CodecPath::Speex(quality(8)))
            .unwrap();
        let (_, samples) = crate::train::corpus::wav_length(&utt.wav).unwrap();
        let frames = samples as usize / 320;
        assert!(prepared[0].features.len().abs_diff(frames) <= 1);
        assert!(prepared[0].features.iter().all(|f| f.mode.is_some()));
        let low = codec
            .prepare_through(&[utt], CodecPath::Speex(quality(3)))
            .unwrap();
        assert_eq!(low[0].features.len(), prepared[0].features.len());
        assert_ne!(low[0].features, prepared[0].features);
        let augmented = codec
            .prepare_augmented(&[utt, utt], &augmentation_settings(), 3, &|| {})
            .unwrap();
        assert_eq!(augmented.len(), 6);
        assert!(
            codec
                .features_through(Path::new("/nonexistent.wav"), CodecPath::Speex(quality(8)))
                .is_err()
        );
    }
}
