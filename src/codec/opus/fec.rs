//! Whether an Opus packet carries in-band FEC: SILK's LBRR copy of the frame before it, flagged
//! in the first range-coded bits of the packet's first frame (RFC 6716 4.2.3 and 4.2.4).
//!
//! libopus, asked to recover a lost frame from the next packet, quietly conceals when that packet
//! carries no FEC. A receiver that counts recovered frames apart from concealed ones, and feeds
//! them to the features as decoded audio, asks here first.

use super::codec::MAX_INPUT_PACKET_BYTES;
use crate::codec::silk::range::RangeDecoder;
use crate::codec::silk::{Mode, Packet};

/// True when the packet's first frame carries an LBRR (FEC) copy of the previous frame for its
/// first (mid) channel. Anything that is no valid SILK or hybrid packet carries none.
pub fn carries_fec(packet: &[u8]) -> bool {
    if packet.len() > MAX_INPUT_PACKET_BYTES {
        return false;
    }
    let Ok(parsed) = Packet::parse(packet) else {
        return false;
    };
    // One SILK frame per 10 or 20 ms Opus frame, two for 40 ms, three for 60 ms.
    let silk_frames = match parsed.toc.mode() {
        Mode::Celt => return false,
        Mode::Hybrid => 1,
        Mode::Silk => (parsed.toc.frame_ms() / 20).max(1),
    };
    let Some(frame) = parsed.frame(0).filter(|f| !f.is_empty()) else {
        return false;
    };
    let mut flags = RangeDecoder::new(frame);
    // The mid channel's VAD flags, then its LBRR flag.
    for _ in 0..silk_frames {
        flags.decode_bit_logp(1);
    }
    flags.decode_bit_logp(1)
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
