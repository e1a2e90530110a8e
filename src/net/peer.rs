//! One remote speaker's receive pipeline: the jitter buffer decides what to play when, the
//! codec layer decodes it ([`StreamDecoder`]) with concealment and the per-frame features the
//! lip-sync network eats.
//!
//! Payload types come through the session's [`PayloadMap`]: a type it does not know is counted
//! and dropped, never decoded as another codec. The buffer runs on the RTP clock of the
//! stream's codec; a stream that switches payload type switches decoder at the first packet of
//! the new type (and, if the clock rate changes, restarts its timing).
//!
//! What the mouth does during loss: a concealed frame keeps the last LSPs (the vocal-tract
//! shape freezes) while the codec's concealment fades the signal out over a few frames, so
//! `energy_db` falls and a network driven by these features closes the mouth towards `sil`. A
//! long gap (a loss, or Opus DTX sending nothing in silence) ends the talk spurt and the peer
//! falls silent (no rows at all).
//!
//! The buffer corrects its delay (clock drift, a change of jitter) inside pauses, and only this
//! side hears the audio: each frame played is told to it as quiet or audible ([`QuietGate`]),
//! and a quiet frame it asks to drop is replaced by the next one.

use std::time::Instant;

use super::jitter::{
    Arrival, Correction, JitterBuffer, JitterConfig, JitterStats, Loudness, Piece, Playout,
};
use super::rtp::Rtp;
use crate::codec::any::{Codec, PayloadMap};
use crate::codec::decoder::{DecodedFrame, FrameOrigin, StreamDecoder};
use crate::vocab::{FRAME_SIZE, FrameAudio};
use crate::vocab::{FrameFeatures, SILENCE_DB};

/// How a played frame came about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    Decoded,
    /// Its packet was lost or late: the decoder concealed it.
    Concealed,
    /// Its packet was lost and the next packet's FEC rebuilt it (Opus).
    Recovered,
    /// Inserted to grow the jitter buffer's delay (also concealment).
    Stretched,
}

/// 20 ms of one peer's audio as played, with its features.
#[derive(Debug, Clone, PartialEq)]
pub struct PlayedFrame {
    /// What the ear hears, at the codec's own rate (48 kHz Opus, 16 kHz G.722, ...).
    pub audio: FrameAudio,
    /// The same 20 ms as the 8 kHz signal the features came from: what the lip-sync pipeline
    /// is given beside them.
    pub pcm: [i16; FRAME_SIZE],
    pub features: FrameFeatures,
    pub kind: FrameKind,
    pub codec: Codec,
}

impl PlayedFrame {
    /// A frame of 8 kHz audio, heard as it is.
    pub fn narrowband(
        pcm: [i16; FRAME_SIZE],
        features: FrameFeatures,
        kind: FrameKind,
        codec: Codec,
    ) -> Self {
        Self {
            audio: FrameAudio::narrowband(&pcm),
            pcm,
            features,
            kind,
            codec,
        }
    }
}

/// Below this a frame is quiet whatever the speaker's level (dBFS; speech sits at -35 to -10).
const QUIET_DB: f32 = -50.0;
/// A frame this close to the background's level, and this far below the speech, is quiet too
/// (a microphone whose noise floor is above [`QUIET_DB`]).
const NEAR_FLOOR_DB: f32 = 6.0;
const BELOW_SPEECH_DB: f32 = 20.0;
/// How fast the trackers forget, per frame: the floor rises 2.5 dB a second, the speech level
/// falls 1 dB a second.
const FLOOR_RISE_DB: f32 = 0.05;
const SPEECH_FALL_DB: f32 = 0.02;

/// Tells quiet frames (silence, background noise) from audible ones by their energy, against
/// an absolute floor and the stream's own levels: its background (the quietest frames lately)
/// and its speech (the loudest).
#[derive(Debug, Clone, Copy)]
pub struct QuietGate {
    floor_db: f32,
    speech_db: f32,
}

impl Default for QuietGate {
    fn default() -> Self {
        Self {
            floor_db: 0.0,
            speech_db: SILENCE_DB,
        }
    }
}

impl QuietGate {
    /// The loudness of a frame of `energy_db`, and the levels updated with it.
    pub fn judge(&mut self, energy_db: f32) -> Loudness {
        self.floor_db = energy_db.min(self.floor_db + FLOOR_RISE_DB);
        self.speech_db = energy_db.max(self.speech_db - SPEECH_FALL_DB);
        let near_floor = energy_db < self.floor_db + NEAR_FLOOR_DB
            && energy_db < self.speech_db - BELOW_SPEECH_DB;
        if energy_db < QUIET_DB || near_floor {
            Loudness::Quiet
        } else {
            Loudness::Audible
        }
    }
}

pub struct PeerReceiver {
    jitter: JitterBuffer,
    gate: QuietGate,
    payloads: PayloadMap,
    enhancer: bool,
    decoder: Option<StreamDecoder>,
    /// The codec of the last packet filed.
    codec: Option<Codec>,
    concealed: u64,
    recovered: u64,
    /// Errors of decoders replaced at a codec switch.
    past_errors: u64,
    /// A decoder could not be created (the frame was played as silence).
    decoder_failures: u64,
    unknown_payload: u64,
    last_unknown_type: Option<u8>,
}

impl std::fmt::Debug for PeerReceiver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PeerReceiver")
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

impl PeerReceiver {
    /// A receiver with the default payload types (GStreamer's and RFC 3551's).
    pub fn new(config: JitterConfig, epoch: Instant, enhancer: bool) -> Self {
        Self::with_payloads(config, epoch, enhancer, PayloadMap::default())
    }

    pub fn with_payloads(
        config: JitterConfig,
        epoch: Instant,
        enhancer: bool,
        payloads: PayloadMap,
    ) -> Self {
        Self {
            jitter: JitterBuffer::new(config, epoch),
            gate: QuietGate::default(),
            payloads,
            enhancer,
            decoder: None,
            codec: None,
            concealed: 0,
            recovered: 0,
            past_errors: 0,
            decoder_failures: 0,
            unknown_payload: 0,
            last_unknown_type: None,
        }
    }

    /// Files a packet for playout; false (and counted) if its payload type carries no codec
    /// we know.
    pub fn insert(&mut self, packet: &Rtp<'_>, arrival: Instant) -> bool {
        let h = packet.header;
        let Some(codec) = self.payloads.codec(h.payload_type) else {
            self.unknown_payload += 1;
            self.last_unknown_type = Some(h.payload_type);
            self.jitter.unplayable(h.sequence);
            return false;
        };
        self.jitter.set_clock(codec.clock_rate());
        self.codec = Some(codec);
        // A payload whose length cannot be read still takes its place: it lasts a frame.
        let duration = codec
            .payload_duration(packet.payload)
            .unwrap_or(codec.frame_ticks());
        let streams = self.jitter.restarts();
        let was_idle = self.jitter.idle();
        self.jitter.file(Arrival {
            sequence: h.sequence,
            timestamp: h.timestamp,
            marker: h.marker,
            payload_type: h.payload_type,
            payload: packet.payload,
            duration,
            on_grid: codec.whole_frames(),
            at: arrival,
        });
        if self.jitter.restarts() != streams && was_idle {
            // A new stream (a redial on this SSRC) after the old one played out: its encoder
            // started afresh. (Right behind the old one's tail, the decoder plays on.)
            self.past_errors += self.decoder.as_ref().map_or(0, StreamDecoder::errors);
            self.decoder = None;
        }
        true
    }

    /// The highest sequence number received in the current stream.
    pub fn highest_sequence(&self) -> Option<u16> {
        self.jitter.highest_sequence()
    }

    /// New streams started on this SSRC after the first (redials).
    pub fn restarts(&self) -> u64 {
        self.jitter.restarts()
    }

    pub fn jitter(&mut self) -> &mut JitterBuffer {
        &mut self.jitter
    }

    /// The codec of the last packet received.
    pub fn codec(&self) -> Option<Codec> {
        self.codec
    }

    /// The decoder for `codec`, a new one after a switch.
    fn decoder(&mut self, codec: Codec) -> Option<&mut StreamDecoder> {
        if self.decoder.as_ref().is_none_or(|d| d.codec() != codec) {
            self.past_errors += self.decoder.as_ref().map_or(0, StreamDecoder::errors);
            self.decoder = StreamDecoder::new(codec, self.enhancer).ok();
            self.decoder_failures += u64::from(self.decoder.is_none());
        }
        self.decoder.as_mut()
    }

    /// The decoder playing now (or for the stream's codec if none yet).
    fn current(&mut self) -> Option<&mut StreamDecoder> {
        match self
            .decoder
            .as_ref()
            .map(StreamDecoder::codec)
            .or(self.codec)
        {
            Some(codec) => self.decoder(codec),
            None => None,
        }
    }

    fn start(&mut self, piece: &Piece) -> Option<&mut StreamDecoder> {
        let codec = self.payloads.codec(piece.payload_type)?;
        let decoder = self.decoder(codec)?;
        decoder.packet(piece, piece.offset);
        Some(decoder)
    }

    /// The next 20 ms of this peer, or `None` while it is silent. A quiet frame the buffer
    /// drops (its delay is more than needed) is decoded, so the decoder stays in step, and
    /// replaced by the frame after it.
    pub fn pull(&mut self, now: Instant) -> Option<PlayedFrame> {
        let frame = self.next_frame(now)?;
        let loudness = self.gate.judge(frame.features.energy_db);
        if self.jitter.played(loudness) != Correction::Drop {
            return Some(frame);
        }
        // (Right after a correction the buffer asks for none: one per pull at most.)
        let next = self.next_frame(now)?;
        let loudness = self.gate.judge(next.features.energy_db);
        self.jitter.played(loudness);
        Some(next)
    }

    fn next_frame(&mut self, now: Instant) -> Option<PlayedFrame> {
        let (frame, stretched) = match self.jitter.pop(now) {
            Playout::Silent | Playout::Pause => return None,
            Playout::Packet(piece) => (self.start(&piece).map(StreamDecoder::frame), false),
            Playout::Pieces(pieces) => {
                for piece in &pieces {
                    self.start(piece);
                }
                (self.current().map(StreamDecoder::frame), false)
            }
            Playout::NextFrame => (self.current().map(StreamDecoder::frame), false),
            Playout::Lost => {
                let codec = self
                    .decoder
                    .as_ref()
                    .map(StreamDecoder::codec)
                    .or(self.codec);
                let next = self
                    .jitter
                    .upcoming()
                    .filter(|&(pt, _)| self.payloads.codec(pt) == codec)
                    .map(|(_, p)| p.to_vec());
                (self.current().map(|d| d.lost(next.as_deref())), false)
            }
            Playout::Stretch => (self.current().map(|d| d.lost(None)), true),
        };
        let codec = self
            .decoder
            .as_ref()
            .map(StreamDecoder::codec)
            .or(self.codec)
            .unwrap_or(Codec::Speex);
        let DecodedFrame {
            audio,
            pcm,
            features,
            origin,
        } = frame.unwrap_or_else(|| DecodedFrame {
            audio: FrameAudio::silence(codec.audio_rate()),
            pcm: [0; FRAME_SIZE],
            features: FrameFeatures::silent(),
            origin: FrameOrigin::Concealed,
        });
        let kind = match (origin, stretched) {
            (_, true) => FrameKind::Stretched,
            (FrameOrigin::Decoded, _) => FrameKind::Decoded,
            (FrameOrigin::Concealed, _) => FrameKind::Concealed,
            (FrameOrigin::Recovered, _) => FrameKind::Recovered,
        };
        match kind {
            FrameKind::Concealed | FrameKind::Stretched => self.concealed += 1,
            FrameKind::Recovered => self.recovered += 1,
            FrameKind::Decoded => {}
        }
        Some(PlayedFrame {
            audio,
            pcm,
            features,
            kind,
            codec,
        })
    }

    pub fn stats(&self) -> ReceiverStats {
        ReceiverStats {
            jitter: self.jitter.stats(),
            concealed: self.concealed,
            recovered: self.recovered,
            decode_errors: self.past_errors
                + self.decoder_failures
                + self.decoder.as_ref().map_or(0, StreamDecoder::errors),
            unknown_payload: self.unknown_payload,
            last_unknown_type: self.last_unknown_type,
            codec: self.codec,
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ReceiverStats {
    pub jitter: JitterStats,
    /// Frames concealed by the decoder (lost, late, stretched or undecodable).
    pub concealed: u64,
    /// Lost frames rebuilt from the next packet's FEC.
    pub recovered: u64,
    pub decode_errors: u64,
    /// Packets of a payload type no codec is mapped to, dropped.
    pub unknown_payload: u64,
    pub last_unknown_type: Option<u8>,
    /// The codec of the last packet received.
    pub codec: Option<Codec>,
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::codec::any::{EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD};
    use crate::net::rtp::{self, RtpStream};

    const FRAME: Duration = Duration::from_millis(20);

    fn voice(frame: usize) -> [i16; FRAME_SIZE] {
        std::array::from_fn(|i| {
            let t = (frame * FRAME_SIZE + i) as f32 / 8000.0;
            let mut s = 0.0;
            for h in 1..15 {
                let f = 130.0 * h as f32;
                s += (2.0 * std::f32::consts::PI * f * t).sin()
                    / (1.0 + ((f - 650.0) / 250.0).powi(2));
            }
            (6000.0 * s * (1.0 + (t * 7.0).sin()) / 2.0) as i16
        })
    }

    /// One sender: encodes frame `k` of `voice` with `codec` and packetises it.
    struct Sender {
        stream: RtpStream,
        encoder: FrameEncoder,
        map: PayloadMap,
        buf: Vec<u8>,
    }

    impl Sender {
        fn new(codec: Codec) -> Self {
            let mut s = Self {
                stream: RtpStream::new(42, 100, 5000),
                encoder: FrameEncoder::new(codec, &EncoderSettings::default()).unwrap(),
                map: PayloadMap::default(),
                buf: Vec::new(),
            };
            s.switch(codec);
            s
        }

        fn switch(&mut self, codec: Codec) {
            self.encoder = FrameEncoder::new(codec, &EncoderSettings::default()).unwrap();
            let pt = self.map.payload_type(codec).unwrap();
            self.stream.set_payload(pt, codec.frame_ticks());
        }

        fn packet(&mut self, k: usize) -> Vec<u8> {
            let mut out = [0u8; MAX_FRAME_PAYLOAD];
            let (n, ticks) = self.encoder.encode(&voice(k), &mut out).unwrap().unwrap();
            self.stream
                .packetize_ticks(&out[..n], ticks, &mut self.buf)
                .unwrap();
            self.buf.clone()
        }
    }

    /// Sends `frames` frames in real time (`send(k)` gives frame k's datagram, or `None` to
    /// send nothing) and pulls every 20 ms.
    fn call(
        rx: &mut PeerReceiver,
        frames: usize,
        mut send: impl FnMut(usize) -> Option<Vec<u8>>,
    ) -> Vec<Option<PlayedFrame>> {
        let t0 = Instant::now();
        let mut out = Vec::new();
        for k in 0..frames + 30 {
            let now = t0 + FRAME * k as u32;
            if k < frames
                && let Some(datagram) = send(k)
            {
                let packet = rtp::parse(&datagram, None).unwrap();
                rx.insert(&packet, now);
            }
            out.push(rx.pull(now));
        }
        out
    }

    /// Speech with pauses: 1.6 s of voiced sound (harmonics of a gliding pitch, no fades),
    /// then 0.4 s of faint noise (-66 dBFS).
    fn talk_with_pauses(frame: usize) -> Option<[i16; FRAME_SIZE]> {
        (frame % 100 < 80).then(|| {
            std::array::from_fn(|i| {
                // A pitch gliding between 100 and 140 Hz (its phase, the pitch's integral, in
                // cycles) and 11 harmonics under one formant.
                let t = (frame * FRAME_SIZE + i) as f64 / 8000.0;
                let pitch = 120.0 + 20.0 * (2.0 * t).sin();
                let cycles = 120.0 * t - 10.0 * (2.0 * t).cos();
                let s: f64 = (1..12)
                    .map(|h| {
                        let f = pitch * f64::from(h);
                        (std::f64::consts::TAU * cycles * f64::from(h)).sin()
                            / (1.0 + ((f - 650.0) / 300.0).powi(2))
                    })
                    .sum();
                (4000.0 * s) as i16
            })
        })
    }

    fn faint_noise(frame: usize) -> [i16; FRAME_SIZE] {
        std::array::from_fn(|i| (((frame * FRAME_SIZE + i) * 7919 % 31) as i16 - 15) * 2)
    }

    /// 40 s of [`talk_with_pauses`] from a Speex sender sending a packet every `period_us`,
    /// pulled every 20 ms: the frames played, and the receiver's counts.
    fn drifting_call(period_us: u64) -> (Vec<PlayedFrame>, ReceiverStats) {
        let mut rx = PeerReceiver::new(JitterConfig::default(), Instant::now(), true);
        let mut sender = Sender::new(Codec::Speex);
        let frames = 2000;
        let t0 = Instant::now();
        let send_at = |k: usize| t0 + Duration::from_micros(period_us * k as u64 + 3000);
        let mut played = Vec::new();
        let mut next = 0;
        for k in 0..frames + 60 {
            let now = t0 + FRAME * k as u32;
            while next < frames && send_at(next) <= now {
                let pcm = talk_with_pauses(next).unwrap_or_else(|| faint_noise(next));
                let mut out = [0u8; MAX_FRAME_PAYLOAD];
                let (n, ticks) = sender.encoder.encode(&pcm, &mut out).unwrap().unwrap();
                sender
                    .stream
                    .packetize_ticks(&out[..n], ticks, &mut sender.buf)
                    .unwrap();
                let packet = rtp::parse(&sender.buf, None).unwrap();
                rx.insert(&packet, send_at(next));
                next += 1;
            }
            played.extend(rx.pull(now));
        }
        (played, rx.stats())
    }

    fn loud(played: &[PlayedFrame]) -> usize {
        played
            .iter()
            .filter(|f| f.kind == FrameKind::Decoded && f.features.energy_db > -35.0)
            .count()
    }

    #[test]
    fn a_drifting_sender_loses_no_speech() {
        // A sender whose clock is 1 % fast (a packet every 19.8 ms) or 1 % slow (20.2 ms)
        // against one in step. The receiver hears which frames are quiet and the buffer
        // corrects its delay in those only: every loud frame is played, as in step.
        let (steady, stats) = drifting_call(20_000);
        assert_eq!(
            stats.jitter.stretched + stats.jitter.dropped,
            0,
            "{stats:?}"
        );
        for (period_us, fast) in [(19_800u64, true), (20_200, false)] {
            let (played, stats) = drifting_call(period_us);
            let what = format!("fast {fast}: {stats:?}");
            assert_eq!(loud(&played), loud(&steady), "{what}");
            let j = stats.jitter;
            assert_eq!((j.forced, j.late, j.lost), (0, 0, 0), "{what}");
            assert!(if fast { j.dropped } else { j.stretched } >= 15, "{what}");
            // The frames inserted were quiet: no loud frame is concealed.
            assert!(
                played
                    .iter()
                    .filter(|f| f.kind != FrameKind::Decoded)
                    .all(|f| f.features.energy_db < -45.0),
                "{what}"
            );
        }
    }

    #[test]
    fn unknown_payload_types_are_counted_and_never_played() {
        let mut rx = PeerReceiver::new(JitterConfig::default(), Instant::now(), true);
        let mut sender = Sender::new(Codec::Speex);
        // Speex inside, but on payload type 100, which nobody mapped.
        sender.stream.set_payload(100, 160);
        let out = call(&mut rx, 50, |k| Some(sender.packet(k)));
        assert!(out.iter().all(Option::is_none));
        let stats = rx.stats();
        assert_eq!(stats.unknown_payload, 50);
        assert_eq!(stats.last_unknown_type, Some(100));
        assert_eq!((stats.jitter.received, stats.codec), (0, None));
    }

    #[test]
    fn packets_of_unknown_payload_types_are_not_counted_lost() {
        // A phone's telephone-event (or comfort noise) between its speech packets, on the same
        // SSRC and sequence numbers: they came, so none of them is lost.
        let mut rx = PeerReceiver::new(JitterConfig::default(), Instant::now(), true);
        let mut sender = Sender::new(Codec::Speex);
        let out = call(&mut rx, 100, |k| {
            let pt = if k % 10 == 5 { 101 } else { 110 };
            sender.stream.set_payload(pt, 160);
            Some(sender.packet(k))
        });
        let stats = rx.stats();
        assert_eq!(stats.unknown_payload, 10, "{stats:?}");
        assert_eq!(
            (stats.jitter.received, stats.jitter.lost),
            (90, 0),
            "{stats:?}"
        );
        assert!(out.iter().flatten().count() >= 90, "{stats:?}");
    }

    #[test]
    fn a_stream_switching_codecs_switches_decoder() {
        for (first, second) in [
            (Codec::Speex, Codec::Pcmu),
            (Codec::Speex, Codec::Opus),
            (Codec::Opus, Codec::Pcma),
        ] {
            let mut rx = PeerReceiver::new(JitterConfig::default(), Instant::now(), true);
            let mut sender = Sender::new(first);
            let out = call(&mut rx, 100, |k| {
                if k == 50 {
                    sender.switch(second);
                }
                Some(sender.packet(k))
            });
            let played: Vec<&PlayedFrame> = out.iter().flatten().collect();
            let codecs: Vec<Codec> = played.iter().map(|f| f.codec).collect();
            let switch = codecs.iter().position(|&c| c == second).unwrap();
            assert!(codecs[..switch].iter().all(|&c| c == first));
            assert!(codecs[switch..].iter().all(|&c| c == second));
            // The new codec's frames decode: a restart of the timing at a new clock costs
            // at most the buffered frames, never garbage.
            let decoded = played[switch..]
                .iter()
                .filter(|f| f.kind == FrameKind::Decoded)
                .count();
            assert!(decoded >= 45, "{first}->{second}: {decoded}");
            let stats = rx.stats();
            assert_eq!(stats.decode_errors, 0, "{first}->{second}: {stats:?}");
            assert_eq!(stats.codec, Some(second));
        }
    }

    #[test]
    fn opus_dtx_gap_is_silence_and_the_next_spurt_plays() {
        let mut rx = PeerReceiver::new(JitterConfig::default(), Instant::now(), true);
        let mut sender = Sender::new(Codec::Opus);
        // 1 s of speech, 1 s of DTX (nothing sent; the timestamps move on), 1 s of speech.
        let out = call(&mut rx, 150, |k| {
            if (50..100).contains(&k) {
                sender.stream.skip(1);
                None
            } else {
                Some(sender.packet(k))
            }
        });
        let first = out.iter().position(Option::is_some).unwrap();
        let spurt: Vec<&PlayedFrame> = out[first..first + 50].iter().flatten().collect();
        assert_eq!(spurt.len(), 50);
        assert!(spurt.iter().all(|f| f.kind == FrameKind::Decoded));
        let held = spurt.last().unwrap().features.lsp;
        // While nothing is buffered the receiver cannot tell the pause from a loss: it conceals
        // for its delay (one frame on this jitter-free link), holding the LSPs, then rests.
        // (The second spurt may start a frame early: the buffer's delay has shrunk to 20 ms.)
        let gap: Vec<&Option<PlayedFrame>> = out[first + 50..first + 95].iter().collect();
        let concealed: Vec<&PlayedFrame> = gap.iter().filter_map(|f| f.as_ref()).collect();
        assert_eq!(concealed.len(), 1);
        assert!(gap[..1].iter().all(|f| f.is_some()));
        assert!(concealed.iter().all(|f| f.kind == FrameKind::Concealed));
        assert!(concealed.iter().all(|f| f.features.lsp == held));
        assert!(concealed.iter().all(|f| f.features.mode.is_none()));
        // The second spurt starts afresh, whole.
        let resumed: Vec<&PlayedFrame> = out[first + 95..].iter().flatten().collect();
        assert!(
            resumed
                .iter()
                .filter(|f| f.kind == FrameKind::Decoded)
                .count()
                >= 49
        );
        let stats = rx.stats();
        assert_eq!(stats.jitter.lost, 0, "{stats:?}");
        assert_eq!(stats.jitter.spurts, 2, "{stats:?}");
    }

    #[test]
    fn a_lost_opus_packet_is_rebuilt_from_the_next_ones_fec() {
        let mut rx = PeerReceiver::new(JitterConfig::default(), Instant::now(), true);
        let mut sender = Sender::new(Codec::Opus);
        let out = call(&mut rx, 100, |k| {
            let p = sender.packet(k);
            (k % 10 != 5).then_some(p)
        });
        let stats = rx.stats();
        assert_eq!(stats.jitter.lost, 10);
        // The ten, and the concealed tail after the stream.
        assert_eq!(
            stats.jitter.missing,
            10 + (out.iter().flatten().count() as u64 - 100)
        );
        // All ten losses have their next packet in the buffer; those whose next packet carries
        // FEC (speech that is active) are rebuilt, the others concealed.
        assert!(stats.recovered >= 8, "{stats:?}");
        assert_eq!(stats.recovered + stats.concealed, stats.jitter.missing);
    }
}
