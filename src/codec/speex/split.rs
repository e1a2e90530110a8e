//! Splitting a multi-frame Speex packet into one packet per frame without decoding it, so that
//! receivers that decode only a packet's first frame (GStreamer's speexdec) hear everything,
//! and counting a packet's frames, so that a receiver knows how long it lasts.
//!
//! Narrowband frames are packed back to back; each opens with a wideband flag and a 4-bit mode
//! whose frame length is fixed. Packets with wideband layers or in-band messages are left whole.

/// Bits of a narrowband frame, header included, indexed by mode (design brief's table).
const FRAME_BITS: [usize; 9] = [5, 43, 119, 160, 220, 300, 364, 492, 79];
const TERMINATOR: u32 = 15;

struct Bits<'a> {
    data: &'a [u8],
    pos: usize,
}

impl Bits<'_> {
    fn remaining(&self) -> usize {
        (self.data.len() * 8).saturating_sub(self.pos)
    }

    fn peek(&self, n: usize) -> Option<u32> {
        if n > self.remaining() {
            return None;
        }
        let mut v = 0u32;
        for i in 0..n {
            let bit = self.pos + i;
            v = (v << 1) | u32::from((self.data[bit / 8] >> (7 - bit % 8)) & 1);
        }
        Some(v)
    }
}

fn copy_bits(src: &[u8], start: usize, len: usize, out: &mut Vec<u8>) {
    out.clear();
    let mut acc = 0u8;
    let mut filled = 0;
    for i in 0..len {
        let bit = start + i;
        acc = (acc << 1) | ((src[bit / 8] >> (7 - bit % 8)) & 1);
        filled += 1;
        if filled == 8 {
            out.push(acc);
            acc = 0;
            filled = 0;
        }
    }
    // Speex's terminator padding: a 0 bit, then 1s up to the byte boundary.
    if filled > 0 {
        acc <<= 1;
        filled += 1;
        while filled < 8 {
            acc = (acc << 1) | 1;
            filled += 1;
        }
        out.push(acc);
    }
}

/// How many frames a packet holds, if it can be told without decoding.
pub fn frame_count(packet: &[u8]) -> Option<usize> {
    let mut bits = Bits {
        data: packet,
        pos: 0,
    };
    let mut count = 0;
    while bits.remaining() >= 5 {
        let head = bits.peek(5)?;
        if head >> 4 != 0 {
            return None;
        }
        if head & 0xf == TERMINATOR {
            break;
        }
        let len = *FRAME_BITS.get((head & 0xf) as usize)?;
        if len > bits.remaining() {
            return None;
        }
        bits.pos += len;
        count += 1;
    }
    (count > 0).then_some(count)
}

/// The frames of `packet` as separate packets, or `None` if it cannot be split safely (it is
/// then sent whole). A single-frame packet comes back as itself.
pub fn split_frames(packet: &[u8]) -> Option<Vec<Vec<u8>>> {
    let mut bits = Bits {
        data: packet,
        pos: 0,
    };
    let mut frames = Vec::new();
    while bits.remaining() >= 5 {
        let head = bits.peek(5)?;
        let wideband = head >> 4;
        let mode = head & 0xf;
        if wideband != 0 {
            return None;
        }
        if mode == TERMINATOR {
            break;
        }
        let len = *FRAME_BITS.get(mode as usize)?;
        if len > bits.remaining() {
            return None;
        }
        let mut frame = Vec::new();
        copy_bits(packet, bits.pos, len, &mut frame);
        frames.push(frame);
        bits.pos += len;
    }
    if frames.is_empty() {
        return None;
    }
    if frames.len() == 1 {
        return Some(vec![packet.to_vec()]);
    }
    Some(frames)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::speex::codec::{
        Decoder, Encoder, EncoderConfig, FrameOutcome, MAX_PACKET_BYTES,
    };
    use crate::vocab::FRAME_SIZE;

    #[test]
    fn split_frames_decode_like_the_whole_packet() {
        for quality in [0u8, 2, 4, 8, 10] {
            let mut enc = Encoder::new(EncoderConfig {
                quality,
                frames_per_packet: 4,
                ..Default::default()
            })
            .unwrap();
            let mut packet = [0u8; MAX_PACKET_BYTES];
            let mut whole = Vec::new();
            for f in 0..12 {
                let frame: [i16; FRAME_SIZE] = std::array::from_fn(|i| {
                    (((f * FRAME_SIZE + i) as f32 * 0.07).sin() * 8000.0) as i16
                });
                if let Some(n) = enc.encode_frame(&frame, &mut packet) {
                    whole.push(packet[..n].to_vec());
                }
            }
            let mut a = Decoder::new(true).unwrap();
            let mut b = Decoder::new(true).unwrap();
            let mut out_a = [0i16; FRAME_SIZE];
            let mut out_b = [0i16; FRAME_SIZE];
            for p in &whole {
                let parts = split_frames(p).unwrap();
                assert_eq!(parts.len(), 4, "quality {quality}");
                a.load(p).unwrap();
                for part in &parts {
                    assert_eq!(a.decode_next(&mut out_a).unwrap(), FrameOutcome::Decoded);
                    b.load(part).unwrap();
                    assert_eq!(b.decode_next(&mut out_b).unwrap(), FrameOutcome::Decoded);
                    assert_eq!(out_a, out_b);
                    assert_eq!(
                        b.decode_next(&mut out_b).unwrap(),
                        FrameOutcome::EndOfPacket
                    );
                }
            }
        }
    }

    #[test]
    fn garbage_is_not_split() {
        assert_eq!(split_frames(&[]), None);
        assert_eq!(split_frames(&[0xff]), None);
        assert_eq!(split_frames(&[0x80, 0, 0]), None);
    }
}
