//! Per-frame inputs of the lip-sync network: the decoder's 10 LSPs and the frame energy.
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
use super::{FRAME_SIZE, LSP_COUNT};
use crate::codec::FeatureFamily;

/// What the receiver knows about one 20 ms frame once it has decoded it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameFeatures {
    /// What the codec says of the frame: Speex's narrowband mode (0..=8), Opus's TOC
    /// configuration (0..=31), G.711's payload type (0 or 8); `None` for a concealed frame.
    pub mode: Option<u8>,
    /// Quantised LSPs in radians, strictly increasing in (0, pi).
    pub lsp: [f32; LSP_COUNT],
    /// Energy of the decoded samples of the row, in dB relative to a full-scale square wave.
    pub energy_db: f32,
    /// Where `lsp` comes from.
    pub family: FeatureFamily,
}

/// The energy floor: digital silence reads as this, not as minus infinity.
pub const SILENCE_DB: f32 = -100.0;

/// LSPs of a flat spectrum, what the features hold before the first speech frame.
pub fn flat_lsp() -> [f32; LSP_COUNT] {
    std::array::from_fn(|i| std::f32::consts::PI * (i + 1) as f32 / (LSP_COUNT + 1) as f32)
}

/// Smallest gap kept between neighbouring LSPs and from 0 and pi.
pub const LSP_MARGIN: f32 = 0.002;

/// The decoder stores LSPs exactly as dequantised, and a few quantiser codes give overlapping
/// or non-positive values (the decoder only spaces the interpolated copies it filters with).
/// Features promise `0 < lsp1 < ... < lsp10 < pi`, so sort and space them here.
pub fn ordered_lsp(lsp: [f32; LSP_COUNT]) -> [f32; LSP_COUNT] {
    if already_ordered(&lsp) {
        lsp
    } else {
        sorted_and_spaced(lsp)
    }
}

/// Whether [`sorted_and_spaced`] would return `lsp` unchanged: increasing, each at least
/// [`LSP_MARGIN`] above the one below (and 0) and below its ceiling, in the same f32
/// arithmetic. Most frames' LSPs are, and this check costs a fraction of the sort.
fn already_ordered(lsp: &[f32; LSP_COUNT]) -> bool {
    let mut floor = LSP_MARGIN;
    let mut ordered = true;
    for (i, &l) in lsp.iter().enumerate() {
        ordered &= l >= floor && l <= lsp_ceiling(i);
        floor = l + LSP_MARGIN;
    }
    ordered
}

fn sorted_and_spaced(mut lsp: [f32; LSP_COUNT]) -> [f32; LSP_COUNT] {
    lsp.sort_by(f32::total_cmp);
    let mut floor = LSP_MARGIN;
    for (i, l) in lsp.iter_mut().enumerate() {
        let ceiling = lsp_ceiling(i);
        // Not `clamp`: after a value held at its ceiling, `floor` (that ceiling plus the margin)
        // can round a hair above this ceiling, and `clamp` panics on that.
        *l = l.max(floor).min(ceiling);
        floor = *l + LSP_MARGIN;
    }
    lsp
}

/// The highest LSP `i` may take: room for a margin above each LSP after it, and below pi.
fn lsp_ceiling(i: usize) -> f32 {
    (std::f32::consts::PI - LSP_MARGIN) - LSP_MARGIN * (LSP_COUNT - 1 - i) as f32
}

/// Mean-square energy of 16-bit samples in dB re full scale, floored at [`SILENCE_DB`].
pub fn energy_db(samples: &[i16]) -> f32 {
    if samples.is_empty() {
        return SILENCE_DB;
    }
    // Exact in integers (and so the same sum in any order, which lets it vectorise).
    let sum: i64 = samples
        .iter()
        .map(|&s| i64::from(i32::from(s) * i32::from(s)))
        .sum();
    let mean = sum as f64 / samples.len() as f64 / (32768.0 * 32768.0);
    if mean <= 0.0 {
        return SILENCE_DB;
    }
    ((10.0 * mean.log10()) as f32).max(SILENCE_DB)
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn energy_of_full_scale_square_is_zero_db() {
        assert!((energy_db(&[32767, -32768, 32767, -32768]) - 0.0).abs() < 0.01);
        assert_eq!(energy_db(&[0; 160]), SILENCE_DB);
        let half: Vec<i16> = vec![16384; 160];
        assert!((energy_db(&half) + 6.02).abs() < 0.01);
    }

    #[test]
    fn overlapping_and_negative_lsps_are_ordered_and_spaced() {
        let raw = [-0.061, 0.3, 0.29, 0.29, 1.0, 1.5, 2.0, 2.5, 3.0, 3.2];
        let l = ordered_lsp(raw);
        assert!(l[0] >= LSP_MARGIN);
        assert!(l[9] <= std::f32::consts::PI - LSP_MARGIN);
        assert!(l.windows(2).all(|w| w[1] - w[0] >= LSP_MARGIN * 0.999));
        let fine = flat_lsp();
        assert_eq!(ordered_lsp(fine), fine);
    }

    #[test]
    fn lsps_already_ordered_are_those_sorting_and_spacing_keeps() {
        let mut state = 0x9E37_79B9u32;
        let mut next = || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) as f32 / (1u32 << 24) as f32
        };
        let (mut kept, mut total) = (0, 0);
        for round in 0..20_000 {
            // Sorted random angles, some crowded (gaps near the margin) or out of range.
            let spread = [3.2f32, 0.05, 0.02][round % 3];
            let mut lsp: [f32; LSP_COUNT] = std::array::from_fn(|_| next() * spread);
            if round % 2 == 0 {
                lsp.sort_by(f32::total_cmp);
                let offset = next() * (3.2 - spread);
                lsp.iter_mut().for_each(|l| *l += offset);
            }
            total += 1;
            if already_ordered(&lsp) {
                kept += 1;
                assert_eq!(sorted_and_spaced(lsp), lsp, "{lsp:?}");
            } else {
                assert_ne!(sorted_and_spaced(lsp), lsp, "{lsp:?}");
            }
            assert_eq!(ordered_lsp(lsp), sorted_and_spaced(lsp), "{lsp:?}");
        }
        assert!(kept > total / 10 && kept < total, "{kept} of {total}");
    }

    #[test]
    fn flat_lsp_is_increasing_inside_zero_pi() {
        let l = flat_lsp();
        assert!(l[0] > 0.0 && l[9] < std::f32::consts::PI);
        assert!(l.windows(2).all(|w| w[0] < w[1]));
    }
}
