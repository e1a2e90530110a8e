//! Janus calls across NATs, with the servers a user behind one sets up, coturn (Debian's
//! `coturn`) standing in for both: as a STUN server it answers lipcall's Binding request and
//! lipcall offers the address it saw beside its local ones; as a TURN server it relays the
//! whole call when lipcall offers its relay only. A STUN server that never answers costs the
//! join a moment and a warning, never the call; wrong TURN credentials are said. Each test runs
//! in a network namespace of its own (tests/common/netns.rs).

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use common::janus::{
    IN_ROOM, STOCK_VIDEOROOM, envelope, envelope_correlation, runs_here, start_janus_with,
};
use common::nat::{media_ip, start_coturn};
use common::net::{finish, spawn, spawn_listening};
use common::{lipcall, repo_file};

/// `send` and `receive` with the `ice` flags meet in a room of a stock Janus: the receiver's
/// stderr and how well it heard the speech.
fn call_with(dir: &Path, ice: &[&str], room: &str) -> (String, f64) {
    let janus = start_janus_with(dir, &[Path::new(STOCK_VIDEOROOM)]);
    let speech = repo_file("assets/speech/demo.wav");
    let wav = dir.join("heard.wav");
    let receiver = spawn_listening(
        lipcall()
            .env("RUST_LOG", "lipcall=info")
            .args(["receive", "--janus", &janus.url, "--room", room])
            .args(ice)
            .args(["--name", "Bob", "--seconds", "13"])
            .args(["--rate", "8000"])
            .arg("--wav")
            .arg(&wav),
        IN_ROOM,
    );
    let sender = spawn(
        lipcall()
            .arg("send")
            .arg(&speech)
            .args(["--janus", &janus.url, "--room", room, "--name", "Ann"]),
    );
    let (_, sent) = finish(sender, Duration::from_secs(30), "lipcall send --janus");
    let (_, received) = receiver.finish(Duration::from_secs(30), "lipcall receive --janus");
    let r = envelope_correlation(&envelope(&speech), &envelope(&wav));
    eprintln!("level contour r {r:.3}\nsender: {sent}\nreceiver: {received}");
    (received, r)
}

#[test]
fn a_stun_server_tells_the_address_offered_and_the_call_is_heard() {
    if !runs_here("a_stun_server_tells_the_address_offered_and_the_call_is_heard") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let Some(coturn) = start_coturn(dir.path(), "127.0.0.1", None) else {
        return;
    };
    let server = coturn.addr.to_string();
    let (received, r) = call_with(dir.path(), &["--stun", &server], "4321");
    assert!(
        received.contains(&format!("STUN server {server}: our address outside is ")),
        "{received}"
    );
    assert!(r > 0.9, "r {r:.3}\n{received}");
}

#[test]
fn a_silent_stun_server_costs_a_warning_not_the_call() {
    if !runs_here("a_silent_stun_server_costs_a_warning_not_the_call") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // Bound, so that no ICMP says it is gone: it just never answers.
    let silent = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let server = silent.local_addr().unwrap().to_string();
    let (received, r) = call_with(dir.path(), &["--stun", &server], "4322");
    assert!(
        received.contains(&format!("STUN server {server} did not answer")),
        "{received}"
    );
    assert!(
        received.contains("offering local addresses only"),
        "{received}"
    );
    assert!(r > 0.9, "r {r:.3}\n{received}");
}

#[test]
fn a_call_relayed_only_through_turn_is_heard() {
    if !runs_here("a_call_relayed_only_through_turn_is_heard") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // The relay on the namespace's own address, where Janus's ICE meets it (libnice takes no
    // loopback candidates).
    let ip = media_ip();
    let Some(coturn) = start_coturn(dir.path(), &ip, Some("ann:s3cret")) else {
        return;
    };
    let server = coturn.addr.to_string();
    let password = dir.path().join("turn-password");
    std::fs::write(&password, "s3cret\n").unwrap();
    let turn = [
        "--turn",
        &server,
        "--turn-user",
        "ann",
        "--turn-password-file",
        password.to_str().unwrap(),
    ];
    let (received, r) = call_with(dir.path(), &[&turn[..], &["--turn-only"]].concat(), "4323");
    assert!(
        received.contains(&format!("TURN server {server}: relaying through {ip}:")),
        "{received}"
    );
    assert!(r > 0.9, "r {r:.3}\n{received}");
    // coturn saw the allocation and its permission for Janus.
    let log = std::fs::read_to_string(dir.path().join("turnserver.log")).unwrap_or_default();
    assert!(
        log.contains("CREATE_PERMISSION") || log.contains("permission"),
        "{log}"
    );
}

#[test]
fn wrong_turn_credentials_are_said_and_a_relay_only_call_refused() {
    if !runs_here("wrong_turn_credentials_are_said_and_a_relay_only_call_refused") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let ip = media_ip();
    let Some(coturn) = start_coturn(dir.path(), &ip, Some("ann:s3cret")) else {
        return;
    };
    let janus = start_janus_with(dir.path(), &[Path::new(STOCK_VIDEOROOM)]);
    let started = Instant::now();
    let out = lipcall()
        .args([
            "receive",
            "--janus",
            &janus.url,
            "--room",
            "4324",
            "--seconds",
            "5",
        ])
        .args(["--turn", &coturn.addr.to_string(), "--turn-user", "ann"])
        .arg("--turn-only")
        .env("LIPCALL_TURN_PASSWORD", "wrong")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("wrong user name or password"), "{stderr}");
    assert!(started.elapsed() < Duration::from_secs(10), "{stderr}");
}
