//! A small wrapper over libopus for mono frames of 20 ms (or 10, sent when asked): the encoder a
//! sender runs and the decoder a receiver runs, with loss concealment and in-band forward error
//! correction.
//!
//! libopus comes through the `opus` crate (safe Rust) over `opusic-sys`, which builds its
//! vendored libopus statically; this file needs no `unsafe`.

use opus::{Application, Bitrate, Channels, ErrorCode};

use crate::vocab::{FRAME_SIZE, SAMPLE_RATE};

/// The largest packet one 20 ms frame can take (RFC 6716 3.2.1: 1275 bytes plus the TOC byte);
/// libopus never writes more than this for one frame.
pub const MAX_PACKET_BYTES: usize = 1276;
/// More than this is no Opus packet (48 frames of 1275 bytes plus generous padding) and is
/// refused before libopus sees it.
pub const MAX_INPUT_PACKET_BYTES: usize = 65_536;
/// The longest packet: 120 ms.
pub const MAX_PACKET_MS: usize = 120;
/// The rate Opus counts time in: RTP timestamps and Ogg granule positions (RFC 7587, RFC 7845).
pub const OPUS_CLOCK_RATE: u32 = 48_000;
/// Samples of the longest packet at 8 kHz.
pub const MAX_PACKET_SAMPLES: usize = SAMPLE_RATE as usize * MAX_PACKET_MS / 1000;

pub const RATES: [u32; 5] = [8000, 12_000, 16_000, 24_000, 48_000];

/// The frame lengths lipcall sends, in ms: 20 by default, 10 for lower latency.
pub const FRAME_MS: [u8; 2] = [10, 20];

/// The audio band an encoder codes (RFC 6716 2: narrowband 4 kHz up to fullband 20 kHz).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Bandwidth {
    /// libopus picks by bitrate and input rate.
    #[default]
    Auto,
    Narrowband,
    Mediumband,
    Wideband,
    Superwideband,
    Fullband,
}

impl Bandwidth {
    pub const ALL: [Bandwidth; 6] = [
        Bandwidth::Auto,
        Bandwidth::Narrowband,
        Bandwidth::Mediumband,
        Bandwidth::Wideband,
        Bandwidth::Superwideband,
        Bandwidth::Fullband,
    ];

    /// The short name on the command line and in settings.
    pub const fn name(self) -> &'static str {
        match self {
            Bandwidth::Auto => "auto",
            Bandwidth::Narrowband => "nb",
            Bandwidth::Mediumband => "mb",
            Bandwidth::Wideband => "wb",
            Bandwidth::Superwideband => "swb",
            Bandwidth::Fullband => "fb",
        }
    }

    /// The highest audio frequency it codes, Hz (none for `Auto`).
    pub const fn top_hz(self) -> Option<u32> {
        match self {
            Bandwidth::Auto => None,
            Bandwidth::Narrowband => Some(4000),
            Bandwidth::Mediumband => Some(6000),
            Bandwidth::Wideband => Some(8000),
            Bandwidth::Superwideband => Some(12_000),
            Bandwidth::Fullband => Some(20_000),
        }
    }

    fn libopus(self) -> opus::Bandwidth {
        match self {
            Bandwidth::Auto => opus::Bandwidth::Auto,
            Bandwidth::Narrowband => opus::Bandwidth::Narrowband,
            Bandwidth::Mediumband => opus::Bandwidth::Mediumband,
            Bandwidth::Wideband => opus::Bandwidth::Wideband,
            Bandwidth::Superwideband => opus::Bandwidth::Superwideband,
            Bandwidth::Fullband => opus::Bandwidth::Fullband,
        }
    }
}

impl std::fmt::Display for Bandwidth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Bandwidth {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Bandwidth::ALL
            .into_iter()
            .find(|b| b.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| {
                format!("unknown bandwidth {s:?} (expected nb, mb, wb, swb, fb or auto)")
            })
    }
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum CodecError {
    #[error("libopus could not create a codec state: {0}")]
    Init(String),
    #[error("bitrate {0} b/s is outside 6000..=510000")]
    Bitrate(u32),
    #[error("complexity {0} is outside 0..=10")]
    Complexity(u8),
    #[error("expected packet loss {0} % is outside 0..=100")]
    LossPercent(u8),
    #[error("Opus works at 8, 12, 16, 24 or 48 kHz, not {0} Hz")]
    Rate(u32),
    #[error("a frame of {got} samples where one frame is {expected}")]
    FrameLength { got: usize, expected: usize },
    #[error("frames of {0} ms: lipcall sends Opus in frames of 10 or 20 ms")]
    FrameMs(u8),
    #[error("{0} samples is not a whole number of 2.5 ms steps up to 120 ms")]
    Duration(usize),
    #[error("corrupted Opus packet")]
    Corrupted,
    #[error("a packet of {0} bytes is larger than any Opus packet can be")]
    PacketTooLarge(usize),
    #[error("a packet of {packet} samples does not fit an output of {room}")]
    OutputTooSmall { packet: usize, room: usize },
    #[error("libopus: {0}")]
    Libopus(String),
}

impl From<opus::Error> for CodecError {
    fn from(e: opus::Error) -> Self {
        match e.code() {
            ErrorCode::InvalidPacket => CodecError::Corrupted,
            _ => CodecError::Libopus(e.to_string()),
        }
    }
}

fn check_rate(rate: u32) -> Result<u32, CodecError> {
    if RATES.contains(&rate) {
        Ok(rate)
    } else {
        Err(CodecError::Rate(rate))
    }
}

/// How the encoder is set up. The defaults suit speech over VoIP at the 8 kHz the features use:
/// 16 kb/s VBR (narrowband SILK), libopus's top complexity, no DTX, no FEC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EncoderConfig {
    /// Bits per second (opusenc's `--bitrate` is in kb/s).
    pub bitrate: u32,
    pub complexity: u8,
    pub vbr: bool,
    /// Discontinuous transmission: near-empty packets while the input is silent.
    pub dtx: bool,
    /// In-band FEC: each packet carries a coarse copy of the previous frame. libopus adds it
    /// only when `loss_percent` is above 0 and the bitrate leaves room: in narrowband from
    /// 18 kb/s (17 at 20 % loss; at 16 kb/s it silently codes none, measured on libopus 1.6).
    pub fec: bool,
    /// The packet loss the encoder should expect, in percent.
    pub loss_percent: u8,
    /// The rate of the PCM handed to `encode_frame`: 8000 (160-sample frames) or any other
    /// Opus rate (48000: 960-sample frames).
    pub input_rate: u32,
    /// The band coded (libopus's choice by default).
    pub bandwidth: Bandwidth,
    /// The length of each frame and packet, ms: 20, or 10 (half the framing delay, twice the
    /// packets; see docs/audio.md).
    pub frame_ms: u8,
}

impl Default for EncoderConfig {
    fn default() -> Self {
        Self {
            bitrate: 16_000,
            complexity: 10,
            vbr: true,
            dtx: false,
            fec: false,
            loss_percent: 0,
            input_rate: SAMPLE_RATE,
            bandwidth: Bandwidth::Auto,
            frame_ms: 20,
        }
    }
}

impl EncoderConfig {
    fn validate(&self) -> Result<(), CodecError> {
        if !(6000..=510_000).contains(&self.bitrate) {
            return Err(CodecError::Bitrate(self.bitrate));
        }
        if self.complexity > 10 {
            return Err(CodecError::Complexity(self.complexity));
        }
        if self.loss_percent > 100 {
            return Err(CodecError::LossPercent(self.loss_percent));
        }
        check_rate(self.input_rate)?;
        if !FRAME_MS.contains(&self.frame_ms) {
            return Err(CodecError::FrameMs(self.frame_ms));
        }
        Ok(())
    }
}

/// A mono Opus encoder (VoIP application) producing one packet per frame (20 or 10 ms).
pub struct Encoder {
    inner: opus::Encoder,
    config: EncoderConfig,
}

impl Encoder {
    pub fn new(config: EncoderConfig) -> Result<Self, CodecError> {
        config.validate()?;
        let mut inner = opus::Encoder::new(config.input_rate, Channels::Mono, Application::Voip)
            .map_err(|e| CodecError::Init(e.to_string()))?;
        // The ranges were checked above, so the casts cannot wrap.
        inner.set_bitrate(Bitrate::Bits(config.bitrate as i32))?;
        inner.set_complexity(i32::from(config.complexity))?;
        inner.set_vbr(config.vbr)?;
        inner.set_dtx(config.dtx)?;
        inner.set_inband_fec(config.fec)?;
        inner.set_packet_loss_perc(i32::from(config.loss_percent))?;
        inner.set_bandwidth(config.bandwidth.libopus())?;
        Ok(Self { inner, config })
    }

    pub fn config(&self) -> EncoderConfig {
        self.config
    }

    /// Samples in one input frame (20 or 10 ms at the input rate).
    pub fn frame_samples(&self) -> usize {
        self.config.input_rate as usize * usize::from(self.config.frame_ms) / 1000
    }

    /// Ticks of the 48 kHz RTP clock one packet lasts: 960, or 480 at 10 ms.
    pub fn frame_ticks(&self) -> u32 {
        OPUS_CLOCK_RATE / 1000 * u32::from(self.config.frame_ms)
    }

    /// Samples (at the input rate) the encoder delays its input by; Ogg Opus's pre-skip is this
    /// at 48 kHz.
    pub fn lookahead(&mut self) -> Result<usize, CodecError> {
        let v = self.inner.get_lookahead()?;
        Ok(usize::try_from(v).unwrap_or(0))
    }

    /// Encodes one frame into `packet` and returns its length. With DTX on, a packet of
    /// 1 or 2 bytes means silence: it may be left unsent.
    pub fn encode_frame(
        &mut self,
        frame: &[i16],
        packet: &mut [u8; MAX_PACKET_BYTES],
    ) -> Result<usize, CodecError> {
        let expected = self.frame_samples();
        if frame.len() != expected {
            return Err(CodecError::FrameLength {
                got: frame.len(),
                expected,
            });
        }
        Ok(self.inner.encode(frame, packet)?)
    }
}

/// Samples a packet decodes to at `rate`, read from its TOC and frame count alone.
pub fn packet_samples(packet: &[u8], rate: u32) -> Result<usize, CodecError> {
    if packet.is_empty() {
        return Err(CodecError::Corrupted);
    }
    if packet.len() > MAX_INPUT_PACKET_BYTES {
        return Err(CodecError::PacketTooLarge(packet.len()));
    }
    let n = opus::packet::get_nb_samples(packet, check_rate(rate)?)?;
    // RFC 6716 3.2.5: a packet never lasts more than 120 ms, and code 3 may not count 0 frames.
    if n == 0 || n > rate as usize * MAX_PACKET_MS / 1000 {
        return Err(CodecError::Corrupted);
    }
    Ok(n)
}

/// A mono Opus decoder (stereo streams are downmixed by libopus) with loss concealment and FEC.
pub struct Decoder {
    inner: opus::Decoder,
    rate: u32,
}

impl Decoder {
    /// A decoder at the 8 kHz the rest of lipcall works at (libopus decodes to it directly).
    pub fn new() -> Result<Self, CodecError> {
        Self::with_rate(SAMPLE_RATE)
    }

    /// A decoder at another Opus rate (48 kHz to compare with opusdec sample for sample).
    pub fn with_rate(rate: u32) -> Result<Self, CodecError> {
        let inner = opus::Decoder::new(check_rate(rate)?, Channels::Mono)
            .map_err(|e| CodecError::Init(e.to_string()))?;
        Ok(Self { inner, rate })
    }

    pub fn rate(&self) -> u32 {
        self.rate
    }

    /// Samples in 20 ms at this decoder's rate.
    pub fn frame_samples(&self) -> usize {
        self.rate as usize / 50
    }

    /// Output gain in 1/256 dB (the Ogg Opus header's output gain), applied to all that follows.
    pub fn set_gain(&mut self, q8_db: i16) -> Result<(), CodecError> {
        Ok(self.inner.set_gain(i32::from(q8_db))?)
    }

    /// Decodes one packet into the start of `out`, which must hold its duration (at most
    /// 120 ms), and returns the samples written. A one-byte packet (DTX) gives comfort noise or
    /// concealment for its duration.
    pub fn decode(&mut self, packet: &[u8], out: &mut [i16]) -> Result<usize, CodecError> {
        let n = packet_samples(packet, self.rate)?;
        let room = out.len();
        let out = out
            .get_mut(..n)
            .ok_or(CodecError::OutputTooSmall { packet: n, room })?;
        let written = self.inner.decode(packet, out, false)?;
        Ok(written)
    }

    /// One 20 ms frame from a 20 ms packet (what lipcall sends and opusenc writes by default).
    pub fn decode_frame(
        &mut self,
        packet: &[u8],
        out: &mut [i16; FRAME_SIZE],
    ) -> Result<(), CodecError> {
        let n = packet_samples(packet, self.rate)?;
        if n != FRAME_SIZE || self.rate != SAMPLE_RATE {
            return Err(CodecError::FrameLength {
                got: n,
                expected: FRAME_SIZE,
            });
        }
        self.inner.decode(packet, out, false)?;
        Ok(())
    }

    fn check_duration(&self, samples: usize) -> Result<(), CodecError> {
        let step = self.rate as usize / 400;
        if samples == 0
            || !samples.is_multiple_of(step)
            || samples > self.rate as usize * MAX_PACKET_MS / 1000
        {
            return Err(CodecError::Duration(samples));
        }
        Ok(())
    }

    /// Fills `out` (a multiple of 2.5 ms, usually 20 ms) for a lost packet from the decoder's
    /// state (libopus's packet loss concealment; it fades to silence over long losses).
    pub fn conceal(&mut self, out: &mut [i16]) -> Result<(), CodecError> {
        self.check_duration(out.len())?;
        self.inner.decode(&[], out, false)?;
        Ok(())
    }

    /// Recovers the lost packet before `next_packet` from the FEC copy that `next_packet`
    /// carries, filling `out` with the lost duration; where it carries none, libopus conceals
    /// instead. Decode `next_packet` itself normally afterwards.
    pub fn decode_fec(&mut self, next_packet: &[u8], out: &mut [i16]) -> Result<(), CodecError> {
        self.check_duration(out.len())?;
        packet_samples(next_packet, self.rate)?;
        self.inner.decode(next_packet, out, true)?;
        Ok(())
    }

    /// Forgets the stream's history (a new talker, or a jump in the stream).
    pub fn reset(&mut self) -> Result<(), CodecError> {
        Ok(self.inner.reset_state()?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A vowel-like buzz: harmonics of 120 Hz under a formant-ish envelope, so SILK codes it
    /// as voiced speech.
    fn buzz(n: usize, rate: u32) -> Vec<i16> {
        (0..n)
            .map(|i| {
                let t = i as f32 / rate as f32;
                let mut s = 0.0;
                for h in 1..25 {
                    let f = 120.0 * h as f32;
                    if f > rate as f32 / 2.0 - 200.0 {
                        break;
                    }
                    let amp = 1.0 / (1.0 + ((f - 700.0) / 300.0).powi(2))
                        + 0.5 / (1.0 + ((f - 1200.0) / 300.0).powi(2));
                    s += amp * (2.0 * std::f32::consts::PI * f * t).sin();
                }
                (4000.0 * s) as i16
            })
            .collect()
    }

    fn encode_all(config: EncoderConfig, pcm: &[i16]) -> Vec<Vec<u8>> {
        let mut enc = Encoder::new(config).unwrap();
        let mut packet = [0u8; MAX_PACKET_BYTES];
        pcm.chunks_exact(enc.frame_samples())
            .map(|f| {
                let n = enc.encode_frame(f, &mut packet).unwrap();
                packet[..n].to_vec()
            })
            .collect()
    }

    fn energy(s: &[i16]) -> f64 {
        s.iter().map(|&x| f64::from(x).powi(2)).sum()
    }

    #[test]
    fn round_trip_at_8k_keeps_the_signal_and_its_timing() {
        let input = buzz(8000, 8000);
        let mut enc = Encoder::new(EncoderConfig::default()).unwrap();
        // 2.5 ms of look-ahead plus 4 ms of delay compensation.
        assert_eq!(enc.lookahead().unwrap(), 52);
        let packets = encode_all(EncoderConfig::default(), &input);
        assert_eq!(packets.len(), 50);
        let bytes: usize = packets.iter().map(Vec::len).sum();
        // 16 kb/s VBR: 2000 bytes a second, give or take.
        assert!((1000..3000).contains(&bytes), "{bytes} bytes");
        let mut dec = Decoder::new().unwrap();
        let mut out = Vec::new();
        for p in &packets {
            let mut frame = [0i16; FRAME_SIZE];
            dec.decode_frame(p, &mut frame).unwrap();
            out.extend_from_slice(&frame);
        }
        // Aligned by the look-ahead, the decoded buzz follows the input.
        let (a, b) = (&input[..8000 - 52], &out[52..]);
        let noise: f64 = a
            .iter()
            .zip(b)
            .skip(800)
            .map(|(&x, &y)| (f64::from(x) - f64::from(y)).powi(2))
            .sum();
        let snr = 10.0 * (energy(&a[800..]) / noise).log10();
        assert!(snr > 5.0, "SNR {snr:.1} dB");
    }

    #[test]
    fn frames_at_48k_take_960_samples() {
        let config = EncoderConfig {
            input_rate: 48_000,
            bitrate: 24_000,
            ..Default::default()
        };
        let mut enc = Encoder::new(config).unwrap();
        assert_eq!(enc.frame_samples(), 960);
        assert_eq!(enc.lookahead().unwrap(), 312);
        let mut packet = [0u8; MAX_PACKET_BYTES];
        assert_eq!(
            enc.encode_frame(&[0i16; FRAME_SIZE], &mut packet),
            Err(CodecError::FrameLength {
                got: 160,
                expected: 960
            })
        );
        let packets = encode_all(config, &buzz(48_000, 48_000));
        // Decoded at 8 kHz: 160 samples per packet whatever the encoder's rate.
        let mut dec = Decoder::new().unwrap();
        let mut out = [0i16; MAX_PACKET_SAMPLES];
        for p in &packets {
            assert_eq!(dec.decode(p, &mut out).unwrap(), 160);
        }
    }

    #[test]
    fn frames_of_10_ms_are_packets_of_10_ms() {
        let config = EncoderConfig {
            input_rate: 48_000,
            bitrate: 24_000,
            frame_ms: 10,
            ..Default::default()
        };
        let enc = Encoder::new(config).unwrap();
        assert_eq!((enc.frame_samples(), enc.frame_ticks()), (480, 480));
        let packets = encode_all(config, &buzz(48_000, 48_000));
        assert_eq!(packets.len(), 100);
        let mut dec = Decoder::new().unwrap();
        let mut out = [0i16; MAX_PACKET_SAMPLES];
        for p in &packets {
            assert_eq!(packet_samples(p, 48_000), Ok(480));
            assert_eq!(dec.decode(p, &mut out).unwrap(), 80);
        }
        // 20 ms frames by default; nothing but 10 and 20.
        assert_eq!(
            Encoder::new(EncoderConfig::default())
                .unwrap()
                .frame_ticks(),
            960
        );
        for ms in [0, 5, 15, 40] {
            let config = EncoderConfig {
                frame_ms: ms,
                ..Default::default()
            };
            assert_eq!(Encoder::new(config).err(), Some(CodecError::FrameMs(ms)));
        }
    }

    #[test]
    fn concealment_and_fec_fill_a_lost_frame() {
        let input = buzz(8000, 8000);
        // At 16 kb/s libopus finds no room for FEC in narrowband (see EncoderConfig::fec).
        let config = EncoderConfig {
            bitrate: 24_000,
            fec: true,
            loss_percent: 20,
            ..Default::default()
        };
        let packets = encode_all(config, &input);
        let lost = 30;
        let decode_with = |recover: &dyn Fn(&mut Decoder, &mut [i16; FRAME_SIZE])| {
            let mut dec = Decoder::new().unwrap();
            let mut frames = Vec::new();
            for (i, p) in packets.iter().enumerate() {
                let mut frame = [0i16; FRAME_SIZE];
                if i == lost {
                    recover(&mut dec, &mut frame);
                } else {
                    dec.decode_frame(p, &mut frame).unwrap();
                }
                frames.push(frame);
            }
            frames
        };
        let clean = decode_with(&|dec, f| dec.decode_frame(&packets[lost], f).unwrap());
        let plc = decode_with(&|dec, f| dec.conceal(f).unwrap());
        let fec = decode_with(&|dec, f| dec.decode_fec(&packets[lost + 1], f).unwrap());
        let error = |frames: &[[i16; FRAME_SIZE]]| {
            frames[lost]
                .iter()
                .zip(&clean[lost])
                .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
                .sum::<f64>()
        };
        // Both fill the gap with sound, and FEC comes closer to the real frame than PLC.
        assert!(energy(&plc[lost]) > 0.1 * energy(&clean[lost]));
        assert!(energy(&fec[lost]) > 0.1 * energy(&clean[lost]));
        assert!(
            error(&fec) < error(&plc),
            "FEC {:.3e} vs PLC {:.3e}",
            error(&fec),
            error(&plc)
        );
    }

    #[test]
    fn bad_packets_and_settings_are_errors() {
        let mut dec = Decoder::new().unwrap();
        let mut out = [0i16; MAX_PACKET_SAMPLES];
        assert_eq!(dec.decode(&[], &mut out), Err(CodecError::Corrupted));
        // Code 3 (arbitrary frame count) with 0 frames is invalid.
        assert_eq!(
            dec.decode(&[0x03, 0x00], &mut out),
            Err(CodecError::Corrupted)
        );
        // Code 3 claiming 48 frames of 20 ms: 960 ms, more than a packet may hold.
        assert_eq!(
            dec.decode(&[0x0b, 48], &mut out),
            Err(CodecError::Corrupted)
        );
        assert!(matches!(
            dec.decode(&vec![0u8; MAX_INPUT_PACKET_BYTES + 1], &mut out),
            Err(CodecError::PacketTooLarge(_))
        ));
        // A 20 ms packet into 10 ms of room.
        let packets = encode_all(EncoderConfig::default(), &buzz(160, 8000));
        assert_eq!(
            dec.decode(&packets[0], &mut out[..80]),
            Err(CodecError::OutputTooSmall {
                packet: 160,
                room: 80
            })
        );
        assert_eq!(dec.conceal(&mut out[..7]), Err(CodecError::Duration(7)));
        let bad = |c: EncoderConfig| Encoder::new(c).err();
        let d = EncoderConfig::default();
        assert_eq!(
            bad(EncoderConfig { bitrate: 5000, ..d }),
            Some(CodecError::Bitrate(5000))
        );
        assert_eq!(
            bad(EncoderConfig {
                complexity: 11,
                ..d
            }),
            Some(CodecError::Complexity(11))
        );
        assert_eq!(
            bad(EncoderConfig {
                input_rate: 44_100,
                ..d
            }),
            Some(CodecError::Rate(44_100))
        );
        assert!(matches!(
            Decoder::with_rate(11_025),
            Err(CodecError::Rate(_))
        ));
    }

    #[test]
    fn dtx_sends_tiny_packets_in_silence() {
        let packets = encode_all(
            EncoderConfig {
                dtx: true,
                ..Default::default()
            },
            &vec![0i16; 8000],
        );
        let tiny = packets.iter().filter(|p| p.len() <= 2).count();
        assert!(tiny > 30, "{tiny} of {} packets", packets.len());
        let mut dec = Decoder::new().unwrap();
        let mut frame = [0i16; FRAME_SIZE];
        for p in &packets {
            dec.decode_frame(p, &mut frame).unwrap();
        }
    }
}
