//! The Opus packet parser and SILK walker over a stream of packets (each a 2-byte length and
//! its bytes; an empty one is a lost packet). No panic; frames lie inside their packet; the
//! walker that stops at the NLSFs reports the same frames as the one that reads every frame to
//! its end; the narrowband LSPs the receiver makes of the NLSFs are finite.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lipcall::codec::opus::features::narrowband_lsp;
use lipcall::codec::silk::{Frame, Packet, SilkWalker};
use lipcall_fuzz::Input;

/// A frame without what only a walk to the frame's end can know.
fn without_end(frame: &Frame) -> Frame {
    match *frame {
        Frame::Silk(mut silk) => {
            silk.end = None;
            Frame::Silk(silk)
        }
        other => other,
    }
}

fuzz_target!(|data: &[u8]| {
    let mut input = Input::new(data);
    let mut quick = SilkWalker::new();
    let mut thorough = SilkWalker::new().read_to_end(true);
    while !input.is_empty() {
        let packet = input.record();
        if packet.is_empty() {
            quick.packet_lost();
            thorough.packet_lost();
            continue;
        }
        if let Ok(parsed) = Packet::parse(packet) {
            let framed: usize = parsed.frames().map(<[u8]>::len).sum();
            assert!(1 + framed + parsed.padding <= packet.len());
            for frame in parsed.frames() {
                let start = frame.as_ptr() as usize - packet.as_ptr() as usize;
                assert!(start + frame.len() <= packet.len());
            }
        }
        let fast = quick.walk_packet(packet);
        let full = thorough.walk_packet(packet);
        match (&fast, &full) {
            (Ok(fast), Ok(full)) => {
                let fast: Vec<Frame> = fast.iter().map(without_end).collect();
                let full: Vec<Frame> = full.iter().map(without_end).collect();
                assert_eq!(fast, full, "the quick walk differs from the full one");
                for silk in full.iter().filter_map(Frame::silk) {
                    if let Some(lsp) = narrowband_lsp(&silk.nlsf, silk.internal_rate_hz) {
                        assert!(lsp.iter().all(|v| v.is_finite()));
                    }
                }
            }
            (Err(a), Err(b)) => assert_eq!(a, b),
            _ => panic!("one walk failed, the other did not: {fast:?} {full:?}"),
        }
    }
});
