//! A Janus call with a STUN server, as a user behind a NAT sets it up: coturn (Debian's
//! `coturn`) answers lipcall's Binding request, lipcall offers the address it saw beside its
//! local ones, and the call is heard. A STUN server that never answers costs the join a moment
//! and a warning, never the call. Each test runs in a network namespace of its own
//! (tests/common/netns.rs).

mod common;

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::janus::{
    IN_ROOM, STOCK_VIDEOROOM, envelope, envelope_correlation, runs_here, start_janus_with,
};
use common::net::{finish, spawn, spawn_listening};
use common::{lipcall, repo_file};

/// coturn as a plain STUN server on a free loopback port, killed when dropped.
struct Coturn {
    child: Child,
    addr: std::net::SocketAddr,
}

impl Drop for Coturn {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn start_coturn(dir: &Path) -> Option<Coturn> {
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .map(|a| a.port())
        .unwrap();
    let child = Command::new("turnserver")
        .args(["-n", "--stun-only", "--no-cli", "--no-tls", "--no-dtls"])
        .args(["--listening-ip", "127.0.0.1", "--listening-port"])
        .arg(port.to_string())
        .arg("--pidfile")
        .arg(dir.join("turnserver.pid"))
        .arg("--log-file")
        .arg(dir.join("turnserver.log"))
        .arg("--simple-log")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn();
    let Ok(child) = child else {
        common::unavailable("no `turnserver` (Debian package coturn)");
        return None;
    };
    let coturn = Coturn {
        child,
        addr: std::net::SocketAddr::from(([127, 0, 0, 1], port)),
    };
    // Ready once it answers.
    let probe = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let asked =
            lipcall::net::stun::reflexive_address(&probe, coturn.addr, Duration::from_millis(300));
        if asked == Ok(probe.local_addr().unwrap()) {
            return Some(coturn);
        }
        assert!(
            Instant::now() < deadline,
            "coturn never answered: {asked:?}"
        );
    }
}

/// `send` and `receive --stun SERVER` meet in a room of a stock Janus: the receiver's stderr
/// and how well it heard the speech.
fn call_with_stun(dir: &Path, stun: &str, room: &str) -> (String, f64) {
    let janus = start_janus_with(dir, &[Path::new(STOCK_VIDEOROOM)]);
    let speech = repo_file("assets/speech/demo.wav");
    let wav = dir.join("heard.wav");
    let receiver = spawn_listening(
        lipcall()
            .env("RUST_LOG", "lipcall=info")
            .args(["receive", "--janus", &janus.url, "--room", room])
            .args(["--stun", stun, "--name", "Bob", "--seconds", "13"])
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
    let Some(coturn) = start_coturn(dir.path()) else {
        return;
    };
    let server = coturn.addr.to_string();
    let (received, r) = call_with_stun(dir.path(), &server, "4321");
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
    let (received, r) = call_with_stun(dir.path(), &server, "4322");
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
