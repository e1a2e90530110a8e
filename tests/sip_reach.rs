//! Reachability of a registered lipcall (issue 45) on 127.0.0.1: keepalives seen on the wire
//! while the account idles (CRLF on TCP, OPTIONS on UDP), and a call to the account's domain
//! sent through its registrar rather than to the domain.

mod common;

use std::io::{Read, Write};
use std::net::{TcpListener, UdpSocket};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use common::sip::{PASSWORD, bob_registered, exit_of, free_port, have, kamailio, reversed_8k};

/// What a registrar of the test saw.
#[derive(Default)]
struct Seen {
    registers: AtomicUsize,
    options: AtomicUsize,
    /// CRLFCRLF pings after the first REGISTER was answered.
    pings: AtomicUsize,
    requests: Mutex<Vec<String>>,
}

/// A 200 OK to `request`, its headers copied (and the binding granted for 300 s).
fn ok_to(request: &str) -> String {
    let mut response = String::from("SIP/2.0 200 OK\r\n");
    for line in request.lines().skip(1) {
        let name = line.split(':').next().unwrap_or("").to_ascii_lowercase();
        match name.as_str() {
            "via" | "from" | "call-id" | "cseq" => {
                response.push_str(line);
                response.push_str("\r\n");
            }
            "to" => response.push_str(&format!("{line};tag=registrar\r\n")),
            "contact" => response.push_str(&format!("{line};expires=300\r\n")),
            _ => {}
        }
    }
    response.push_str("Content-Length: 0\r\n\r\n");
    response
}

impl Seen {
    /// Takes one request; the answer to send, if any.
    fn take(&self, request: &str) -> Option<String> {
        self.requests.lock().unwrap().push(request.to_owned());
        let method = request.split(' ').next().unwrap_or("");
        match method {
            "REGISTER" => {
                self.registers.fetch_add(1, Ordering::Relaxed);
                Some(ok_to(request))
            }
            "OPTIONS" => {
                self.options.fetch_add(1, Ordering::Relaxed);
                Some(ok_to(request))
            }
            _ => None,
        }
    }
}

/// A registrar on UDP that takes every REGISTER and answers OPTIONS.
fn udp_registrar(seen: Arc<Seen>) -> u16 {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = socket.local_addr().unwrap().port();
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        while let Ok((n, from)) = socket.recv_from(&mut buf) {
            let text = String::from_utf8_lossy(&buf[..n]).into_owned();
            if let Some(answer) = seen.take(&text) {
                let _ = socket.send_to(answer.as_bytes(), from);
            }
        }
    });
    port
}

/// A registrar on TCP that takes every REGISTER and counts the client's CRLFCRLF pings
/// (answered with CRLF, RFC 5626 4.4.1).
fn tcp_registrar(seen: Arc<Seen>) -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    std::thread::spawn(move || {
        let Ok((mut stream, _)) = listener.accept() else {
            return;
        };
        let mut pending = Vec::new();
        let mut buf = [0u8; 4096];
        while let Ok(n) = stream.read(&mut buf) {
            if n == 0 {
                break;
            }
            pending.extend_from_slice(&buf[..n]);
            loop {
                if pending.starts_with(b"\r\n\r\n") {
                    pending.drain(..4);
                    if seen.registers.load(Ordering::Relaxed) > 0 {
                        seen.pings.fetch_add(1, Ordering::Relaxed);
                    }
                    let _ = stream.write_all(b"\r\n");
                    continue;
                }
                let Some(end) = pending.windows(4).position(|w| w == b"\r\n\r\n") else {
                    break;
                };
                let request = String::from_utf8_lossy(&pending[..end + 4]).into_owned();
                pending.drain(..end + 4);
                if let Some(answer) = seen.take(&request) {
                    let _ = stream.write_all(answer.as_bytes());
                }
            }
        }
    });
    port
}

/// `sip answer` registered as alice with `account`, idling for `seconds`: its exit and log.
fn idle_registered(dir: &std::path::Path, account: &str, seconds: &str) -> (Option<i32>, String) {
    let listen = free_port(false);
    let answer = common::sip::Peer::spawn_logged(
        "lipcall sip answer",
        common::lipcall()
            .args(["sip", "answer", "--listen", &format!("127.0.0.1:{listen}")])
            .args(["--account", account])
            .env("LIPCALL_SIP_PASSWORD", PASSWORD)
            .arg("--play")
            .arg(common::demo_8k(dir))
            .args(["--seconds", seconds]),
    );
    exit_of(answer, Duration::from_secs(60))
}

#[test]
fn an_idle_account_on_tcp_pings_its_registrar_with_crlf() {
    if !have(&["sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let seen = Arc::new(Seen::default());
    let port = tcp_registrar(Arc::clone(&seen));
    let (_, log) = idle_registered(
        dir.path(),
        &format!("sip:alice@127.0.0.1:{port};transport=tcp"),
        "23",
    );
    assert!(log.contains("over TCP"), "{log}");
    assert!(log.contains("registered with"), "{log}");
    let pings = seen.pings.load(Ordering::Relaxed);
    eprintln!("CRLF pings in 23 s registered: {pings}");
    // ezk pings every 10 s.
    assert!(
        pings >= 2,
        "{pings} pings: {:?}",
        seen.requests.lock().unwrap()
    );
}

#[test]
fn an_idle_account_on_udp_sends_options_to_its_registrar() {
    if !have(&["sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let seen = Arc::new(Seen::default());
    let port = udp_registrar(Arc::clone(&seen));
    let (_, log) = idle_registered(dir.path(), &format!("sip:alice@127.0.0.1:{port}"), "29");
    assert!(log.contains("registered with"), "{log}");
    let options = seen.options.load(Ordering::Relaxed);
    eprintln!("OPTIONS in 29 s registered: {options}");
    // One every 25 s: the first at 25 s.
    assert!(
        (1..=2).contains(&options),
        "{:?}",
        seen.requests.lock().unwrap()
    );
    let requests = seen.requests.lock().unwrap();
    let ping = requests.iter().find(|r| r.starts_with("OPTIONS")).unwrap();
    assert!(ping.contains("OPTIONS sip:127.0.0.1:"), "{ping}");
}

#[test]
fn a_call_to_the_accounts_domain_goes_through_its_registrar() {
    if !have(&["kamailio", "baresip", "sox"]) {
        return;
    }
    // The domain does not resolve: only the registrar can take the call.
    let domain = "lipcall-test.invalid";
    let dir = tempfile::tempdir().unwrap();
    let kam_port = free_port(false);
    let _kamailio = kamailio(dir.path(), kam_port, "");
    let bob = bob_registered(dir.path(), kam_port, "auto", &reversed_8k(dir.path()));
    let out = common::lipcall()
        .args(["sip", "call", &format!("sip:bob@{domain}")])
        .args(["--account", &format!("sip:alice@{domain}")])
        .args(["--registrar", &format!("127.0.0.1:{kam_port}")])
        .env("LIPCALL_SIP_PASSWORD", PASSWORD)
        .arg("--play")
        .arg(common::demo_8k(dir.path()))
        .args(["--codec", "pcmu", "--seconds", "4"])
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{log}\nbaresip: {}", bob.text());
    assert!(
        log.contains(&format!("in a SIP call with sip:bob@{domain}")),
        "{log}"
    );
    assert!(
        bob.wait_for("session closed", Duration::from_secs(5)),
        "baresip: {}",
        bob.text()
    );
}
