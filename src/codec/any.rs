//! Every codec lipcall speaks, as a call sees it: its RTP identity (name, clock rate, payload
//! type), how long a payload lasts, the rate its audio is heard at, and an encoder of 20 ms
//! frames at its own input rate. The decoder side is [`super::decoder::StreamDecoder`].
//!
//! Payload types. PCMU, PCMA and G.722 have the static types of RFC 3551 (0, 8 and 9; G.722's
//! RTP clock is 8000 though it samples at 16 kHz, RFC 3551 4.5.2). Speex and Opus
//! have dynamic ones, normally agreed in SDP; without SDP lipcall uses GStreamer's payloader
//! defaults (`rtpspeexpay` 110, `rtpopuspay` 96, checked with `gst-inspect-1.0`), so GStreamer
//! talks to it with no options, and a [`PayloadMap`] can move them (`--pt opus=111`).

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use super::g711::Law;
use super::{g722, opus, speex};
use crate::vocab::SAMPLE_RATE;

/// The codecs of a call.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Codec {
    /// Speex narrowband (RFC 5574): the reference path, LSPs read from its bitstream.
    Speex,
    /// Opus (RFC 6716, RTP by RFC 7587), decoded to 8 kHz mono.
    Opus,
    /// G.711 mu-law.
    Pcmu,
    /// G.711 A-law.
    Pcma,
    /// G.722 at 64 kbit/s: 16 kHz audio in two sub-bands.
    G722,
    /// Speex wideband (RFC 5574 `speex/16000`): 16 kHz audio, the LSPs read from its
    /// narrowband layer.
    SpeexWb,
}

impl Codec {
    pub const ALL: [Codec; 6] = [
        Codec::Speex,
        Codec::Opus,
        Codec::Pcmu,
        Codec::Pcma,
        Codec::G722,
        Codec::SpeexWb,
    ];

    /// The name on the command line and in settings.
    pub const fn name(self) -> &'static str {
        match self {
            Codec::Speex => "speex",
            Codec::Opus => "opus",
            Codec::Pcmu => "pcmu",
            Codec::Pcma => "pcma",
            Codec::G722 => "g722",
            Codec::SpeexWb => "speex-wb",
        }
    }

    /// The encoding name in SDP and in GStreamer's RTP caps.
    pub const fn encoding_name(self) -> &'static str {
        match self {
            Codec::Speex | Codec::SpeexWb => "SPEEX",
            Codec::Opus => "OPUS",
            Codec::Pcmu => "PCMU",
            Codec::Pcma => "PCMA",
            Codec::G722 => "G722",
        }
    }

    /// The RTP timestamp rate: 48 kHz for Opus whatever the audio's rate (RFC 7587 4.1).
    pub const fn clock_rate(self) -> u32 {
        match self {
            Codec::Opus => opus::codec::OPUS_CLOCK_RATE,
            Codec::SpeexWb => speex::codec::Band::Wide.rate(),
            Codec::Speex | Codec::Pcmu | Codec::Pcma | Codec::G722 => SAMPLE_RATE,
        }
    }

    /// The rate its decoder gives the ear: what the stream carries at most (Opus is always
    /// decoded at 48 kHz, whatever band its TOC says it codes).
    pub const fn audio_rate(self) -> u32 {
        match self {
            Codec::Opus => opus::codec::OPUS_CLOCK_RATE,
            Codec::G722 => g722::AUDIO_RATE,
            Codec::SpeexWb => speex::codec::Band::Wide.rate(),
            Codec::Speex | Codec::Pcmu | Codec::Pcma => SAMPLE_RATE,
        }
    }

    /// The rate of the audio its encoder takes.
    pub const fn input_rate(self) -> u32 {
        self.audio_rate()
    }

    /// RTP timestamp units ("ticks") in one 20 ms frame.
    pub const fn frame_ticks(self) -> u32 {
        self.clock_rate() / 50
    }

    /// The payload type used when nothing else is agreed.
    pub const fn default_payload_type(self) -> u8 {
        match self {
            Codec::Speex => 110,
            Codec::Opus => 96,
            Codec::Pcmu => Law::Mu.payload_type(),
            Codec::Pcma => Law::A.payload_type(),
            Codec::G722 => g722::PAYLOAD_TYPE,
            Codec::SpeexWb => 97,
        }
    }

    /// Whether the codec has a payload type of its own in RFC 3551's static table.
    pub const fn is_static(self) -> bool {
        matches!(self, Codec::Pcmu | Codec::Pcma | Codec::G722)
    }

    pub const fn law(self) -> Option<Law> {
        match self {
            Codec::Pcmu => Some(Law::Mu),
            Codec::Pcma => Some(Law::A),
            Codec::Speex | Codec::Opus | Codec::G722 | Codec::SpeexWb => None,
        }
    }

    /// How long a payload lasts, in ticks of [`Codec::clock_rate`], read without decoding it:
    /// Speex by counting its frames, Opus from its TOC and frame count, G.711 and G.722 by
    /// their length (one byte per tick, any length). `None` when the payload is not one of this codec.
    pub fn payload_duration(self, payload: &[u8]) -> Option<u32> {
        match self {
            Codec::Speex => speex::split::frame_count(payload)
                .and_then(|n| u32::try_from(n).ok())
                .map(|n| n * self.frame_ticks()),
            // Wideband frames' lengths vary with their layer's submode: walked, not counted.
            Codec::SpeexWb => {
                let frames = speex::bitstream::Walker::new()
                    .frames(payload)
                    .map_while(Result::ok)
                    .count();
                u32::try_from(frames)
                    .ok()
                    .filter(|&n| n > 0)
                    .map(|n| n * self.frame_ticks())
            }
            Codec::Opus => opus::codec::packet_samples(payload, self.clock_rate())
                .ok()
                .and_then(|n| u32::try_from(n).ok()),
            Codec::Pcmu | Codec::Pcma | Codec::G722 => match payload.len() {
                0 => None,
                n => u32::try_from(n).ok(),
            },
        }
    }

    /// Whether each payload is whole 20 ms frames that the decoder plays as they come (Speex),
    /// so that a receiver rounds its timestamp to the 20 ms grid. Other codecs' payloads may
    /// start anywhere (G.711 at any sample, Opus at any 2.5 ms) and are placed where their
    /// timestamps say.
    pub const fn whole_frames(self) -> bool {
        matches!(self, Codec::Speex | Codec::SpeexWb)
    }

    /// Samples at 8 kHz in `ticks` of this codec's clock (rounded down).
    pub fn ticks_to_samples(self, ticks: u32) -> usize {
        (u64::from(ticks) * u64::from(SAMPLE_RATE) / u64::from(self.clock_rate())) as usize
    }
}

impl fmt::Display for Codec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PayloadMapError {
    #[error("unknown codec {0:?} (expected speex, speex-wb, opus, pcmu, pcma or g722)")]
    UnknownCodec(String),
    #[error("expected CODEC=PT such as opus=111, not {0:?}")]
    Syntax(String),
    #[error(
        "payload type {pt} cannot carry {codec}: dynamic types are 96..=127{}",
        if codec.is_static() { format!(", or {codec}'s static {}", codec.default_payload_type()) } else { String::new() }
    )]
    Range { codec: Codec, pt: u8 },
}

impl FromStr for Codec {
    type Err = PayloadMapError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Codec::ALL
            .into_iter()
            .find(|c| c.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| PayloadMapError::UnknownCodec(s.to_string()))
    }
}

/// Which codec each RTP payload type carries, for receiving, and which type each codec is sent
/// with. A payload type the map does not hold is no codec at all: its packets are dropped.
#[derive(Clone, PartialEq, Eq)]
pub struct PayloadMap {
    by_type: [Option<Codec>; 128],
}

impl Default for PayloadMap {
    fn default() -> Self {
        let mut by_type = [None; 128];
        for codec in Codec::ALL {
            by_type[usize::from(codec.default_payload_type())] = Some(codec);
        }
        Self { by_type }
    }
}

impl fmt::Debug for PayloadMap {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_map()
            .entries(
                self.by_type
                    .iter()
                    .enumerate()
                    .filter_map(|(pt, c)| c.map(|c| (pt, c))),
            )
            .finish()
    }
}

impl PayloadMap {
    /// The codec a payload type carries.
    pub fn codec(&self, payload_type: u8) -> Option<Codec> {
        self.by_type
            .get(usize::from(payload_type))
            .copied()
            .flatten()
    }

    /// The payload type `codec` is sent with (the lowest mapped to it), if any is.
    pub fn payload_type(&self, codec: Codec) -> Option<u8> {
        self.by_type
            .iter()
            .position(|&c| c == Some(codec))
            .and_then(|pt| u8::try_from(pt).ok())
    }

    /// Carries `codec` on `payload_type` from now on, instead of on its previous type. A codec
    /// that had `payload_type` before loses it (and is no longer received unless mapped again).
    /// Dynamic types are 96..=127; PCMU and PCMA may also keep their static ones. Types 64..=95
    /// are refused anyway: with RTCP on the same port they could read as RTCP (RFC 5761 4).
    pub fn set(&mut self, codec: Codec, payload_type: u8) -> Result<(), PayloadMapError> {
        let allowed = (96..=127).contains(&payload_type)
            || (codec.is_static() && payload_type == codec.default_payload_type());
        if !allowed {
            return Err(PayloadMapError::Range {
                codec,
                pt: payload_type,
            });
        }
        for slot in self.by_type.iter_mut() {
            if *slot == Some(codec) {
                *slot = None;
            }
        }
        self.by_type[usize::from(payload_type)] = Some(codec);
        Ok(())
    }

    /// Applies `CODEC=PT` assignments in order, e.g. `["opus=111"]`.
    pub fn with_assignments<S: AsRef<str>>(
        mut self,
        assignments: &[S],
    ) -> Result<Self, PayloadMapError> {
        for a in assignments {
            let (codec, pt) = parse_assignment(a.as_ref())?;
            self.set(codec, pt)?;
        }
        Ok(self)
    }
}

/// `opus=111` as (Opus, 111).
pub fn parse_assignment(s: &str) -> Result<(Codec, u8), PayloadMapError> {
    let (name, pt) = s
        .split_once('=')
        .ok_or_else(|| PayloadMapError::Syntax(s.to_string()))?;
    let codec = name.parse()?;
    let pt = pt
        .trim()
        .parse::<u8>()
        .ok()
        .filter(|&pt| pt < 128)
        .ok_or_else(|| PayloadMapError::Syntax(s.to_string()))?;
    Ok((codec, pt))
}

/// Largest payload one 20 ms frame encodes to, whatever the codec.
pub const MAX_FRAME_PAYLOAD: usize = opus::codec::MAX_PACKET_BYTES;

/// What a sender's encoder is set to, per codec.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EncoderSettings {
    pub speex: speex::codec::EncoderConfig,
    pub opus: opus::codec::EncoderConfig,
}

impl Default for EncoderSettings {
    /// Speex as speexenc encodes (quality 8). Opus for a live call at the 8 kHz lipcall sends:
    /// narrowband SILK at 20 kb/s with in-band FEC for 10 % loss (libopus codes FEC in
    /// narrowband only from about 18 kb/s), so one lost packet is rebuilt from the next.
    fn default() -> Self {
        Self {
            speex: speex::codec::EncoderConfig::default(),
            opus: opus::codec::EncoderConfig {
                bitrate: 20_000,
                fec: true,
                loss_percent: 10,
                ..Default::default()
            },
        }
    }
}

impl EncoderSettings {
    /// Opus at its own 48 kHz input rate coding `bandwidth` (fullband: up to 20 kHz), at a
    /// bitrate that carries it (libopus's hybrid mode needs about 32 kb/s for fullband speech),
    /// with the same in-band FEC; the other codecs as by default.
    pub fn wideband(bandwidth: opus::codec::Bandwidth) -> Self {
        use opus::codec::Bandwidth;
        let defaults = Self::default();
        let bitrate = match bandwidth {
            Bandwidth::Narrowband | Bandwidth::Mediumband => defaults.opus.bitrate,
            Bandwidth::Wideband => 24_000,
            Bandwidth::Superwideband | Bandwidth::Fullband | Bandwidth::Auto => 32_000,
        };
        Self {
            opus: opus::codec::EncoderConfig {
                bitrate,
                input_rate: opus::codec::OPUS_CLOCK_RATE,
                bandwidth,
                ..defaults.opus
            },
            ..defaults
        }
    }
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum EncodeError {
    #[error(transparent)]
    Speex(#[from] speex::codec::CodecError),
    #[error(transparent)]
    Opus(#[from] opus::codec::CodecError),
    #[error("{codec} takes frames of {expected} samples, not {got}")]
    FrameLength {
        codec: Codec,
        got: usize,
        expected: usize,
    },
}

/// A sender's encoder: frames at its input rate in (20 ms; Opus's may be 10), payloads out.
pub enum FrameEncoder {
    Speex(speex::codec::Encoder),
    Opus(opus::codec::Encoder),
    G711(Law),
    G722(Box<g722::WidebandEncoder>),
}

impl fmt::Debug for FrameEncoder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "FrameEncoder({})", self.codec())
    }
}

impl FrameEncoder {
    pub fn new(codec: Codec, settings: &EncoderSettings) -> Result<Self, EncodeError> {
        Ok(match codec {
            Codec::Speex => FrameEncoder::Speex(speex::codec::Encoder::new(settings.speex)?),
            Codec::SpeexWb => FrameEncoder::Speex(speex::codec::Encoder::with_band(
                settings.speex,
                speex::codec::Band::Wide,
            )?),
            Codec::Opus => FrameEncoder::Opus(opus::codec::Encoder::new(settings.opus)?),
            Codec::Pcmu => FrameEncoder::G711(Law::Mu),
            Codec::Pcma => FrameEncoder::G711(Law::A),
            Codec::G722 => FrameEncoder::G722(Box::default()),
        })
    }

    /// The rate of the frames [`FrameEncoder::encode`] takes (Opus: as its settings say).
    pub fn input_rate(&self) -> u32 {
        match self {
            FrameEncoder::Opus(enc) => enc.config().input_rate,
            _ => self.codec().input_rate(),
        }
    }

    /// Samples in one input frame: 20 ms, or Opus's own frame length (10 ms when asked).
    pub fn frame_samples(&self) -> usize {
        match self {
            FrameEncoder::Opus(enc) => enc.frame_samples(),
            _ => self.input_rate() as usize / 50,
        }
    }

    /// The length of one input frame, ms.
    pub fn frame_ms(&self) -> u8 {
        match self {
            FrameEncoder::Opus(enc) => enc.config().frame_ms,
            _ => 20,
        }
    }

    pub fn codec(&self) -> Codec {
        match self {
            FrameEncoder::Speex(enc) => match enc.band() {
                speex::codec::Band::Narrow => Codec::Speex,
                speex::codec::Band::Wide => Codec::SpeexWb,
            },
            FrameEncoder::Opus(_) => Codec::Opus,
            FrameEncoder::G711(Law::Mu) => Codec::Pcmu,
            FrameEncoder::G711(Law::A) => Codec::Pcma,
            FrameEncoder::G722(_) => Codec::G722,
        }
    }

    /// Encodes one frame of [`FrameEncoder::frame_samples`] at [`FrameEncoder::input_rate`]
    /// into `out`. Returns the payload's length and how long it lasts in ticks of the codec's
    /// RTP clock (Opus: 960 a 20 ms frame, 480 a 10 ms one), or `None` while the codec holds
    /// frames back (Speex with several frames per packet).
    pub fn encode(
        &mut self,
        frame: &[i16],
        out: &mut [u8; MAX_FRAME_PAYLOAD],
    ) -> Result<Option<(usize, u32)>, EncodeError> {
        let expected = self.frame_samples();
        if frame.len() != expected {
            return Err(EncodeError::FrameLength {
                codec: self.codec(),
                got: frame.len(),
                expected,
            });
        }
        let frame_ticks = self.codec().frame_ticks();
        match self {
            FrameEncoder::Speex(enc) => {
                let mut packet = [0u8; speex::codec::MAX_PACKET_BYTES];
                let ticks = enc.config().frames_per_packet as u32 * frame_ticks;
                Ok(enc.encode_samples(frame, &mut packet)?.map(|n| {
                    out[..n].copy_from_slice(&packet[..n]);
                    (n, ticks)
                }))
            }
            FrameEncoder::Opus(enc) => {
                let ticks = enc.frame_ticks();
                Ok(Some((enc.encode_frame(frame, out)?, ticks)))
            }
            FrameEncoder::G711(law) => Ok(Some((law.encode_into(frame, out), frame_ticks))),
            FrameEncoder::G722(enc) => {
                let frame: &[i16; g722::WIDEBAND_FRAME] =
                    frame.try_into().unwrap_or(&[0; g722::WIDEBAND_FRAME]);
                let payload = enc.encode_frame(frame);
                out[..payload.len()].copy_from_slice(&payload);
                Ok(Some((payload.len(), frame_ticks)))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vocab::FRAME_SIZE;

    #[test]
    fn payload_types_follow_gstreamer_and_rfc_3551() {
        let map = PayloadMap::default();
        assert_eq!(map.codec(0), Some(Codec::Pcmu));
        assert_eq!(map.codec(8), Some(Codec::Pcma));
        assert_eq!(map.codec(96), Some(Codec::Opus));
        assert_eq!(map.codec(110), Some(Codec::Speex));
        assert_eq!(map.codec(100), None);
        assert_eq!(map.codec(200), None);
        for c in Codec::ALL {
            assert_eq!(map.payload_type(c), Some(c.default_payload_type()));
            assert_eq!(c.name().parse::<Codec>(), Ok(c));
            assert_eq!(c.frame_ticks() * 50, c.clock_rate());
        }
        assert_eq!(Codec::Opus.frame_ticks(), 960);
        assert_eq!(Codec::Speex.frame_ticks(), 160);
    }

    #[test]
    fn payload_types_move_with_assignments() {
        let map = PayloadMap::default()
            .with_assignments(&["opus=111", "PCMA=100"])
            .unwrap();
        assert_eq!(map.codec(111), Some(Codec::Opus));
        assert_eq!(map.codec(96), None);
        assert_eq!(map.codec(100), Some(Codec::Pcma));
        assert_eq!(map.codec(8), None);
        assert_eq!(map.payload_type(Codec::Opus), Some(111));
        // Taking Speex's type leaves Speex with none.
        let map = map.with_assignments(&["opus=110"]).unwrap();
        assert_eq!(map.codec(110), Some(Codec::Opus));
        assert_eq!(map.payload_type(Codec::Speex), None);
        let bad = |a: &str| PayloadMap::default().with_assignments(&[a]).err();
        assert!(matches!(bad("opus=0"), Some(PayloadMapError::Range { .. })));
        assert!(matches!(
            bad("pcmu=72"),
            Some(PayloadMapError::Range { .. })
        ));
        assert!(matches!(bad("opus=128"), Some(PayloadMapError::Syntax(_))));
        assert!(matches!(bad("opus"), Some(PayloadMapError::Syntax(_))));
        assert!(matches!(
            bad("g729=18"),
            Some(PayloadMapError::UnknownCodec(_))
        ));
        assert!(matches!(bad("g722=0"), Some(PayloadMapError::Range { .. })));
        assert!(bad("pcmu=0").is_none());
        assert!(bad("g722=9").is_none());
        assert_eq!(PayloadMap::default().codec(9), Some(Codec::G722));
    }

    #[test]
    fn durations_are_read_without_decoding() {
        let settings = EncoderSettings::default();
        let mut out = [0u8; MAX_FRAME_PAYLOAD];
        for codec in Codec::ALL {
            let mut enc = FrameEncoder::new(codec, &settings).unwrap();
            assert_eq!(enc.codec(), codec);
            let frame: Vec<i16> = (0..enc.frame_samples())
                .map(|i| ((i as f32 * 0.3).sin() * 5000.0) as i16)
                .collect();
            assert!(matches!(
                enc.encode(&frame[1..], &mut out),
                Err(EncodeError::FrameLength { .. })
            ));
            let (n, ticks) = enc.encode(&frame, &mut out).unwrap().unwrap();
            assert_eq!(ticks, codec.frame_ticks());
            assert_eq!(
                codec.payload_duration(&out[..n]),
                Some(codec.frame_ticks()),
                "{codec}"
            );
            assert_eq!(codec.ticks_to_samples(codec.frame_ticks()), FRAME_SIZE);
        }
        // Opus in 10 ms frames: half the samples in, 480 ticks out.
        let mut settings = EncoderSettings::wideband(opus::codec::Bandwidth::Fullband);
        settings.opus.frame_ms = 10;
        let mut enc = FrameEncoder::new(Codec::Opus, &settings).unwrap();
        assert_eq!((enc.frame_samples(), enc.frame_ms()), (480, 10));
        let (n, ticks) = enc.encode(&[0; 480], &mut out).unwrap().unwrap();
        assert_eq!(ticks, 480);
        assert_eq!(Codec::Opus.payload_duration(&out[..n]), Some(480));
        assert_eq!(Codec::Pcmu.payload_duration(&[0; 80]), Some(80));
        assert_eq!(Codec::Pcma.payload_duration(&[]), None);
        assert_eq!(Codec::Opus.payload_duration(&[]), None);
        assert_eq!(Codec::Speex.payload_duration(&[0xff]), None);
    }
}
