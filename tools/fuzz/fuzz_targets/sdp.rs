//! SDP from a SIP peer (`net::sip::sdp::parse`, `negotiate`, `answer`): what an INVITE or the
//! answer to ours carries. No panic or runaway allocation; a description that negotiates gets
//! an answer from us that reads back to the same codec, payload type and events, at our
//! address.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lipcall::codec::any::Codec;
use lipcall::net::sip::sdp::{self, LocalAudio};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let Ok(remote) = sdp::parse(&text) else {
        return;
    };
    let Ok(chosen) = sdp::negotiate(&remote, &Codec::ALL) else {
        return;
    };
    let local = LocalAudio {
        addr: ([127, 0, 0, 1], 4000).into(),
        codecs: Codec::ALL.to_vec(),
        session_id: 1,
        key: sdp::SdesKey([1; sdp::SDES_KEY_LEN]),
        offer_srtp: false,
    };
    let answer = sdp::answer(&local, &chosen, 1);
    let back = sdp::parse(&answer).expect("our answer reads back");
    let again = sdp::negotiate(&back, &Codec::ALL).expect("our answer negotiates");
    assert_eq!(
        (again.codec, again.payload_type, again.events),
        (chosen.codec, chosen.payload_type, chosen.events)
    );
    assert_eq!(again.srtp.is_some(), chosen.srtp.is_some());
    assert_eq!(back.addr, local.addr);
});
