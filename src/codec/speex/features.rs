//! Speex's feature rows ([`FrameFeatures`]): the decoder's 10 LSPs, read from the bitstream, and
//! the frame energy.
//!
//! Alignment. The decoder's synthesis runs one sub-frame (40 samples) behind its LSPs: the
//! parameters of decoded frame `k` shape output samples `160k+40 .. 160k+200`. A feature row
//! covers 160 output samples starting at `p` (a frame of OUT.wav, or of the audio as played);
//! its LSPs are those of the frame whose synthesis overlaps those samples most, which is the
//! decoded frame holding sample `p` both for speexdec's trimmed output (`p = 160n + 80` in
//! decoder samples: 120 of 160 samples overlap) and for untrimmed real-time playback
//! (`p = 160k`: 120 of 160 again). The energy is measured on exactly the row's 160 samples, so
//! a row never waits for audio that has not been decoded yet.

use super::bitstream::{BitstreamError, Frame, Walker};
use crate::vocab::{
    FRAME_SIZE, FeatureFamily, FrameFeatures, LSP_COUNT, energy_db, flat_lsp, ordered_lsp,
};

#[derive(Debug, thiserror::Error)]
pub enum FeatureError {
    #[error("the decoder and the bitstream walker disagree on packet {packet}: {source}")]
    Walker {
        packet: usize,
        source: BitstreamError,
    },
}

/// Real-time features: one row per decoded (or concealed) frame, no allocation, no look-ahead.
#[derive(Debug, Clone)]
pub struct FrameTracker {
    walker: Walker,
    pending: [Option<(u8, [f32; LSP_COUNT])>; MAX_TRACKED_FRAMES],
    pending_len: usize,
    next: usize,
}

const MAX_TRACKED_FRAMES: usize = super::ogg_file::MAX_FRAMES_PER_PACKET;

impl Default for FrameTracker {
    fn default() -> Self {
        Self {
            walker: Walker::new(),
            pending: [None; MAX_TRACKED_FRAMES],
            pending_len: 0,
            next: 0,
        }
    }
}

impl FrameTracker {
    pub fn new() -> Self {
        Self::default()
    }

    /// Reads the LSPs of every frame of a packet about to be decoded.
    pub fn start_packet(&mut self, packet: &[u8]) -> Result<(), BitstreamError> {
        self.pending_len = 0;
        self.next = 0;
        for frame in self.walker.frames(packet) {
            let frame = frame?;
            if self.pending_len == MAX_TRACKED_FRAMES {
                break;
            }
            self.pending[self.pending_len] = Some(match frame {
                Frame::Speech { mode, lsp } => (mode, ordered_lsp(lsp)),
                Frame::Silence { held_lsp } => (0, held_lsp.map_or_else(flat_lsp, ordered_lsp)),
            });
            self.pending_len += 1;
        }
        Ok(())
    }

    /// Features of the next decoded frame of the current packet.
    pub fn decoded(&mut self, pcm: &[i16]) -> FrameFeatures {
        let slot = (self.next < self.pending_len)
            .then(|| self.pending[self.next])
            .flatten();
        self.next += 1;
        let (mode, lsp) = match slot {
            Some((mode, lsp)) => (Some(mode), lsp),
            None => (None, self.held_lsp()),
        };
        FrameFeatures {
            mode,
            lsp,
            energy_db: energy_db(pcm),
            family: FeatureFamily::Bitstream,
        }
    }

    /// Features of a concealed frame: the decoder keeps its last LSPs while its output fades, so
    /// the mouth follows the fading energy towards closed.
    pub fn concealed(&mut self, pcm: &[i16]) -> FrameFeatures {
        FrameFeatures {
            mode: None,
            lsp: self.held_lsp(),
            energy_db: energy_db(pcm),
            family: FeatureFamily::Bitstream,
        }
    }

    fn held_lsp(&self) -> [f32; LSP_COUNT] {
        self.walker
            .held_lsp()
            .map_or_else(flat_lsp, |&lsp| ordered_lsp(lsp))
    }
}

/// Offline features for a whole decoded stream whose output was trimmed (as speexdec trims it).
#[derive(Debug, Default)]
pub struct FeatureExtractor {
    tracker: FrameTracker,
    packets: usize,
    /// Mode and LSPs of every decoded frame.
    frames: Vec<(Option<u8>, [f32; LSP_COUNT])>,
    /// For every output sample, the decoded frame it came from.
    origin: Vec<u32>,
    pcm: Vec<i16>,
}

impl FeatureExtractor {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn start_packet(&mut self, packet: &[u8]) -> Result<(), FeatureError> {
        self.packets += 1;
        self.tracker
            .start_packet(packet)
            .map_err(|source| FeatureError::Walker {
                packet: self.packets,
                source,
            })
    }

    /// Records a decoded frame of which `pcm[keep]` went to the output.
    pub fn push_frame(&mut self, pcm: &[i16; FRAME_SIZE], keep: std::ops::Range<usize>) {
        let row = self.tracker.decoded(pcm);
        let index = self.frames.len() as u32;
        self.frames.push((row.mode, row.lsp));
        let kept = &pcm[keep.start.min(FRAME_SIZE)..keep.end.min(FRAME_SIZE)];
        self.origin.extend(std::iter::repeat_n(index, kept.len()));
        self.pcm.extend_from_slice(kept);
    }

    /// The output PCM and one feature row per 160 output samples (the last may be partial).
    pub fn finish(self) -> (Vec<i16>, Vec<FrameFeatures>) {
        let features = self
            .pcm
            .chunks(FRAME_SIZE)
            .enumerate()
            .map(|(row, samples)| {
                let (mode, lsp) = self.frames[self.origin[row * FRAME_SIZE] as usize];
                FrameFeatures {
                    mode,
                    lsp,
                    energy_db: energy_db(samples),
                    family: FeatureFamily::Bitstream,
                }
            })
            .collect();
        (self.pcm, features)
    }
}
