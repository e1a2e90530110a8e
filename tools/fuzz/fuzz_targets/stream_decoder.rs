//! One peer's decoder for any codec (the first byte picks it) over a stream of payloads (each
//! a 2-byte length and its bytes; an empty one is a lost frame), each placed at an offset the
//! next byte gives. No panic; every frame carries 20 ms at the codec's own rate, and features
//! with ordered, finite LSPs.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lipcall::codec::any::Codec;
use lipcall::codec::decoder::StreamDecoder;
use lipcall_fuzz::Input;

fuzz_target!(|data: &[u8]| {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    let codec = Codec::ALL[usize::from(pick) % Codec::ALL.len()];
    let Ok(mut decoder) = StreamDecoder::new(codec, pick & 0x80 != 0) else {
        return;
    };
    let mut input = Input::new(rest);
    while !input.is_empty() {
        let payload = input.record();
        let frame = if payload.is_empty() {
            decoder.lost(None)
        } else {
            let offset = u32::from(payload[0]) * 8;
            decoder.packet(payload, offset);
            decoder.frame()
        };
        assert_eq!(frame.audio.rate(), codec.audio_rate());
        assert_eq!(frame.audio.samples().len(), codec.audio_rate() as usize / 50);
        assert!(frame.features.lsp.iter().all(|v| v.is_finite()));
        assert!(frame.features.energy_db.is_finite());
    }
});
