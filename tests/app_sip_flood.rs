//! The app's idle, registered phone under a flood of INVITEs that are never ACKed (issue 43:
//! 162 -> 1,134 MB once): the registrar is written here on 127.0.0.1 and tells the flooder
//! where the phone listens; 40,000 INVITEs later the app has grown by less than 50 MB, its
//! engine answered all along, and a real caller (`lipcall sip call`) still rings, is answered
//! and heard.

mod common;

use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use common::memory_mb;
use common::sip::{flood, header};
use lipcall::app::engine::{Command, Shared, lock};
use lipcall::app::sip_call::PhoneCommand;
use lipcall::net::sip::agent::Account;

const INVITES: usize = 40_000;
const MAX_GROWTH_MB: f64 = 50.0;

/// A registrar that takes every REGISTER (and answers OPTIONS), and keeps the last registered
/// Contact's HOST:PORT: where the phone listens.
struct Registrar {
    addr: SocketAddr,
    /// The last Contact and how many REGISTERs carried one.
    contact: Arc<Mutex<(Option<SocketAddr>, usize)>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Registrar {
    fn start() -> Self {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket
            .set_read_timeout(Some(Duration::from_millis(50)))
            .unwrap();
        let addr = socket.local_addr().unwrap();
        let contact = Arc::new(Mutex::new((None, 0)));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (contact, stop) = (Arc::clone(&contact), Arc::clone(&stop));
            std::thread::spawn(move || {
                let mut buf = [0u8; 65536];
                while !stop.load(Ordering::Relaxed) {
                    let Ok((n, from)) = socket.recv_from(&mut buf) else {
                        continue;
                    };
                    let request = String::from_utf8_lossy(&buf[..n]).into_owned();
                    let Some(method) = request.split(' ').next() else {
                        continue;
                    };
                    if !matches!(method, "REGISTER" | "OPTIONS") {
                        continue;
                    }
                    let copied: String = ["Via", "From", "Call-ID", "CSeq", "Contact"]
                        .iter()
                        .filter_map(|h| Some(format!("{h}: {}\r\n", header(&request, h)?)))
                        .collect();
                    let to = header(&request, "To").unwrap_or("");
                    // A listener that leaves unregisters (expires 0): that Contact is gone.
                    let leaving = header(&request, "Expires").is_some_and(|e| e == "0")
                        || header(&request, "Contact").is_some_and(|c| c.contains("expires=0"));
                    if method == "REGISTER"
                        && !leaving
                        && let Some(at) = header(&request, "Contact")
                            .and_then(|c| c.split('@').nth(1))
                            .and_then(|c| c.split(['>', ';']).next())
                            .and_then(|c| c.parse().ok())
                    {
                        let mut contact = contact.lock().unwrap();
                        *contact = (Some(at), contact.1 + 1);
                    }
                    let reply = format!(
                        "SIP/2.0 200 OK\r\n{copied}To: {to};tag=reg\r\nExpires: 3600\r\n\
                         Content-Length: 0\r\n\r\n"
                    );
                    let _ = socket.send_to(reply.as_bytes(), from);
                }
            })
        };
        Self {
            addr,
            contact,
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for Registrar {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Sends `INVITES` INVITEs to `to`, 200 at most unanswered at a time (each never ACKed): how
/// many got a final answer.
fn flood_invites(to: SocketAddr) -> usize {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let me = socket.local_addr().unwrap();
    let offer = "v=0\r\no=flood 1 1 IN IP4 127.0.0.1\r\ns=-\r\nc=IN IP4 127.0.0.1\r\nt=0 0\r\n\
                 m=audio 9 RTP/AVP 0\r\na=rtpmap:0 PCMU/8000\r\n";
    let invite = |n: usize| {
        format!(
            "INVITE sip:alice@{to} SIP/2.0\r\nVia: SIP/2.0/UDP {me};branch=z9hG4bKf{n}\r\n\
             From: <sip:flood@{me}>;tag=f{n}\r\nTo: <sip:alice@{to}>\r\n\
             Call-ID: flood-{n}\r\nCSeq: 1 INVITE\r\nContact: <sip:flood@{me}>\r\n\
             Max-Forwards: 70\r\nContent-Type: application/sdp\r\nContent-Length: {}\r\n\r\n{offer}",
            offer.len()
        )
    };
    let number = |response: &str| {
        header(response, "Call-ID")?
            .strip_prefix("flood-")?
            .parse::<usize>()
            .ok()
    };
    flood(
        &socket,
        to,
        INVITES,
        200,
        Duration::from_secs(60),
        invite,
        number,
    )
    .len()
}

#[test]
fn an_idle_registered_phone_outlives_an_invite_flood_and_still_takes_a_call() {
    let registrar = Registrar::start();
    let engine = common::app::headless_engine("Alice", None);
    let account = Account::parse(&format!("sip:alice@{}", registrar.addr), "flood-pw").unwrap();
    engine.send(Command::Phone(PhoneCommand::Account(Some(account))));
    let limit = Duration::from_secs(20);
    let registered = |s: &Shared| s.phone.registration.starts_with("registered with");
    common::app::wait_for(&engine, "registered", limit, registered);
    let phone = registrar.contact.lock().unwrap().0.expect("a Contact");
    std::thread::sleep(Duration::from_secs(1));
    let me = std::process::id();
    let before = memory_mb(me, "VmRSS").unwrap();

    // The engine is looked at every 50 ms through the flood: the longest wait for its state.
    let flooding = Arc::new(AtomicBool::new(true));
    let watcher = {
        let (shared, flooding) = (Arc::clone(&engine.shared), Arc::clone(&flooding));
        std::thread::spawn(move || {
            let mut longest = Duration::ZERO;
            while flooding.load(Ordering::Relaxed) {
                let asked = Instant::now();
                drop(lock(&shared));
                longest = longest.max(asked.elapsed());
                std::thread::sleep(Duration::from_millis(50));
            }
            longest
        })
    };
    let started = Instant::now();
    let answered = flood_invites(phone);
    let took = started.elapsed();
    flooding.store(false, Ordering::Relaxed);
    let longest = watcher.join().unwrap();
    let after = memory_mb(me, "VmRSS").unwrap();
    eprintln!(
        "{INVITES} INVITEs in {took:.1?}: {answered} answered; RSS {before:.1} -> {after:.1} MB; \
         the engine's state waited for at most {longest:?}; phone {:?}",
        lock(&engine.shared).phone
    );
    assert!(
        after - before < MAX_GROWTH_MB,
        "the app grew from {before:.1} to {after:.1} MB"
    );
    assert!(
        longest < Duration::from_secs(1),
        "the engine stalled {longest:?}"
    );

    // A flood call left ringing is turned down; a fresh listener registers, free again.
    let registers = registrar.contact.lock().unwrap().1;
    if lock(&engine.shared).phone.ringing.is_some() {
        engine.send(Command::Phone(PhoneCommand::Decline));
        let deadline = Instant::now() + limit;
        while registrar.contact.lock().unwrap().1 == registers {
            assert!(
                Instant::now() < deadline,
                "no new REGISTER after the decline"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    common::app::wait_for(&engine, "registered and idle", limit, |s| {
        registered(s) && s.phone.ringing.is_none() && !s.call.in_call
    });
    let phone = registrar.contact.lock().unwrap().0.expect("a Contact");

    // A real caller: it rings, is answered and heard.
    let speech = common::repo_file("assets/speech/demo.wav");
    let mut caller = common::lipcall()
        .args(["sip", "call", &format!("sip:alice@{phone}")])
        .arg("--play")
        .arg(&speech)
        .args(["--codec", "pcmu", "--seconds", "10"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let caller_log = {
        let mut pipe = caller.stderr.take().unwrap();
        std::thread::spawn(move || {
            let mut text = String::new();
            let _ = std::io::Read::read_to_string(&mut pipe, &mut text);
            text
        })
    };
    let rings = |s: &Shared| {
        s.phone
            .ringing
            .as_deref()
            .is_some_and(|c| !c.contains("flood"))
    };
    let deadline = Instant::now() + limit;
    while !rings(&lock(&engine.shared)) {
        if Instant::now() > deadline || caller.try_wait().unwrap().is_some() {
            let _ = caller.kill();
            let _ = caller.wait();
            panic!(
                "the real call never rang: phone {:?}; caller: {}",
                lock(&engine.shared).phone,
                caller_log.join().unwrap()
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    engine.send(Command::Phone(PhoneCommand::Answer));
    common::app::wait_for(&engine, "the caller is heard", limit, |s| {
        s.call.in_call
            && s.peers
                .views()
                .iter()
                .any(|p| !p.is_demo && p.frames_received > 50)
    });
    engine.send(Command::Leave);
    let deadline = Instant::now() + limit;
    while caller.try_wait().unwrap().is_none() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = caller.kill();
    let _ = caller.wait();
}
