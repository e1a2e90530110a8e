//! G.711 mu-law (PCMU) and A-law (PCMA): sample companding at 8 kHz, no bitstream features.
//!
//! ITU-T G.711 in arithmetic form, table-free: mu-law codes the top 14 bits of a sample,
//! A-law the top 13, each as sign, 3-bit segment (octave) and 4-bit mantissa, with the
//! transmitted bits inverted (mu-law) or every other bit inverted (A-law, mask 0x55).
//! G.711 itself starts from 14- or 13-bit samples; how 16-bit samples lose their low bits is
//! the implementation's choice. We round to the nearest 14/13-bit value, as sox does (then
//! Sun's g711.c segments, which sox uses): bit-exact with sox for all 65536 inputs and all
//! codes (tests/g711.rs). GStreamer's encoders truncate the magnitude instead and pick the
//! neighbouring code for 383 of the 65536 inputs (mu-law) and 1147 (A-law); every decoder
//! agrees.

use crate::vocab::FRAME_SIZE;

/// Mu-law bias (33 in 14-bit units): makes the segments start at powers of two.
const ULAW_BIAS: i32 = 0x21;
/// Largest 14-bit magnitude before the bias that still fits the top segment.
const ULAW_CLIP: i32 = 8159;

/// Encodes one 16-bit sample as a mu-law byte.
pub fn linear_to_ulaw(sample: i16) -> u8 {
    let value = ((i32::from(sample) + 2) >> 2).min(0x1FFF);
    let (magnitude, mask) = if value < 0 {
        (-value, 0x7F)
    } else {
        (value, 0xFF)
    };
    let biased = magnitude.min(ULAW_CLIP) + ULAW_BIAS;
    // Segment: the octave of the biased magnitude, 0 for 33..=63 up to 7 for 4096..=8191;
    // the clipped top (8192) takes the largest code.
    let segment = (32 - biased.leading_zeros() as i32 - 6).max(0);
    if segment > 7 {
        return (0x7F ^ mask) as u8;
    }
    let mantissa = (biased >> (segment + 1)) & 0x0F;
    (((segment << 4) | mantissa) ^ mask) as u8
}

/// Decodes a mu-law byte to a 16-bit sample (at most +-32124).
pub fn ulaw_to_linear(code: u8) -> i16 {
    let code = i32::from(!code);
    let segment = (code >> 4) & 0x07;
    let magnitude = ((((code & 0x0F) << 3) + 0x84) << segment) - 0x84;
    (if code & 0x80 != 0 {
        -magnitude
    } else {
        magnitude
    }) as i16
}

/// Encodes one 16-bit sample as an A-law byte.
pub fn linear_to_alaw(sample: i16) -> u8 {
    let value = ((i32::from(sample) + 4) >> 3).min(0x0FFF);
    // Negative values are coded from their one's complement: -1 shares code 0 with 0.
    let (magnitude, mask) = if value >= 0 {
        (value, 0xD5)
    } else {
        (-value - 1, 0x55)
    };
    // Segments 0 and 1 share the finest step (2 units), then one octave each, 7 ending at 4095.
    let octave = 32 - magnitude.leading_zeros() as i32;
    let code = match octave {
        0..=5 => (magnitude >> 1) & 0x0F,
        6 => (1 << 4) | ((magnitude >> 1) & 0x0F),
        7..=12 => {
            let segment = octave - 5;
            (segment << 4) | ((magnitude >> segment) & 0x0F)
        }
        _ => 0x7F,
    };
    (code ^ mask) as u8
}

/// Decodes an A-law byte to a 16-bit sample (at most +-32256).
pub fn alaw_to_linear(code: u8) -> i16 {
    let code = i32::from(code ^ 0x55);
    let segment = (code >> 4) & 0x07;
    let step = (code & 0x0F) << 4;
    let magnitude = match segment {
        0 => step + 8,
        s => (step + 0x108) << (s - 1),
    };
    (if code & 0x80 != 0 {
        magnitude
    } else {
        -magnitude
    }) as i16
}

/// The two companding laws, with their static RTP payload types (RFC 3551).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Law {
    /// Mu-law, PCMU, RTP payload type 0 (North America, Japan).
    Mu,
    /// A-law, PCMA, RTP payload type 8 (elsewhere).
    A,
}

impl Law {
    pub const fn payload_type(self) -> u8 {
        match self {
            Law::Mu => 0,
            Law::A => 8,
        }
    }

    /// The encoding name in SDP and RTP terms.
    pub const fn name(self) -> &'static str {
        match self {
            Law::Mu => "PCMU",
            Law::A => "PCMA",
        }
    }

    pub fn encode_sample(self, sample: i16) -> u8 {
        match self {
            Law::Mu => linear_to_ulaw(sample),
            Law::A => linear_to_alaw(sample),
        }
    }

    pub fn decode_sample(self, code: u8) -> i16 {
        match self {
            Law::Mu => ulaw_to_linear(code),
            Law::A => alaw_to_linear(code),
        }
    }

    /// Encodes one 20 ms frame (one byte per sample).
    pub fn encode_frame(self, pcm: &[i16; FRAME_SIZE]) -> [u8; FRAME_SIZE] {
        pcm.map(|s| self.encode_sample(s))
    }

    /// Decodes one 20 ms frame.
    pub fn decode_frame(self, payload: &[u8; FRAME_SIZE]) -> [i16; FRAME_SIZE] {
        payload.map(|c| self.decode_sample(c))
    }

    /// Decodes any number of bytes into `out`, as many as both hold; returns that count.
    pub fn decode_into(self, payload: &[u8], out: &mut [i16]) -> usize {
        for (o, &c) in out.iter_mut().zip(payload) {
            *o = self.decode_sample(c);
        }
        payload.len().min(out.len())
    }

    /// Encodes any number of samples into `out`, as many as both hold; returns that count.
    pub fn encode_into(self, pcm: &[i16], out: &mut [u8]) -> usize {
        for (o, &s) in out.iter_mut().zip(pcm) {
            *o = self.encode_sample(s);
        }
        pcm.len().min(out.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_code_survives_decode_then_encode() {
        for code in 0..=255u8 {
            assert_eq!(
                linear_to_ulaw(ulaw_to_linear(code)),
                code | u8::from(code == 0x7F) << 7
            );
            // A-law has no negative zero: every code is its own.
            assert_eq!(linear_to_alaw(alaw_to_linear(code)), code);
        }
    }

    #[test]
    fn known_values() {
        assert_eq!(linear_to_ulaw(0), 0xFF);
        assert_eq!(linear_to_ulaw(-2), 0xFF);
        assert_eq!(linear_to_ulaw(-3), 0x7E);
        assert_eq!(linear_to_ulaw(i16::MAX), 0x80);
        assert_eq!(linear_to_ulaw(i16::MIN), 0x00);
        assert_eq!(ulaw_to_linear(0x80), 32124);
        assert_eq!(ulaw_to_linear(0x00), -32124);
        assert_eq!(linear_to_alaw(0), 0xD5);
        assert_eq!(linear_to_alaw(-4), 0xD5);
        assert_eq!(linear_to_alaw(-5), 0x55);
        assert_eq!(alaw_to_linear(0xD5), 8);
        assert_eq!(alaw_to_linear(0xAA), 32256);
        assert_eq!(alaw_to_linear(0x2A), -32256);
    }

    #[test]
    fn companding_error_is_within_half_a_step() {
        for s in i16::MIN..=i16::MAX {
            for (law, bits) in [(Law::Mu, 14), (Law::A, 13)] {
                let back = law.decode_sample(law.encode_sample(s));
                // The step of the segment a sample falls in is at most 1/16 of its magnitude
                // plus the finest step; clipping aside, the error stays under one step.
                let magnitude = i32::from(s).unsigned_abs() as f64;
                let finest = f64::from(1 << (16 - bits)) * 2.0;
                let bound = magnitude / 16.0 + finest;
                let error = (i32::from(back) - i32::from(s)).unsigned_abs() as f64;
                if magnitude < 32000.0 {
                    assert!(error <= bound, "{law:?} {s} -> {back}");
                }
            }
        }
    }
}
