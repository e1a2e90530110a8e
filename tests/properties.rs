//! Random and mutated input to every parser on the decode path: errors are fine, panics and
//! hangs are not.

use lipcall::codec::speex::codec::{Decoder, EncoderConfig, FrameOutcome};
use lipcall::codec::speex::features::FrameTracker;
use lipcall::codec::speex::{ogg_file, stream};
use lipcall::vocab::FRAME_SIZE;
use proptest::prelude::*;

fn speech_like(n: usize) -> Vec<i16> {
    (0..n)
        .map(|i| {
            let t = i as f32 / 8000.0;
            let envelope = (t * 3.0).sin().abs();
            (envelope
                * (5000.0 * (2.0 * std::f32::consts::PI * 140.0 * t).sin()
                    + 2000.0 * (2.0 * std::f32::consts::PI * 900.0 * t).sin())) as i16
        })
        .collect()
}

fn valid_file(quality: u8, vbr: bool, frames_per_packet: usize) -> Vec<u8> {
    stream::encode(
        &speech_like(8000),
        EncoderConfig {
            quality,
            vbr,
            frames_per_packet,
            ..Default::default()
        },
    )
    .unwrap()
}

fn decode_packet(decoder: &mut Decoder, tracker: &mut FrameTracker, packet: &[u8]) {
    let _ = tracker.start_packet(packet);
    if decoder.load(packet).is_err() {
        return;
    }
    let mut out = [0i16; FRAME_SIZE];
    for _ in 0..64 {
        match decoder.decode_next(&mut out) {
            Ok(FrameOutcome::Decoded) => {
                let row = tracker.decoded(&out);
                assert!(row.energy_db.is_finite());
            }
            Ok(FrameOutcome::EndOfPacket) | Err(_) => break,
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn random_packets_never_panic_the_decoder(packets in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..200), 1..20)) {
        let mut decoder = Decoder::new(true).unwrap();
        let mut tracker = FrameTracker::new();
        for p in &packets {
            decode_packet(&mut decoder, &mut tracker, p);
        }
    }

    #[test]
    fn mutated_packets_never_panic_the_decoder(quality in 0u8..=10, flips in prop::collection::vec((any::<prop::sample::Index>(), 0u8..8), 1..8)) {
        let file = ogg_file::read(&valid_file(quality, false, 2)).unwrap();
        let mut decoder = Decoder::new(false).unwrap();
        let mut tracker = FrameTracker::new();
        for page in &file.pages {
            for packet in &page.packets {
                let mut p = packet.clone();
                for (at, bit) in &flips {
                    let i = at.index(p.len());
                    p[i] ^= 1 << bit;
                }
                decode_packet(&mut decoder, &mut tracker, &p);
            }
        }
    }

    #[test]
    fn random_bytes_never_panic_the_ogg_reader(bytes in prop::collection::vec(any::<u8>(), 0..4000)) {
        let _ = ogg_file::read(&bytes);
        let mut with_magic = b"OggS".to_vec();
        with_magic.extend_from_slice(&bytes);
        let _ = stream::decode(&with_magic, true);
    }

    #[test]
    fn mutated_files_never_panic_the_stream_decoder(
        vbr in any::<bool>(),
        frames_per_packet in 1usize..4,
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..12),
        cut in any::<prop::sample::Index>(),
        do_cut in any::<bool>(),
    ) {
        let mut bytes = valid_file(4, vbr, frames_per_packet);
        for (at, value) in &edits {
            let i = at.index(bytes.len());
            bytes[i] = *value;
        }
        if do_cut {
            bytes.truncate(cut.index(bytes.len()));
        }
        if let Ok(decoded) = stream::decode(&bytes, true) {
            prop_assert_eq!(decoded.features.len(), decoded.pcm.len().div_ceil(FRAME_SIZE));
        }
    }
}
