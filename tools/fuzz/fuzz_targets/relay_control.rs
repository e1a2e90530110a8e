//! The relay's control protocol and its rules, without sockets: control datagrams decoded on
//! their own (a decoded one encodes back to the same bytes), then a stream of datagrams from a
//! few addresses into one `RelayCore` (raw bytes, or joins, confirms echoing the last cookie
//! the relay gave that address, leaves, time passing, expiry). No panic; no answer is ever
//! larger than the datagram it answers, nothing goes to an address that sent nothing, and the
//! counts stay within the quotas.
#![no_main]

use std::collections::{HashMap, HashSet};
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::time::{Duration, Instant};

use libfuzzer_sys::fuzz_target;
use lipcall::net::control::{self, Control, ControlKind, Cookie, RoomId};
use lipcall::net::relay::{RelayConfig, RelayCore};
use lipcall_fuzz::Input;

fn address(choice: u8) -> SocketAddr {
    let host = IpAddr::V4(Ipv4Addr::new(127, 0, 0, 1 + (choice >> 2) % 4));
    SocketAddr::new(host, 5000 + u16::from(choice % 4))
}

fn room(choice: u8) -> RoomId {
    RoomId([choice % 3; 16])
}

fuzz_target!(|data: &[u8]| {
    if let Ok(decoded) = Control::decode(data) {
        assert_eq!(&decoded.encode()[..], data);
    }
    if let Some(refusal) = control::legacy_refusal(data) {
        assert!(refusal.len() <= data.len());
    }

    let mut input = Input::new(data);
    let config = RelayConfig {
        max_rooms: 2,
        max_members: 3,
        max_members_per_source: 2,
        burst: 4.0,
        join_burst: 3.0,
        ..RelayConfig::default()
    };
    let start = Instant::now();
    let mut now = start;
    let mut relay = RelayCore::with_secret(config, [7; 64], now);
    let mut cookies: HashMap<SocketAddr, Cookie> = HashMap::new();
    let mut senders: HashSet<SocketAddr> = HashSet::new();
    while !input.is_empty() {
        let op = input.u8();
        let from = address(input.u8());
        let request: Vec<u8> = match op % 6 {
            0 => input.record().to_vec(),
            1 => Control::new(ControlKind::Join, room(input.u8()), Cookie::NONE)
                .encode()
                .to_vec(),
            2 | 3 => {
                let kind = if op % 6 == 2 {
                    ControlKind::Confirm
                } else {
                    ControlKind::Leave
                };
                let cookie = cookies.get(&from).copied().unwrap_or(Cookie::NONE);
                Control::new(kind, room(input.u8()), cookie)
                    .encode()
                    .to_vec()
            }
            4 => {
                now += Duration::from_millis(u64::from(input.u16()) * 16);
                continue;
            }
            _ => {
                relay.expire(now);
                continue;
            }
        };
        senders.insert(from);
        let is_control = request.starts_with(&control::MAGIC);
        let mut copies = 0;
        relay.handle(&request, from, now, |out, to| {
            assert!(
                senders.contains(&to),
                "a datagram to {to}, which sent nothing"
            );
            if is_control {
                assert_eq!(to, from, "a control answer to another address");
                assert!(
                    out.len() <= request.len(),
                    "an answer larger than its request"
                );
                if let Ok(answer) = Control::decode(out) {
                    cookies.insert(to, answer.cookie);
                }
            } else {
                assert_eq!(out, &request[..], "media forwarded changed");
                copies += 1;
            }
            true
        });
        assert!(
            copies < config.max_members,
            "media copied to more than a room"
        );
        let stats = relay.stats();
        assert!(stats.rooms <= config.max_rooms);
        assert!(stats.members <= config.max_rooms * config.max_members);
    }
});
