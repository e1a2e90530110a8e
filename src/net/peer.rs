//! One remote speaker's receive pipeline: jitter buffer, Speex decoder with concealment and
//! the per-frame features the lip-sync network eats.
//!
//! What the mouth does during loss: a concealed frame keeps the last LSPs the decoder held
//! (the vocal-tract shape freezes) while libspeex fades the concealed signal out over a few
//! frames, so `energy_db` falls and a network driven by these features closes the mouth
//! towards `sil`. A long gap ends the talk spurt and the peer falls silent (no rows at all).

use std::time::Instant;

use super::jitter::{JitterBuffer, JitterConfig, JitterStats, Playout};
use super::rtp::Rtp;
use super::split;
use crate::codec::speex::FRAME_SIZE;
use crate::codec::speex::codec::{CodecError, Decoder, FrameOutcome};
use crate::codec::speex::features::{FrameFeatures, FrameTracker};

/// How a played frame came about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    Decoded,
    /// Its packet was lost or late: the decoder concealed it.
    Concealed,
    /// Inserted to grow the jitter buffer's delay (also concealment).
    Stretched,
}

/// 20 ms of one peer's audio as played, with its features.
#[derive(Debug, Clone, PartialEq)]
pub struct PlayedFrame {
    pub pcm: [i16; FRAME_SIZE],
    pub features: FrameFeatures,
    pub kind: FrameKind,
}

pub struct PeerReceiver {
    jitter: JitterBuffer,
    decoder: Decoder,
    tracker: FrameTracker,
    concealed: u64,
    decode_errors: u64,
}

impl std::fmt::Debug for PeerReceiver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PeerReceiver")
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

impl PeerReceiver {
    pub fn new(config: JitterConfig, epoch: Instant, enhancer: bool) -> Result<Self, CodecError> {
        Ok(Self {
            jitter: JitterBuffer::new(config, epoch),
            decoder: Decoder::new(enhancer)?,
            tracker: FrameTracker::new(),
            concealed: 0,
            decode_errors: 0,
        })
    }

    pub fn insert(&mut self, packet: &Rtp<'_>, arrival: Instant) {
        let frames = split::frame_count(packet.payload).unwrap_or(1) as u32;
        let h = packet.header;
        self.jitter.insert(
            h.sequence,
            h.timestamp,
            h.marker,
            packet.payload,
            frames,
            arrival,
        );
    }

    pub fn jitter(&mut self) -> &mut JitterBuffer {
        &mut self.jitter
    }

    /// The next 20 ms of this peer, or `None` while it is silent.
    pub fn pull(&mut self, now: Instant) -> Option<PlayedFrame> {
        let mut pcm = [0i16; FRAME_SIZE];
        let kind = match self.jitter.pop(now) {
            Playout::Silent => return None,
            Playout::Packet(payload) => {
                let loaded = self.decoder.load(&payload).is_ok();
                // A packet the walker cannot read still decodes; its row keeps held LSPs.
                let _ = self.tracker.start_packet(&payload);
                if loaded {
                    self.decode(&mut pcm)
                } else {
                    self.decode_errors += 1;
                    self.conceal(&mut pcm, FrameKind::Concealed)
                }
            }
            Playout::NextFrame => self.decode(&mut pcm),
            Playout::Lost => self.conceal(&mut pcm, FrameKind::Concealed),
            Playout::Stretch => self.conceal(&mut pcm, FrameKind::Stretched),
        };
        let features = match kind {
            FrameKind::Decoded => self.tracker.decoded(&pcm),
            _ => self.tracker.concealed(&pcm),
        };
        Some(PlayedFrame {
            pcm,
            features,
            kind,
        })
    }

    fn decode(&mut self, pcm: &mut [i16; FRAME_SIZE]) -> FrameKind {
        match self.decoder.decode_next(pcm) {
            Ok(FrameOutcome::Decoded) => FrameKind::Decoded,
            Ok(FrameOutcome::EndOfPacket) | Err(_) => {
                self.decode_errors += 1;
                self.conceal(pcm, FrameKind::Concealed)
            }
        }
    }

    fn conceal(&mut self, pcm: &mut [i16; FRAME_SIZE], kind: FrameKind) -> FrameKind {
        self.decoder.conceal(pcm);
        self.concealed += 1;
        kind
    }

    pub fn stats(&self) -> ReceiverStats {
        ReceiverStats {
            jitter: self.jitter.stats(),
            concealed: self.concealed,
            decode_errors: self.decode_errors,
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ReceiverStats {
    pub jitter: JitterStats,
    /// Frames concealed by the decoder (lost, late, stretched or undecodable).
    pub concealed: u64,
    pub decode_errors: u64,
}
