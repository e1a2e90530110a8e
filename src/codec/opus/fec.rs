//! Whether an Opus packet carries in-band FEC: SILK's LBRR copy of the frame before it, flagged
//! in the first range-coded bits of the packet's first frame (RFC 6716 4.2.3 and 4.2.4).
//!
//! libopus, asked to recover a lost frame from the next packet, quietly conceals when that packet
//! carries no FEC. A receiver that counts recovered frames apart from concealed ones, and feeds
//! them to the features as decoded audio, asks here first.

use super::codec::MAX_INPUT_PACKET_BYTES;

/// The first configurations of the TOC byte that are CELT-only (RFC 6716 3.1): no SILK layer.
const FIRST_CELT_CONFIG: u8 = 16;
/// Hybrid configurations: SILK (in 10 or 20 ms frames) under CELT.
const FIRST_HYBRID_CONFIG: u8 = 12;

/// Just enough of the range decoder (RFC 6716 4.1) to read the header's one-bit flags.
struct Flags<'a> {
    data: &'a [u8],
    pos: usize,
    rem: u32,
    rng: u32,
    val: u32,
}

impl<'a> Flags<'a> {
    fn new(data: &'a [u8]) -> Self {
        let mut d = Self {
            data,
            pos: 0,
            rem: 0,
            rng: 128,
            val: 0,
        };
        d.rem = d.byte();
        d.val = d.rng - 1 - (d.rem >> 1);
        d.normalize();
        d
    }

    /// Bytes past the end read as zeros, as in libopus.
    fn byte(&mut self) -> u32 {
        let b = self.data.get(self.pos).copied().unwrap_or(0);
        self.pos += 1;
        u32::from(b)
    }

    fn normalize(&mut self) {
        while self.rng <= 1 << 23 {
            self.rng <<= 8;
            let sym = self.rem;
            self.rem = self.byte();
            let sym = ((sym << 8) | self.rem) >> 1;
            self.val = ((self.val << 8) + (255 & !sym)) & 0x7FFF_FFFF;
        }
    }

    /// A bit coded with probability one half (`ec_dec_bit_logp(_, 1)`).
    fn bit(&mut self) -> bool {
        let s = self.rng >> 1;
        let one = self.val < s;
        if one {
            self.rng = s;
        } else {
            self.val -= s;
            self.rng -= s;
        }
        self.normalize();
        one
    }
}

/// True when the packet's first frame carries an LBRR (FEC) copy of the previous frame for its
/// first (mid) channel. Anything that is no valid SILK or hybrid packet carries none.
pub fn carries_fec(packet: &[u8]) -> bool {
    if packet.len() > MAX_INPUT_PACKET_BYTES {
        return false;
    }
    let Ok(parsed) = opus::packet::parse(packet) else {
        return false;
    };
    let config = parsed.toc >> 3;
    if config >= FIRST_CELT_CONFIG {
        return false;
    }
    let Some(&frame) = parsed.frames.first() else {
        return false;
    };
    if frame.is_empty() {
        return false;
    }
    // One SILK frame per 10 or 20 ms Opus frame, two for 40 ms, three for 60 ms.
    let silk_frames = if config >= FIRST_HYBRID_CONFIG {
        1
    } else {
        match config & 3 {
            0 | 1 => 1,
            2 => 2,
            _ => 3,
        }
    };
    let mut flags = Flags::new(frame);
    // The mid channel's VAD flags, then its LBRR flag.
    for _ in 0..silk_frames {
        flags.bit();
    }
    flags.bit()
}

#[cfg(test)]
mod tests {
    use super::super::codec::{Decoder, Encoder, EncoderConfig, MAX_PACKET_BYTES};
    use super::*;

    fn speech_packets(config: EncoderConfig) -> Vec<Vec<u8>> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/speech/demo.wav");
        let pcm = crate::audio::wav::read_narrowband(&path).unwrap();
        let mut enc = Encoder::new(config).unwrap();
        let mut out = [0u8; MAX_PACKET_BYTES];
        pcm.chunks_exact(160)
            .take(250)
            .map(|f| {
                let n = enc.encode_frame(f, &mut out).unwrap();
                out[..n].to_vec()
            })
            .collect()
    }

    /// libopus itself is the judge: recovering frame i-1 from packet i gives something else
    /// than concealing it exactly when packet i carries FEC.
    #[test]
    fn the_flag_says_what_libopus_recovers() {
        let packets = speech_packets(EncoderConfig {
            bitrate: 20_000,
            fec: true,
            loss_percent: 10,
            ..Default::default()
        });
        let mut flagged = 0;
        for i in 1..packets.len() {
            let mut a = Decoder::new().unwrap();
            let mut b = Decoder::new().unwrap();
            let mut scratch = [0i16; 160];
            for p in &packets[..i - 1] {
                a.decode(p, &mut scratch).unwrap();
                b.decode(p, &mut scratch).unwrap();
            }
            let (mut fec, mut plc) = ([0i16; 160], [0i16; 160]);
            a.decode_fec(&packets[i], &mut fec).unwrap();
            b.conceal(&mut plc).unwrap();
            assert_eq!(carries_fec(&packets[i]), fec != plc, "packet {i}");
            flagged += usize::from(carries_fec(&packets[i]));
        }
        // Speech is mostly active; silent stretches get no FEC.
        assert!(
            flagged > packets.len() / 2,
            "{flagged} of {}",
            packets.len()
        );
        let without = speech_packets(EncoderConfig {
            bitrate: 20_000,
            ..Default::default()
        });
        assert_eq!(without.iter().filter(|p| carries_fec(p)).count(), 0);
    }

    #[test]
    fn no_fec_in_what_is_not_silk() {
        assert!(!carries_fec(&[]));
        assert!(!carries_fec(&[0x08]));
        // CELT-only fullband 20 ms, however its bytes look.
        assert!(!carries_fec(&[31 << 3, 0xff, 0xff, 0xff]));
        // Code 3 with a frame count of zero is no packet.
        assert!(!carries_fec(&[0x03, 0x00]));
    }
}
