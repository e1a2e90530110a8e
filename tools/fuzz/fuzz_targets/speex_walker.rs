//! The Speex bitstream walker over a stream of packets (each a 1-byte length and its bytes),
//! and the packet splitter beside it. No panic; the splitter and the frame counter agree; a
//! packet the splitter cuts into frames walks to the same frames whole as cut.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lipcall::codec::speex::bitstream::{Frame, Walker};
use lipcall::codec::speex::split::{frame_count, split_frames};
use lipcall_fuzz::Input;

fn walk(walker: &mut Walker, packet: &[u8]) -> Option<Vec<Frame>> {
    walker.walk_packet(packet).ok()
}

fuzz_target!(|data: &[u8]| {
    let mut input = Input::new(data);
    let mut walker = Walker::new();
    while !input.is_empty() {
        let packet = input.short_record();
        let parts = split_frames(packet);
        assert_eq!(frame_count(packet), parts.as_ref().map(Vec::len));
        let mut cut = walker.clone();
        let whole = walk(&mut walker, packet);
        for frame in whole.iter().flatten() {
            assert!(frame.mode() <= 8);
        }
        if let Some(parts) = parts.filter(|p| p.len() > 1) {
            let mut frames = Vec::new();
            for part in &parts {
                frames.extend(walk(&mut cut, part).expect("a split frame walks"));
            }
            assert_eq!(whole.as_ref(), Some(&frames), "whole and cut differ");
        }
    }
});
