//! RTCP compound parsing: no panic, names come out printable and short, and a report parsed
//! from the wire is built again into one that parses to the same report.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lipcall::net::rtcp::{self, MAX_NAME_BYTES, Outgoing, RtcpItem};

fuzz_target!(|data: &[u8]| {
    let Ok(items) = rtcp::parse(data) else {
        return;
    };
    for item in &items {
        match item {
            RtcpItem::Names { cname, name, .. } => {
                for text in [cname, name].into_iter().flatten() {
                    assert!(text.len() <= MAX_NAME_BYTES);
                    assert!(!text.chars().any(char::is_control));
                }
            }
            RtcpItem::Report {
                reporter,
                sender,
                blocks,
            } if blocks.len() <= 31 && blocks.iter().all(|b| b.cumulative_lost <= 0x7f_ffff) => {
                let mut out = Vec::new();
                let outgoing = Outgoing {
                    ssrc: *reporter,
                    sender: *sender,
                    blocks,
                    cname: "fuzz",
                    ..Outgoing::default()
                };
                rtcp::build(&outgoing, &mut out).expect("a parsed report rebuilt");
                let again = rtcp::parse(&out).expect("a rebuilt report parsed");
                assert_eq!(again.first(), Some(item));
            }
            _ => {}
        }
    }
});
