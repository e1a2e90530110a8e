//! The app's phone behind a NAT (issue 45), without a window: its listener takes the STUN
//! server of the NAT settings (the media address the SDP gives) and the fixed local SIP port
//! of its settings, where a caller reaches it directly.

mod common;

use std::net::{SocketAddr, SocketAddrV4, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use common::sip::{
    PASSWORD, baresip, free_port, have, kamailio, reversed_8k, stun_binding_success, tell_baresip,
};
use lipcall::app::engine::Command;
use lipcall::app::sip_call::{PhoneCommand, PhoneNetwork};
use lipcall::net::sip::agent::Account;

/// A STUN server on 127.0.0.1 answering each Binding request with its source; the count of
/// requests.
fn stun_server() -> (u16, Arc<AtomicUsize>) {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = socket.local_addr().unwrap().port();
    let asked = Arc::new(AtomicUsize::new(0));
    let counted = Arc::clone(&asked);
    std::thread::spawn(move || {
        let mut buf = [0u8; 1500];
        while let Ok((n, from)) = socket.recv_from(&mut buf) {
            let SocketAddr::V4(from) = from else { continue };
            let mapped = SocketAddrV4::new(*from.ip(), from.port());
            if let Some(reply) = stun_binding_success(&buf[..n], mapped) {
                counted.fetch_add(1, Ordering::Relaxed);
                let _ = socket.send_to(&reply, from);
            }
        }
    });
    (port, asked)
}

#[test]
fn the_phone_listens_on_its_fixed_port_and_asks_stun() {
    if !have(&["kamailio", "baresip", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (kam_port, bob_port, control, sip_port) = (
        free_port(false),
        free_port(false),
        free_port(false),
        free_port(false),
    );
    let _kamailio = kamailio(dir.path(), kam_port, "");
    let (stun_port, stun_asked) = stun_server();
    let bob = baresip(
        dir.path(),
        bob_port,
        control,
        "<sip:bob@127.0.0.1>;regint=0;audio_codecs=PCMU",
        &reversed_8k(dir.path()),
    );
    let engine = common::app::headless_engine("Alice", None);
    engine.send(Command::Phone(PhoneCommand::Network(PhoneNetwork {
        stun: Some(format!("127.0.0.1:{stun_port}")),
        sip_port: Some(sip_port),
        ca: None,
        frame_ms: 20,
    })));
    let account = Account::parse(&format!("sip:alice@127.0.0.1:{kam_port}"), PASSWORD).unwrap();
    engine.send(Command::Phone(PhoneCommand::Account(Some(account))));
    common::app::wait_for(&engine, "registered", Duration::from_secs(15), |s| {
        s.phone.registration.starts_with("registered with")
    });
    // The listener's RTP and RTCP sockets each asked where the NAT maps them.
    assert!(stun_asked.load(Ordering::Relaxed) >= 2);

    // A caller that knows the port reaches the phone there, not through the registrar.
    tell_baresip(control, "dial", &format!("sip:alice@127.0.0.1:{sip_port}"));
    common::app::wait_for(&engine, "the call rings", Duration::from_secs(15), |s| {
        s.phone.ringing.is_some()
    });
    engine.send(Command::Phone(PhoneCommand::Decline));
    assert!(
        bob.wait_for("603 Decline", Duration::from_secs(10)),
        "baresip: {}",
        bob.text()
    );
}
