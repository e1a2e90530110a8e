//! A hostile Mumble server: a client that has its UDP key is fed a stream of operations from
//! the fuzzer's bytes, each a record (2-byte length, bytes) after an op byte and a time step:
//! raw bytes of the TLS stream (framed protobuf messages, or anything), raw UDP datagrams,
//! datagrams the server encrypted properly (so that the voice parser and the speakers'
//! receivers see what they carry), and our own sending and playing. No panic, no hang.
#![no_main]

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use libfuzzer_sys::fuzz_target;
use lipcall::net::jitter::JitterConfig;
use lipcall::net::mumble::client::{ClientConfig, ClientCore};
use lipcall::net::mumble::crypt::CryptState;
use lipcall::net::mumble::messages::{self, CryptSetup, MessageType};
use lipcall_fuzz::Input;

const KEY: [u8; 16] = [7; 16];
const OURS: [u8; 16] = [1; 16];
const THEIRS: [u8; 16] = [2; 16];

fuzz_target!(|data: &[u8]| {
    let mut input = Input::new(data);
    let server: SocketAddr = ([127, 0, 0, 1], 64738).into();
    let mut now = Instant::now();
    let config = ClientConfig {
        name: "fuzz".into(),
        password: None,
        channel: Some("Lobby".into()),
        jitter: JitterConfig::default(),
        tcp_only: input.u8() & 1 == 1,
    };
    let mut core = ClientCore::new(config, server, now);
    core.connected(now);
    let setup = CryptSetup {
        key: Some(KEY.to_vec()),
        client_nonce: Some(OURS.to_vec()),
        server_nonce: Some(THEIRS.to_vec()),
    };
    core.handle_stream(&messages::frame(MessageType::CryptSetup, &setup), now);
    let mut server_crypt = CryptState::new(&KEY, THEIRS, OURS);
    let mut frames = Vec::new();
    while !input.is_empty() {
        let op = input.u8();
        now += Duration::from_millis(u64::from(input.u8()));
        let record = input.record();
        match op % 5 {
            0 => core.handle_stream(record, now),
            1 => core.datagram(record, server, now),
            2 => {
                let packet = server_crypt.encrypt(record);
                core.datagram(&packet, server, now);
            }
            3 => {
                let _ = core.send_voice(record, 1 + u32::from(op >> 5));
            }
            _ => {
                frames.clear();
                core.pull(now, &mut frames);
                let _ = core.speakers();
            }
        }
        let _ = core.take_fatal();
        while core.poll_control().is_some() {}
        while core.next_transmit().is_some() {}
        while core.poll_event().is_some() {}
        if now >= core.next_wake() {
            core.wake(now);
        }
    }
});
