//! RTP parsing (what the session does with every datagram that classifies as RTP): no panic,
//! the payload lies inside the packet after a header of at least 12 bytes, and a parsed header
//! written back with the same payload parses to the same packet.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lipcall::net::{DatagramKind, classify, rtp};

fuzz_target!(|data: &[u8]| {
    let kind = classify(data);
    let Ok(packet) = rtp::parse(data, None) else {
        return;
    };
    assert_ne!(
        kind,
        DatagramKind::Control,
        "an RTP packet taken for relay control"
    );
    assert!(!packet.payload.is_empty());
    let start = packet.payload.as_ptr() as usize - data.as_ptr() as usize;
    assert!(start >= 12 && start + packet.payload.len() <= data.len());
    assert_eq!(
        rtp::parse(data, Some(packet.header.payload_type)),
        Ok(packet)
    );
    let mut out = Vec::new();
    rtp::write(&packet.header, packet.payload, &mut out).expect("a parsed packet rewritten");
    let again = rtp::parse(&out, None).expect("a rewritten packet parsed");
    assert_eq!(again, packet);
});
