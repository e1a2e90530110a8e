//! The one opener of the audio files lipcall reads (`decode`, `animate`, `send`): what a file
//! holds is told by its content (RIFF WAVE, an Ogg stream opening with OpusHead, another Ogg
//! stream), its name only a hint ([`MediaKind::of`]); each caller then takes what
//! it needs: PCM, the features a receiver would see, or the packets to send.

use std::io::Read;
use std::path::{Path, PathBuf};

use crate::audio::wav::{self, WavError};
use crate::codec::any::{Codec, EncodeError, EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD};
use crate::codec::speex::split::split_frames;
use crate::codec::{opus, speex};
use crate::input::InputError;
use crate::vocab::{FRAME_SIZE, FrameFeatures, SAMPLE_RATE};

/// Bytes enough to see every beginning-of-stream page of an Ogg file and a WAV header.
const SNIFF_BYTES: u64 = 64 * 1024;

#[derive(Debug, thiserror::Error)]
pub enum MediaError {
    #[error(transparent)]
    Input(#[from] InputError),
    #[error(transparent)]
    Wav(#[from] WavError),
    #[error("{path}")]
    Speex {
        path: String,
        #[source]
        source: speex::stream::StreamError,
    },
    #[error("{path}")]
    SpeexFile {
        path: String,
        #[source]
        source: speex::ogg_file::OggSpeexError,
    },
    #[error("{path}")]
    Opus {
        path: String,
        #[source]
        source: opus::stream::StreamError,
    },
    #[error("{0}: holds no audio frame")]
    NoFrame(String),
    #[error("{path}: too short: {samples} samples at 8 kHz, a frame needs {FRAME_SIZE}")]
    TooShort { path: String, samples: usize },
    #[error("{0}: expected a .wav, .spx or .opus file")]
    Unknown(String),
    #[error(transparent)]
    Encode(#[from] EncodeError),
}

/// What an audio file holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MediaKind {
    Wav,
    OggSpeex,
    OggOpus,
}

impl MediaKind {
    /// By content, the name a hint: RIFF WAVE; an Ogg stream opening with OpusHead; another
    /// Ogg stream is Speex, or Opus when named `.opus` (so the reader whose format the file
    /// claims says what is wrong with it); where the content says nothing, the name alone.
    pub fn of(bytes: &[u8], path: &Path) -> Option<Self> {
        let named = Self::from_extension(path);
        if bytes.len() >= 12 && &bytes[..4] == b"RIFF" && &bytes[8..12] == b"WAVE" {
            Some(MediaKind::Wav)
        } else if opus::ogg_file::holds_opus(bytes) {
            Some(MediaKind::OggOpus)
        } else if bytes.starts_with(b"OggS") {
            match named {
                Some(MediaKind::OggOpus) => Some(MediaKind::OggOpus),
                _ => Some(MediaKind::OggSpeex),
            }
        } else {
            named
        }
    }

    /// By name: `.wav`, `.opus`, `.spx` or `.ogg`.
    pub fn from_extension(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "wav" => Some(MediaKind::Wav),
            "opus" => Some(MediaKind::OggOpus),
            "spx" | "ogg" => Some(MediaKind::OggSpeex),
            _ => None,
        }
    }
}

/// An audio file, opened and told apart.
pub struct MediaFile {
    path: PathBuf,
    /// `None`: neither content nor name said (the caller picks a reader, whose error says why).
    kind: Option<MediaKind>,
    /// The whole file, for the Ogg readers (a WAV is streamed from its path).
    bytes: Vec<u8>,
}

/// A stream as a receiver hears it: 8 kHz samples and one feature row per 20 ms frame.
pub struct Heard {
    pub rate: u32,
    pub pcm: Vec<i16>,
    pub features: Vec<FrameFeatures>,
}

/// Payloads to send, each with its duration in ticks of the codec's RTP clock.
pub type Packets = Vec<(Vec<u8>, u32)>;

impl MediaFile {
    /// Opens `path` (a regular file within the input cap) and tells what it holds: by content,
    /// else by name.
    pub fn open(path: &Path) -> Result<Self, MediaError> {
        let (file, _) = crate::input::open(path, crate::input::MAX_INPUT_BYTES)?;
        let mut head = Vec::new();
        let mut file = file;
        let read_error = |e: std::io::Error| {
            MediaError::Input(InputError::Io {
                path: path.display().to_string(),
                source: e,
            })
        };
        (&mut file)
            .take(SNIFF_BYTES)
            .read_to_end(&mut head)
            .map_err(read_error)?;
        let kind = MediaKind::of(&head, path);
        let mut bytes = head;
        if kind != Some(MediaKind::Wav) {
            file.read_to_end(&mut bytes).map_err(read_error)?;
        }
        Ok(Self {
            path: path.to_path_buf(),
            kind,
            bytes,
        })
    }

    pub fn kind(&self) -> Option<MediaKind> {
        self.kind
    }

    fn name(&self) -> String {
        self.path.display().to_string()
    }

    /// An Ogg Speex file, decoded (a file of another kind gets the Speex reader's account).
    /// `decode` takes every file but Ogg Opus as this.
    pub fn speex(&self, enhancer: bool) -> Result<speex::stream::Decoded, MediaError> {
        speex::stream::decode(&self.bytes, enhancer).map_err(|source| MediaError::Speex {
            path: self.name(),
            source,
        })
    }

    /// An Ogg Opus file, decoded at 8 kHz (another kind gets the Opus reader's account).
    pub fn opus(&self) -> Result<opus::stream::Decoded, MediaError> {
        opus::stream::decode(&self.bytes).map_err(|source| MediaError::Opus {
            path: self.name(),
            source,
        })
    }

    /// An Ogg Opus file decoded at another Opus rate (48 kHz: its own).
    pub fn opus_at(&self, rate: u32) -> Result<opus::stream::Decoded, MediaError> {
        opus::stream::decode_at(&self.bytes, rate).map_err(|source| MediaError::Opus {
            path: self.name(),
            source,
        })
    }

    /// A WAV file at 8 kHz mono (another kind gets the WAV reader's account).
    pub fn wav(&self) -> Result<Vec<i16>, MediaError> {
        Ok(wav::read_narrowband(&self.path)?)
    }

    /// What a receiver would hear and see: an Ogg Speex or Ogg Opus file decoded, its features
    /// read from its bitstream (Speex LSPs, SILK NLSFs); a WAV (or a file neither content nor
    /// name tells) resampled to 8 kHz and sent through Speex at the default quality.
    pub fn heard(&self) -> Result<Heard, MediaError> {
        let heard = match self.kind {
            Some(MediaKind::OggOpus) => {
                let decoded = self.opus()?;
                let features = opus::features::stream_features(&decoded);
                Heard {
                    rate: decoded.rate,
                    pcm: decoded.pcm,
                    features,
                }
            }
            Some(MediaKind::OggSpeex) => self.speex(true)?.into(),
            Some(MediaKind::Wav) | None => {
                let pcm = self.wav()?;
                if pcm.len() < FRAME_SIZE {
                    return Err(MediaError::TooShort {
                        path: self.name(),
                        samples: pcm.len(),
                    });
                }
                speex::stream::round_trip(&pcm, speex::codec::EncoderConfig::default())
                    .map_err(|source| MediaError::Speex {
                        path: self.name(),
                        source,
                    })?
                    .into()
            }
        };
        if heard.features.is_empty() {
            return Err(MediaError::NoFrame(self.name()));
        }
        Ok(heard)
    }

    /// What `send` sends: a coded file as it is (Ogg Speex split into frames, Ogg Opus packets
    /// with their durations), or its audio encoded here in `codec` (a WAV, or a coded file
    /// when `codec` names another, or Opus in 10 ms frames). Without `codec`, a WAV goes as Speex, the reference path.
    pub fn packets(
        &self,
        codec: Option<Codec>,
        settings: &EncoderSettings,
    ) -> Result<(Codec, Packets), MediaError> {
        match self.kind {
            Some(MediaKind::OggOpus) => {
                let decoded = self.opus()?;
                // Re-encoded where another codec or Opus's 10 ms frames are asked for.
                let reframed = settings.opus.frame_ms != 20;
                if let Some(codec) = codec.filter(|&c| c != Codec::Opus || reframed) {
                    return Ok((
                        codec,
                        encode_pcm(&decoded.pcm, decoded.rate, codec, settings)?,
                    ));
                }
                // Timestamps count 48 kHz ticks; the packets were decoded at 8 kHz.
                let per_sample = Codec::Opus.clock_rate() / SAMPLE_RATE;
                let packets = decoded
                    .packets
                    .into_iter()
                    .map(|p| (p.data, p.samples as u32 * per_sample))
                    .collect();
                Ok((Codec::Opus, packets))
            }
            Some(MediaKind::OggSpeex) => {
                if let Some(codec) = codec.filter(|&c| c != Codec::Speex) {
                    let decoded = self.speex(true)?;
                    let rate = decoded.header.rate;
                    return Ok((codec, encode_pcm(&decoded.pcm, rate, codec, settings)?));
                }
                let file =
                    speex::ogg_file::read(&self.bytes).map_err(|source| MediaError::SpeexFile {
                        path: self.name(),
                        source,
                    })?;
                let per_packet = file.header.frames_per_packet.max(1) as u32;
                let step = Codec::Speex.frame_ticks();
                let mut out = Vec::new();
                for packet in file.pages.iter().flat_map(|p| &p.packets) {
                    match split_frames(packet) {
                        Some(frames) => out.extend(frames.into_iter().map(|f| (f, step))),
                        None => out.push((packet.clone(), per_packet * step)),
                    }
                }
                Ok((Codec::Speex, out))
            }
            Some(MediaKind::Wav) => {
                let audio = wav::read_mono(&self.path)?;
                let codec = codec.unwrap_or(Codec::Speex);
                let rate = FrameEncoder::new(codec, settings)?.input_rate();
                let pcm = wav::to_i16(&wav::resample(&audio, rate)?);
                Ok((codec, encode_pcm(&pcm, rate, codec, settings)?))
            }
            None => Err(MediaError::Unknown(self.name())),
        }
    }
}

impl From<speex::stream::Decoded> for Heard {
    fn from(decoded: speex::stream::Decoded) -> Self {
        Heard {
            rate: decoded.header.rate,
            pcm: decoded.pcm,
            features: decoded.features,
        }
    }
}

/// Encodes audio at `rate` in the encoder's frames (20 ms; Opus's may be 10), the last padded
/// with silence, resampled first to the encoder's rate where it takes another.
pub fn encode_pcm(
    pcm: &[i16],
    rate: u32,
    codec: Codec,
    settings: &EncoderSettings,
) -> Result<Packets, MediaError> {
    let mut encoder = FrameEncoder::new(codec, settings)?;
    let input_rate = encoder.input_rate();
    let resampled;
    let pcm = if rate == input_rate {
        pcm
    } else {
        let audio = wav::MonoAudio {
            rate,
            samples: pcm.iter().map(|&s| f32::from(s) / 32768.0).collect(),
        };
        resampled = wav::to_i16(&wav::resample(&audio, input_rate)?);
        &resampled[..]
    };
    let frame_samples = encoder.frame_samples();
    let mut payload = [0u8; MAX_FRAME_PAYLOAD];
    let mut out = Vec::with_capacity(pcm.len() / frame_samples + 1);
    let mut frame = vec![0i16; frame_samples];
    for chunk in pcm.chunks(frame_samples) {
        frame.fill(0);
        frame[..chunk.len()].copy_from_slice(chunk);
        if let Some((n, ticks)) = encoder.encode(&frame, &mut payload)? {
            out.push((payload[..n].to_vec(), ticks));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn content_wins_over_the_name() {
        let dir = tempfile::tempdir().unwrap();
        let pcm: Vec<i16> = (0..4000)
            .map(|i| ((i as f32 * 0.2).sin() * 6000.0) as i16)
            .collect();
        let opus_bytes = opus::stream::encode(&pcm, opus::codec::EncoderConfig::default()).unwrap();
        let speex_bytes =
            speex::stream::encode(&pcm, speex::codec::EncoderConfig::default()).unwrap();
        let wav_path = dir.path().join("tone.spx");
        wav::write_mono_i16(&wav_path, SAMPLE_RATE, &pcm).unwrap();
        let cases = [
            ("opus.wav", opus_bytes, MediaKind::OggOpus),
            ("speex.wav", speex_bytes, MediaKind::OggSpeex),
        ];
        for (name, bytes, kind) in cases {
            let path = dir.path().join(name);
            std::fs::write(&path, bytes).unwrap();
            let file = MediaFile::open(&path).unwrap();
            assert_eq!(file.kind(), Some(kind), "{name}");
            assert!(!file.heard().unwrap().features.is_empty());
        }
        assert_eq!(
            MediaFile::open(&wav_path).unwrap().kind(),
            Some(MediaKind::Wav)
        );
        let text = dir.path().join("notes.txt");
        std::fs::write(&text, "not audio").unwrap();
        let file = MediaFile::open(&text).unwrap();
        assert_eq!(file.kind(), None);
        let err = file
            .packets(None, &EncoderSettings::default())
            .err()
            .unwrap();
        assert!(
            err.to_string().contains("expected a .wav, .spx or .opus"),
            "{err}"
        );
    }
}
