//! A pure-Rust walker over Speex narrowband packets.
//!
//! It reads only what the lip-sync path needs from each frame (the mode and the quantised
//! LSPs) and steps over everything else, following the reference decoder's framing rules so
//! that it finds exactly the frames `nb_decode` would decode. The LSPs are dequantised with
//! the same constants and the same floating-point steps as the float build of libspeex, so
//! they are bit-identical to the decoder's `old_qlsp` after each frame.
//!
//! Being the decoder's raw values, they are not always ordered or inside (0, pi): about 2% of
//! the 18-bit codes and 4% of the 30-bit codes give overlapping LSPs, and a few 30-bit codes
//! a first LSP at or below zero. The decoder enforces its stability margins only on the
//! per-subframe interpolated copies it builds filters from; consumers needing ordered LSPs
//! must do the same.

use super::lsp_tables::{CDBK_NB, CDBK_NB_HIGH1, CDBK_NB_HIGH2, CDBK_NB_LOW1, CDBK_NB_LOW2};
use crate::vocab::LSP_COUNT;

/// Ten LSPs in radians.
pub type Lsp = [f32; LSP_COUNT];

/// Highest narrowband mode (0 is silence, 1..=8 carry LSPs).
pub const MAX_MODE: u8 = 8;

/// Bits in the one-bit wideband flag plus the four-bit mode that open every frame.
const HEADER_BITS: usize = 5;

/// Total bits of one narrowband frame, header included, indexed by mode.
const FRAME_BITS: [usize; MAX_MODE as usize + 1] = [5, 43, 119, 160, 220, 300, 364, 492, 79];

/// Bits of a wideband layer as the narrowband decoder steps over it, indexed by submode.
/// Zero marks a submode it cannot step over (it treats the stream as corrupt).
const WIDEBAND_LAYER_BITS: [usize; 8] = [0, 36, 112, 192, 352, 0, 0, 0];

/// Mode codes that are not frames.
const MODE_USER_MESSAGE: u32 = 13;
const MODE_INBAND_REQUEST: u32 = 14;
const MODE_TERMINATOR: u32 = 15;

/// One narrowband frame found in a packet.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Frame {
    /// A frame of mode 1..=8; `lsp` is what the decoder's `old_qlsp` holds after it (which
    /// may be unordered, see the module documentation).
    Speech { mode: u8, lsp: Lsp },
    /// A mode-0 frame, which carries no LSPs. The decoder leaves `old_qlsp` untouched, so it
    /// still holds the last speech frame's LSPs (`held_lsp`); before any speech frame it holds
    /// zeros, reported here as `None`.
    Silence { held_lsp: Option<Lsp> },
}

impl Frame {
    /// The narrowband mode, 0..=8.
    pub fn mode(&self) -> u8 {
        match self {
            Frame::Speech { mode, .. } => *mode,
            Frame::Silence { .. } => 0,
        }
    }

    /// The LSPs the decoder holds after this frame, if it holds any yet.
    pub fn lsp(&self) -> Option<&Lsp> {
        match self {
            Frame::Speech { lsp, .. } => Some(lsp),
            Frame::Silence { held_lsp } => held_lsp.as_ref(),
        }
    }
}

/// Why a packet could not be walked. `frame` counts the frames already found before it.
///
/// The reference decoder reports the same packets as corrupt (-2), except truncation: there
/// it decodes the missing bits as zeros, or takes a cut-off in-band message or wideband
/// layer as the end of the packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum BitstreamError {
    #[error("frame {frame}: packet truncated ({needed} bits needed, {remaining} left)")]
    Truncated {
        frame: usize,
        needed: usize,
        remaining: usize,
    },
    #[error("frame {frame}: invalid narrowband mode {mode}")]
    InvalidMode { frame: usize, mode: u8 },
    #[error("frame {frame}: wideband layer with submode {submode}, which cannot be skipped")]
    InvalidWidebandSubmode { frame: usize, submode: u8 },
    #[error("frame {frame}: more than two wideband layers")]
    TooManyWidebandLayers { frame: usize },
}

impl BitstreamError {
    /// Index within the packet of the frame the walker was looking for.
    pub fn frame(&self) -> usize {
        match *self {
            BitstreamError::Truncated { frame, .. }
            | BitstreamError::InvalidMode { frame, .. }
            | BitstreamError::InvalidWidebandSubmode { frame, .. }
            | BitstreamError::TooManyWidebandLayers { frame } => frame,
        }
    }
}

/// Walks packets of one stream, keeping the LSP state that mode-0 frames report.
#[derive(Debug, Clone, Default)]
pub struct Walker {
    held: Option<Lsp>,
}

impl Walker {
    pub const fn new() -> Self {
        Self { held: None }
    }

    /// What the decoder's `old_qlsp` holds now: the last speech frame's LSPs, or `None` before
    /// any (the decoder holds zeros then). Lost frames do not change it.
    pub fn held_lsp(&self) -> Option<&Lsp> {
        self.held.as_ref()
    }

    /// Forgets the stream, as a freshly created decoder would.
    pub fn reset(&mut self) {
        self.held = None;
    }

    /// Iterates over the frames of one packet without allocating. After an error the iterator
    /// ends; the frames yielded before it have already updated the walker, as they would the
    /// decoder.
    pub fn frames<'w, 'p>(&'w mut self, packet: &'p [u8]) -> Frames<'w, 'p> {
        Frames {
            walker: self,
            reader: BitReader::new(packet),
            found: 0,
            done: false,
        }
    }

    /// All frames of one packet.
    pub fn walk_packet(&mut self, packet: &[u8]) -> Result<Vec<Frame>, BitstreamError> {
        self.frames(packet).collect()
    }
}

/// The frames of one packet; see [`Walker::frames`].
#[derive(Debug)]
pub struct Frames<'w, 'p> {
    walker: &'w mut Walker,
    reader: BitReader<'p>,
    found: usize,
    done: bool,
}

impl Iterator for Frames<'_, '_> {
    type Item = Result<Frame, BitstreamError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let result = next_frame(&mut self.reader, &mut self.walker.held)
            .map_err(|problem| problem.at_frame(self.found));
        match result {
            Ok(Some(frame)) => {
                self.found += 1;
                Some(Ok(frame))
            }
            Ok(None) => {
                self.done = true;
                None
            }
            Err(error) => {
                self.done = true;
                Some(Err(error))
            }
        }
    }
}

impl std::iter::FusedIterator for Frames<'_, '_> {}

/// A [`BitstreamError`] before it knows which frame it belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Problem {
    Overrun { needed: usize, remaining: usize },
    InvalidMode(u8),
    InvalidWidebandSubmode(u8),
    TooManyWidebandLayers,
}

impl Problem {
    fn at_frame(self, frame: usize) -> BitstreamError {
        match self {
            Problem::Overrun { needed, remaining } => BitstreamError::Truncated {
                frame,
                needed,
                remaining,
            },
            Problem::InvalidMode(mode) => BitstreamError::InvalidMode { frame, mode },
            Problem::InvalidWidebandSubmode(submode) => {
                BitstreamError::InvalidWidebandSubmode { frame, submode }
            }
            Problem::TooManyWidebandLayers => BitstreamError::TooManyWidebandLayers { frame },
        }
    }
}

/// Finds the next narrowband frame, or `None` where the decoder would report end of packet.
fn next_frame(
    reader: &mut BitReader<'_>,
    held: &mut Option<Lsp>,
) -> Result<Option<Frame>, Problem> {
    loop {
        if reader.remaining() < HEADER_BITS {
            return Ok(None);
        }
        if reader.read(1)? == 1 {
            skip_wideband_layer(reader)?;
            if reader.remaining() < HEADER_BITS {
                return Ok(None);
            }
            if reader.read(1)? == 1 {
                skip_wideband_layer(reader)?;
                // The decoder reads this flag without checking that a bit is left; running
                // out here is its normal end of an ultra-wideband packet, not an error.
                match reader.read(1) {
                    Err(_) => return Ok(None),
                    Ok(1) => return Err(Problem::TooManyWidebandLayers),
                    Ok(_) => {}
                }
            }
        }
        if reader.remaining() < 4 {
            return Ok(None);
        }
        match reader.read(4)? {
            MODE_TERMINATOR => return Ok(None),
            MODE_INBAND_REQUEST => {
                let code = reader.read(4)?;
                reader.skip(inband_request_bits(code))?;
            }
            MODE_USER_MESSAGE => {
                // The reference decoder's default handler reads a 4-bit length and then skips
                // 5 + 8 * length bits (not the 5-bit length of the format description).
                // Following it keeps the walker in step with the decoder next to it.
                let length = reader.read(4)? as usize;
                reader.skip(5 + 8 * length)?;
            }
            mode @ 0..=8 => return read_frame(reader, mode as u8, held).map(Some),
            mode => return Err(Problem::InvalidMode(mode as u8)),
        }
    }
}

/// Steps over a wideband layer whose flag bit has just been read.
fn skip_wideband_layer(reader: &mut BitReader<'_>) -> Result<(), Problem> {
    let submode = reader.read(3)? as usize;
    let layer_bits = WIDEBAND_LAYER_BITS[submode];
    if layer_bits == 0 {
        // The decoder's skip table has no size for these; stepping back over the submode it
        // re-reads the same layer until it sees "more than two layers". Either way: corrupt.
        return Err(Problem::InvalidWidebandSubmode(submode as u8));
    }
    reader.skip(layer_bits - 4)
}

/// Payload bits of an in-band request the decoder has no handler for, by request code.
fn inband_request_bits(code: u32) -> usize {
    match code {
        0..=1 => 1,
        2..=7 => 4,
        8..=9 => 8,
        10..=11 => 16,
        12..=13 => 32,
        _ => 64,
    }
}

/// Reads the frame body after a header of mode 0..=8.
fn read_frame(
    reader: &mut BitReader<'_>,
    mode: u8,
    held: &mut Option<Lsp>,
) -> Result<Frame, Problem> {
    let body_bits = FRAME_BITS[usize::from(mode)] - HEADER_BITS;
    // Check the whole frame up front: the decoder would otherwise decode zeros past the end.
    if reader.remaining() < body_bits {
        return Err(Problem::Overrun {
            needed: body_bits,
            remaining: reader.remaining(),
        });
    }
    if mode == 0 {
        return Ok(Frame::Silence { held_lsp: *held });
    }
    let (lsp, lsp_bits) = if (5..=7).contains(&mode) {
        let mut index = [0; 5];
        for i in &mut index {
            *i = reader.read(6)? as usize;
        }
        (lsp_30_bit(index), 30)
    } else {
        let mut index = [0; 3];
        for i in &mut index {
            *i = reader.read(6)? as usize;
        }
        (lsp_18_bit(index), 18)
    };
    reader.skip(body_bits - lsp_bits)?;
    *held = Some(lsp);
    Ok(Frame::Speech { mode, lsp })
}

// The float decoder's scale factors: rounded decimal literals, not exact powers of two.
const DIV_256: f64 = 0.0039062;
const DIV_512: f64 = 0.0019531;
const DIV_1024: f64 = 0.00097656;

/// The decoder's starting point before any codebook stage: 0.25 * (i + 1) radians.
fn lsp_base() -> Lsp {
    std::array::from_fn(|i| (0.25 * i as f64 + 0.25) as f32)
}

/// Adds one codebook stage. In C the LSP is a float but the scaled entry is a double, so the
/// sum is formed in double and rounded to float on assignment; f32 arithmetic would differ.
fn add_stage(lsp: &mut [f32], entry: &[i8], scale: f64) {
    for (value, &step) in lsp.iter_mut().zip(entry) {
        *value = (f64::from(*value) + scale * f64::from(step)) as f32;
    }
}

/// Dequantises the 18-bit LSP code of modes 1-4 and 8. Indices are taken modulo 64.
fn lsp_18_bit(index: [usize; 3]) -> Lsp {
    let mut lsp = lsp_base();
    add_stage(&mut lsp, &CDBK_NB[index[0] % 64], DIV_256);
    add_stage(&mut lsp[..5], &CDBK_NB_LOW1[index[1] % 64], DIV_512);
    add_stage(&mut lsp[5..], &CDBK_NB_HIGH1[index[2] % 64], DIV_512);
    lsp
}

/// Dequantises the 30-bit LSP code of modes 5-7. Indices are taken modulo 64.
fn lsp_30_bit(index: [usize; 5]) -> Lsp {
    let mut lsp = lsp_base();
    add_stage(&mut lsp, &CDBK_NB[index[0] % 64], DIV_256);
    add_stage(&mut lsp[..5], &CDBK_NB_LOW1[index[1] % 64], DIV_512);
    add_stage(&mut lsp[..5], &CDBK_NB_LOW2[index[2] % 64], DIV_1024);
    add_stage(&mut lsp[5..], &CDBK_NB_HIGH1[index[3] % 64], DIV_512);
    add_stage(&mut lsp[5..], &CDBK_NB_HIGH2[index[4] % 64], DIV_1024);
    lsp
}

/// Reads a byte slice as a big-endian bit string, most significant bit of each byte first.
#[derive(Debug, Clone)]
struct BitReader<'a> {
    data: &'a [u8],
    /// Position in bits from the start of `data`.
    pos: usize,
    /// Length in bits.
    len: usize,
}

impl<'a> BitReader<'a> {
    fn new(data: &'a [u8]) -> Self {
        Self {
            data,
            pos: 0,
            len: data.len().saturating_mul(8),
        }
    }

    fn remaining(&self) -> usize {
        self.len - self.pos
    }

    fn overrun(&self, needed: usize) -> Problem {
        Problem::Overrun {
            needed,
            remaining: self.remaining(),
        }
    }

    /// Reads `count` bits (at most 32) as an unsigned number.
    fn read(&mut self, count: u32) -> Result<u32, Problem> {
        debug_assert!(count <= 32);
        let wanted = count as usize;
        if wanted > self.remaining() {
            return Err(self.overrun(wanted));
        }
        let mut value: u64 = 0;
        let mut left = count;
        while left > 0 {
            let byte = *self
                .data
                .get(self.pos / 8)
                .ok_or_else(|| self.overrun(wanted))?;
            let unread_in_byte = 8 - (self.pos % 8) as u32;
            let take = unread_in_byte.min(left);
            let bits = (u32::from(byte) >> (unread_in_byte - take)) & ((1 << take) - 1);
            value = (value << take) | u64::from(bits);
            self.pos += take as usize;
            left -= take;
        }
        Ok(value as u32)
    }

    fn skip(&mut self, count: usize) -> Result<(), Problem> {
        if count > self.remaining() {
            return Err(self.overrun(count));
        }
        self.pos += count;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f32::consts::PI;

    /// Packs (value, bit count) pairs MSB-first, padding the last byte like
    /// `speex_bits_insert_terminator`: a zero, then ones.
    fn pack(fields: &[(u32, u32)]) -> Vec<u8> {
        let mut bits = Vec::new();
        for &(value, count) in fields {
            for i in (0..count).rev() {
                bits.push((value >> i) & 1 == 1);
            }
        }
        if bits.len() % 8 != 0 {
            bits.push(false);
            while bits.len() % 8 != 0 {
                bits.push(true);
            }
        }
        bits.chunks(8)
            .map(|c| c.iter().fold(0u8, |acc, &b| (acc << 1) | u8::from(b)))
            .collect()
    }

    /// A frame header plus LSP indices, with the rest of the frame's bits zero.
    fn frame_fields(mode: u32, index: &[u32]) -> Vec<(u32, u32)> {
        let mut fields = vec![(0, 1), (mode, 4)];
        fields.extend(index.iter().map(|&i| (i, 6)));
        let mut rest = FRAME_BITS[mode as usize] - HEADER_BITS - 6 * index.len();
        while rest > 0 {
            let n = rest.min(32);
            fields.push((0, n as u32));
            rest -= n;
        }
        fields
    }

    fn assert_ordered(lsp: &[f32], what: &str) {
        assert!(lsp[0] > 0.0, "{what}: {lsp:?}");
        assert!(*lsp.last().unwrap() < PI, "{what}: {lsp:?}");
        assert!(lsp.windows(2).all(|w| w[0] < w[1]), "{what}: {lsp:?}");
    }

    #[test]
    fn bit_reader_reads_msb_first_across_bytes() {
        let data = [0b1011_0010, 0b0111_1111, 0xA5, 0x5A, 0xFF];
        let mut r = BitReader::new(&data);
        assert_eq!(r.read(1), Ok(1));
        assert_eq!(r.read(3), Ok(0b011));
        assert_eq!(r.read(6), Ok(0b00_1001));
        assert_eq!(r.remaining(), 30);
        r.skip(6).unwrap();
        assert_eq!(r.read(24), Ok(0xA55AFF));
        assert_eq!(r.remaining(), 0);
        assert_eq!(
            r.read(1),
            Err(Problem::Overrun {
                needed: 1,
                remaining: 0
            })
        );
    }

    #[test]
    fn bit_reader_refuses_overruns_without_moving() {
        let mut r = BitReader::new(&[0xFF, 0x00]);
        assert_eq!(r.read(32), Err(r.overrun(32)));
        assert_eq!(r.skip(17), Err(r.overrun(17)));
        assert_eq!(r.read(16), Ok(0xFF00));
        assert!(r.read(1).is_err());
        let mut empty = BitReader::new(&[]);
        assert_eq!(empty.remaining(), 0);
        assert!(empty.read(1).is_err());
        assert_eq!(empty.read(0), Ok(0));
        assert_eq!(empty.skip(0), Ok(()));
    }

    #[test]
    fn bit_reader_reads_32_bits() {
        let mut r = BitReader::new(&[0x80, 0, 0, 1, 0xC0]);
        r.skip(0).unwrap();
        assert_eq!(r.read(32), Ok(0x8000_0001));
        assert_eq!(r.read(2), Ok(3));
    }

    #[test]
    fn codebooks_have_the_reference_sizes() {
        assert_eq!(CDBK_NB.len() * CDBK_NB[0].len(), 640);
        for table in [&CDBK_NB_LOW1, &CDBK_NB_LOW2, &CDBK_NB_HIGH1, &CDBK_NB_HIGH2] {
            assert_eq!(table.len() * table[0].len(), 320);
        }
        // Spot checks against lsp_tables_nb.c.
        assert_eq!(CDBK_NB[0][0], 30);
        assert_eq!(CDBK_NB[1][..2], [5, -18]);
        assert_eq!(CDBK_NB_LOW1[1], [23, 21, 52, 24, -33]);
    }

    #[test]
    fn frame_sizes_add_up() {
        // Header + LSP code + the rest; the 18-bit code fits even in mode 1's 43 bits.
        for (mode, &bits) in FRAME_BITS.iter().enumerate().skip(1) {
            let lsp_bits = if (5..=7).contains(&mode) { 30 } else { 18 };
            assert!(bits >= HEADER_BITS + lsp_bits, "mode {mode}");
        }
    }

    fn is_ordered(lsp: &[f32]) -> bool {
        lsp.windows(2).all(|w| w[0] < w[1])
    }

    #[test]
    fn first_stage_codes_are_ordered() {
        for (a, entry) in CDBK_NB.iter().enumerate() {
            let mut lsp = lsp_base();
            add_stage(&mut lsp, entry, DIV_256);
            assert_ordered(&lsp, &format!("first stage {a}"));
        }
    }

    // Not every code yields ordered LSPs: the decoder stores them as dequantised and only
    // enforces its margins on the per-subframe interpolated copies. The counts below pin the
    // codebooks (a transcription slip would move them) and document how often it happens.

    #[test]
    fn every_18_bit_code_is_in_range_and_few_are_unordered() {
        let mut unordered = 0;
        for a in 0..64 {
            for b in 0..64 {
                for c in 0..64 {
                    let lsp = lsp_18_bit([a, b, c]);
                    assert!(lsp[0] > 0.0 && lsp[9] < PI, "{a} {b} {c}: {lsp:?}");
                    unordered += usize::from(!is_ordered(&lsp));
                }
            }
        }
        assert_eq!(unordered, 4424, "of 262144 codes");
    }

    #[test]
    fn every_30_bit_code_half_is_counted() {
        // After the first stage the low and high halves depend on disjoint indices, so
        // 2 x 64^3 halves cover all 64^5 codes.
        let (mut low_unordered, mut high_unordered, mut low_not_positive) = (0, 0, 0);
        for a in 0..64 {
            for b in 0..64 {
                for c in 0..64 {
                    let low = lsp_30_bit([a, b, c, 0, 0]);
                    let high = lsp_30_bit([a, 0, 0, b, c]);
                    assert_eq!(low[5..], lsp_30_bit([a, 0, 0, 0, 0])[5..]);
                    assert!(high[9] < PI, "{a} {b} {c}: {high:?}");
                    low_unordered += usize::from(!is_ordered(&low[..5]));
                    high_unordered += usize::from(!is_ordered(&high[5..]));
                    low_not_positive += usize::from(low[0] <= 0.0);
                }
            }
        }
        assert_eq!(
            (low_unordered, high_unordered, low_not_positive),
            (4321, 671, 223),
            "of 262144 halves each"
        );
    }

    #[test]
    fn lsp_arithmetic_matches_the_float_decoder() {
        // By hand: base 0.25, entry 30 of cdbk_nb at 0.0039062 each, in double, then float.
        let lsp = lsp_18_bit([0, 0, 0]);
        let first = ((0.25f64 + 0.0039062 * 30.0) as f32 as f64 + 0.0019531 * -34.0) as f32;
        assert_eq!(CDBK_NB_LOW1[0][0], -34, "table transcription changed");
        // Plain f32 arithmetic would give a different float for this very code.
        let in_f32 = (0.25f32 + 0.0039062f32 * 30.0) + 0.0019531f32 * -34.0;
        assert_ne!(lsp[0], in_f32);
        assert_eq!(lsp[0], first);
    }

    #[test]
    fn walks_every_mode_in_one_packet() {
        let mut fields = Vec::new();
        for mode in [1, 8, 2, 3, 4, 5, 6, 7, 0] {
            let index: &[u32] = if (5..=7).contains(&mode) {
                &[1, 2, 3, 4, 5]
            } else if mode == 0 {
                &[]
            } else {
                &[6, 7, 8]
            };
            fields.extend(frame_fields(mode, index));
        }
        let packet = pack(&fields);
        let mut walker = Walker::new();
        let frames = walker.walk_packet(&packet).unwrap();
        let modes: Vec<u8> = frames.iter().map(Frame::mode).collect();
        assert_eq!(modes, [1, 8, 2, 3, 4, 5, 6, 7, 0]);
        assert_eq!(frames[0].lsp(), Some(&lsp_18_bit([6, 7, 8])));
        assert_eq!(frames[5].lsp(), Some(&lsp_30_bit([1, 2, 3, 4, 5])));
        assert_eq!(
            frames[8],
            Frame::Silence {
                held_lsp: Some(lsp_30_bit([1, 2, 3, 4, 5]))
            }
        );
        assert_eq!(walker.held_lsp(), Some(&lsp_30_bit([1, 2, 3, 4, 5])));
    }

    #[test]
    fn silence_before_speech_holds_nothing_and_state_carries_over() {
        let mut walker = Walker::new();
        let silence = pack(&frame_fields(0, &[]));
        assert_eq!(
            walker.walk_packet(&silence).unwrap(),
            [Frame::Silence { held_lsp: None }]
        );
        let speech = pack(&frame_fields(3, &[10, 20, 30]));
        walker.walk_packet(&speech).unwrap();
        assert_eq!(
            walker.walk_packet(&silence).unwrap(),
            [Frame::Silence {
                held_lsp: Some(lsp_18_bit([10, 20, 30]))
            }]
        );
        walker.reset();
        assert_eq!(walker.held_lsp(), None);
    }

    #[test]
    fn end_of_packet_rules() {
        let mut walker = Walker::new();
        assert_eq!(walker.walk_packet(&[]).unwrap(), []);
        // Fewer than five bits left is the end, whatever they are.
        let mut fields = frame_fields(5, &[0; 5]);
        fields.push((0b1111, 4));
        let packet = pack(&fields);
        assert_eq!(packet.len() * 8, 304);
        assert_eq!(walker.walk_packet(&packet).unwrap().len(), 1);
        // A terminator stops the walk even with frames after it.
        let mut fields = vec![(0, 1), (15, 4)];
        fields.extend(frame_fields(1, &[0, 0, 0]));
        assert_eq!(walker.walk_packet(&pack(&fields)).unwrap(), []);
        // Five zero bits of padding are a mode-0 frame, to the decoder as well.
        assert_eq!(walker.walk_packet(&[0]).unwrap().len(), 1);
        // One byte of all ones: wideband flag, submode 7: corrupt.
        assert!(matches!(
            walker.walk_packet(&[0xFF]),
            Err(BitstreamError::InvalidWidebandSubmode {
                frame: 0,
                submode: 7
            })
        ));
    }

    #[test]
    fn skips_inband_requests_user_messages_and_wideband_layers() {
        let mut fields = Vec::new();
        // In-band request 9 (8-bit payload), then request 15 (64 bits).
        fields.extend([(0, 1), (14, 4), (9, 4), (0xAB, 8)]);
        fields.extend([(0, 1), (14, 4), (15, 4), (u32::MAX, 32), (u32::MAX, 32)]);
        // User message with length field 2: 5 + 16 more bits.
        fields.extend([(0, 1), (13, 4), (2, 4), (0x1F, 5), (0xFFFF, 16)]);
        fields.extend(frame_fields(2, &[1, 1, 1]));
        // Two wideband layers (submodes 1 and 4), then a frame.
        fields.extend([(1, 1), (1, 3), (u32::MAX, 32)]);
        fields.extend([(1, 1), (4, 3)]);
        for _ in 0..10 {
            fields.push((u32::MAX, 32));
        }
        fields.push((u32::MAX, 28));
        fields.extend(frame_fields(6, &[2, 2, 2, 2, 2]));
        let packet = pack(&fields);
        let frames = Walker::new().walk_packet(&packet).unwrap();
        assert_eq!(frames.iter().map(Frame::mode).collect::<Vec<_>>(), [2, 6]);
        assert_eq!(frames[1].lsp(), Some(&lsp_30_bit([2; 5])));
    }

    #[test]
    fn wideband_layers_at_the_end_are_the_end() {
        let mut fields = frame_fields(1, &[0, 0, 0]);
        fields.extend([(1, 1), (1, 3), (0, 32)]);
        assert_eq!(Walker::new().walk_packet(&pack(&fields)).unwrap().len(), 1);
        // Two layers filling the packet exactly: the third flag is missing, not an error.
        let packet = pack(&[(1, 1), (1, 3), (0, 32), (1, 1), (1, 3), (0, 32)]);
        assert_eq!(packet.len() * 8, 72);
        assert_eq!(Walker::new().walk_packet(&packet).unwrap(), []);
        let exact = pack(&[(1, 1), (1, 3), (0, 32), (1, 1), (1, 3), (0, 32), (0xFF, 8)]);
        assert_eq!(exact.len(), 10);
        assert_eq!(
            Walker::new().walk_packet(&exact),
            Err(BitstreamError::TooManyWidebandLayers { frame: 0 })
        );
    }

    #[test]
    fn invalid_modes_are_errors() {
        for mode in 9..=12 {
            let mut fields = frame_fields(1, &[0, 0, 0]);
            fields.extend([(0, 1), (mode, 4), (0, 8)]);
            assert_eq!(
                Walker::new().walk_packet(&pack(&fields)),
                Err(BitstreamError::InvalidMode {
                    frame: 1,
                    mode: mode as u8
                })
            );
        }
    }

    #[test]
    fn truncated_packets_are_errors() {
        for mode in 1..=8u32 {
            let index: &[u32] = if (5..=7).contains(&mode) {
                &[0; 5]
            } else {
                &[0; 3]
            };
            let packet = pack(&frame_fields(mode, index));
            let bits = FRAME_BITS[mode as usize];
            assert_eq!(packet.len(), bits.div_ceil(8));
            assert_eq!(Walker::new().walk_packet(&packet[..0]), Ok(vec![]));
            for cut in 1..packet.len() {
                assert_eq!(
                    Walker::new().walk_packet(&packet[..cut]),
                    Err(BitstreamError::Truncated {
                        frame: 0,
                        needed: bits - HEADER_BITS,
                        remaining: cut * 8 - HEADER_BITS
                    }),
                    "mode {mode}, {cut} bytes"
                );
            }
        }
        // Truncated in-band request payload and user message.
        let request = pack(&[(0, 1), (14, 4), (15, 4), (0, 20)]);
        assert!(matches!(
            Walker::new().walk_packet(&request),
            Err(BitstreamError::Truncated { needed: 64, .. })
        ));
        let message = pack(&[(0, 1), (13, 4), (15, 4), (0, 30)]);
        assert!(matches!(
            Walker::new().walk_packet(&message),
            Err(BitstreamError::Truncated { needed: 125, .. })
        ));
        // Truncated wideband layer.
        let layer = pack(&[(1, 1), (4, 3), (0, 30)]);
        assert!(matches!(
            Walker::new().walk_packet(&layer),
            Err(BitstreamError::Truncated { needed: 348, .. })
        ));
    }

    #[test]
    fn frames_iterator_stops_after_an_error_but_keeps_earlier_frames() {
        let mut fields = frame_fields(3, &[5, 6, 7]);
        fields.extend([(0, 1), (10, 4), (0, 3)]);
        let packet = pack(&fields);
        let mut walker = Walker::new();
        let mut frames = walker.frames(&packet);
        assert_eq!(frames.next().map(|f| f.map(|f| f.mode())), Some(Ok(3)));
        assert_eq!(
            frames.next(),
            Some(Err(BitstreamError::InvalidMode { frame: 1, mode: 10 }))
        );
        assert_eq!(frames.next(), None);
        assert_eq!(walker.held_lsp(), Some(&lsp_18_bit([5, 6, 7])));
        assert_eq!(
            BitstreamError::TooManyWidebandLayers { frame: 4 }.frame(),
            4
        );
    }

    /// A random valid frame: (mode, LSP indices).
    fn arb_frame() -> impl proptest::strategy::Strategy<Value = (u32, Vec<u32>)> {
        use proptest::prelude::*;
        (0u32..=8).prop_flat_map(|mode| {
            let count = match mode {
                0 => 0,
                5..=7 => 5,
                _ => 3,
            };
            (Just(mode), prop::collection::vec(0u32..64, count))
        })
    }

    proptest::proptest! {
        #[test]
        fn random_bytes_never_panic(packet in proptest::collection::vec(proptest::num::u8::ANY, 0..300)) {
            let mut walker = Walker::new();
            let frames = walker.frames(&packet).count();
            // Every frame takes at least five bits.
            proptest::prop_assert!(frames <= packet.len() * 8 / 5);
        }

        #[test]
        fn valid_packets_walk_and_mutated_ones_do_not_panic(
            frames in proptest::collection::vec(arb_frame(), 0..8),
            flips in proptest::collection::vec(proptest::num::usize::ANY, 0..4),
            cut in proptest::num::usize::ANY,
        ) {
            let fields: Vec<_> = frames.iter().flat_map(|(m, i)| frame_fields(*m, i)).collect();
            let packet = pack(&fields);
            let walked = Walker::new().walk_packet(&packet).unwrap();
            let modes: Vec<u32> = walked.iter().map(|f| u32::from(f.mode())).collect();
            let expected: Vec<u32> = frames.iter().map(|(m, _)| *m).collect();
            proptest::prop_assert_eq!(modes, expected);

            let mut mutated = packet.clone();
            if !mutated.is_empty() {
                for flip in flips {
                    let bit = flip % (mutated.len() * 8);
                    mutated[bit / 8] ^= 0x80 >> (bit % 8);
                }
                mutated.truncate(cut % (mutated.len() + 1));
            }
            let _ = Walker::new().walk_packet(&mutated);
        }
    }
}
