//! SRTP and SRTCP under a fixed key, both key schemes: a stream of operations from the fuzzer's
//! bytes, each one record (2-byte length, bytes). Raw records are unprotected as received
//! datagrams; others are protected by a sender first, maybe with one byte changed on the way,
//! and unprotected by the receiver. No panic; a packet changed on the way is never accepted;
//! one accepted unchanged is the packet sent.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lipcall::net::srtp::{KeyScheme, MasterKey, Srtp};
use lipcall_fuzz::Input;

fn key(scheme: KeyScheme) -> MasterKey {
    let mut key = [0u8; 16];
    let mut salt = [0u8; 14];
    for (i, b) in key.iter_mut().chain(salt.iter_mut()).enumerate() {
        *b = (i as u8).wrapping_mul(37).wrapping_add(11);
    }
    MasterKey { key, salt, scheme }
}

/// Changes one byte of `packet` (never to itself); `None` leaves it as it is.
fn tamper(packet: &mut [u8], at: u16, by: u8) -> bool {
    if by == 0 || packet.is_empty() {
        return false;
    }
    let i = usize::from(at) % packet.len();
    packet[i] ^= by;
    true
}

fuzz_target!(|data: &[u8]| {
    let mut input = Input::new(data);
    let scheme = if input.u8() & 1 == 0 {
        KeyScheme::Rfc3711
    } else {
        KeyScheme::PerSession
    };
    let master = key(scheme);
    let mut sender = Srtp::new(&master).expect("random session id");
    let mut receiver = Srtp::new(&master).expect("random session id");
    while !input.is_empty() {
        let op = input.u8() % 5;
        if op == 4 {
            receiver.set_clock_tolerance(u32::from(input.u16()));
            continue;
        }
        let plain = input.record().to_vec();
        let rtcp = op % 2 == 1;
        let mut packet = plain.clone();
        if op < 2 {
            let _ = if rtcp {
                receiver.unprotect_rtcp(&mut packet)
            } else {
                receiver.unprotect_rtp(&mut packet)
            };
            continue;
        }
        let protected = if rtcp {
            sender.protect_rtcp(&mut packet)
        } else {
            sender.protect_rtp(&mut packet)
        };
        let (at, by) = (input.u16(), input.u8());
        if protected.is_err() {
            continue;
        }
        let changed = tamper(&mut packet, at, by);
        let accepted = if rtcp {
            receiver.unprotect_rtcp(&mut packet)
        } else {
            receiver.unprotect_rtp(&mut packet)
        };
        if accepted.is_ok() {
            assert!(!changed, "a packet changed on the way was accepted");
            assert_eq!(
                packet, plain,
                "unprotect did not give back what was protected"
            );
        }
    }
});
