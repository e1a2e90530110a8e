//! The app's engine without a window: it joins an encrypted room on a relay (sending Opus), and
//! an Opus sender in the same room is heard and animated, its codec shown.

mod common;

use std::time::{Duration, Instant};

use lipcall::app::engine::{CallSpec, Command, lock};
use lipcall::codec::any::Codec;
use lipcall::commands::net::{KeyArgs, SendArgs, send};
use lipcall::net::relay::{Relay, RelayConfig};

#[test]
fn the_engine_joins_an_encrypted_room_and_animates_a_sender() {
    let relay = Relay::start("127.0.0.1:0".parse().unwrap(), RelayConfig::default()).unwrap();
    let relay_addr = relay.local_addr().to_string();
    let engine = common::app::headless_engine("Eve", None);
    engine.send(Command::Call(Box::new(CallSpec {
        address: relay_addr.clone(),
        room: Some("lab".into()),
        passphrase: Some("open sesame".into()),
        name: "Eve".into(),
        codec: Codec::Opus,
        ..CallSpec::default()
    })));
    let deadline = Instant::now() + Duration::from_secs(10);
    while !lock(&engine.shared).call.in_call {
        assert!(Instant::now() < deadline, "{:?}", lock(&engine.shared).call);
        std::thread::sleep(Duration::from_millis(20));
    }
    // The sender's passphrase from a file, as the command line takes it.
    let dir = tempfile::tempdir().unwrap();
    let key = dir.path().join("key");
    std::fs::write(&key, "open sesame\n").unwrap();
    let args = SendArgs {
        input: concat!(env!("CARGO_MANIFEST_DIR"), "/assets/speech/demo.wav").into(),
        to: relay_addr,
        key: KeyArgs {
            passphrase_file: Some(key),
            hex_file: None,
        },
        name: Some("Mallory".into()),
        room: Some("lab".into()),
        quality: 8,
        bandwidth: lipcall::codec::opus::codec::Bandwidth::Fullband,
        frame_ms: 20,
        no_rtcp: false,
        ssrc: None,
        codec: Some(Codec::Opus),
        payload_types: Vec::new(),
        seconds: None,
    };
    std::thread::spawn(move || send(&args));
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        {
            let s = lock(&engine.shared);
            assert_eq!(
                s.call.encryption,
                lipcall::app::engine::Encryption::EndToEnd,
                "the call is not encrypted"
            );
            assert!(s.call.error.is_none(), "{:?}", s.call.error);
            assert_eq!(s.call.codec, Some(Codec::Opus));
            if let Some(p) = s.peers.views().into_iter().find(|p| p.name == "Mallory")
                && p.frames_animated > 50
            {
                assert!(!p.is_demo);
                assert_eq!(p.codec, Some(Codec::Opus));
                break;
            }
        }
        assert!(
            Instant::now() < deadline,
            "no animated peer: {:?}",
            lock(&engine.shared).peers.views()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    engine.send(Command::Leave);
    let deadline = Instant::now() + Duration::from_secs(5);
    while lock(&engine.shared).call.in_call {
        assert!(Instant::now() < deadline, "leave did not end the call");
        std::thread::sleep(Duration::from_millis(20));
    }
}
