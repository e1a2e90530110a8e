//! `receive --mumble` against a hostile Mumble server written here (TLS with a certificate made
//! in the test, Mumble's framing, on 127.0.0.1): one that moves us between two crowded channels
//! 300 times, one that adds and removes 300,000 users (each saying a word before it goes), one
//! that goes silent with the connection open, and one that dribbles its TLS handshake. The
//! receive must keep its memory and its log small, end on `--seconds`, and notice the silence.

mod common;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::process::{Child, Stdio};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use openssl::asn1::Asn1Time;
use openssl::hash::MessageDigest;
use openssl::pkey::PKey;
use openssl::rsa::Rsa;
use openssl::ssl::{SslAcceptor, SslMethod, SslStream};
use openssl::x509::{X509, X509NameBuilder};

use lipcall::net::mumble::messages::{
    self, ChannelState, Deframer, MessageType, ServerSync, UserRemove, UserState,
};
use lipcall::net::mumble::voice;

use common::mumble::lipcall_as;
use common::rss_mb;

type Tls = SslStream<TcpStream>;

/// A TLS acceptor with a self-signed certificate, as a Mumble server has.
fn acceptor() -> SslAcceptor {
    let key = PKey::from_rsa(Rsa::generate(2048).unwrap()).unwrap();
    let mut name = X509NameBuilder::new().unwrap();
    name.append_entry_by_text("CN", "hostile murmur").unwrap();
    let name = name.build();
    let mut cert = X509::builder().unwrap();
    cert.set_version(2).unwrap();
    cert.set_subject_name(&name).unwrap();
    cert.set_issuer_name(&name).unwrap();
    cert.set_pubkey(&key).unwrap();
    cert.set_not_before(&Asn1Time::days_from_now(0).unwrap())
        .unwrap();
    cert.set_not_after(&Asn1Time::days_from_now(2).unwrap())
        .unwrap();
    cert.sign(&key, MessageDigest::sha256()).unwrap();
    let mut builder = SslAcceptor::mozilla_intermediate_v5(SslMethod::tls()).unwrap();
    builder.set_private_key(&key).unwrap();
    builder.set_certificate(&cert.build()).unwrap();
    builder.build()
}

/// A server on a loopback port that hands each connection (numbered from 0) to `behave` on a
/// thread of its own.
struct Hostile {
    port: u16,
    accepted: Arc<AtomicUsize>,
    stop: Arc<AtomicBool>,
}

impl Hostile {
    fn start(behave: impl Fn(usize, TcpStream, &SslAcceptor) + Send + Sync + 'static) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        listener.set_nonblocking(true).unwrap();
        let port = listener.local_addr().unwrap().port();
        let accepted = Arc::new(AtomicUsize::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let (count, halt) = (accepted.clone(), stop.clone());
        let behave = Arc::new(behave);
        let tls = Arc::new(acceptor());
        std::thread::spawn(move || {
            while !halt.load(Ordering::Relaxed) {
                match listener.accept() {
                    Ok((tcp, _)) => {
                        tcp.set_nonblocking(false).unwrap();
                        let index = count.fetch_add(1, Ordering::Relaxed);
                        let (behave, tls) = (behave.clone(), tls.clone());
                        std::thread::spawn(move || behave(index, tcp, &tls));
                    }
                    Err(_) => std::thread::sleep(Duration::from_millis(10)),
                }
            }
        });
        Self {
            port,
            accepted,
            stop,
        }
    }

    fn address(&self) -> String {
        format!("127.0.0.1:{}", self.port)
    }
}

impl Drop for Hostile {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// The TLS handshake, then the client's messages up to its Authenticate.
fn greet(tcp: TcpStream, tls: &SslAcceptor) -> Option<Tls> {
    tcp.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
    let mut stream = tls.accept(tcp).ok()?;
    let mut deframer = Deframer::default();
    let mut buf = [0u8; 4096];
    loop {
        let n = stream.read(&mut buf).ok()?;
        if n == 0 {
            return None;
        }
        deframer.push(&buf[..n]);
        while let Ok(Some((kind, _))) = deframer.next_frame() {
            if kind == MessageType::Authenticate as u16 {
                return Some(stream);
            }
        }
    }
}

/// Reads and drops what the client sends, answering nothing, until it goes away.
fn ignore(stream: &mut Tls) {
    let _ = stream
        .get_ref()
        .set_read_timeout(Some(Duration::from_secs(120)));
    let mut buf = [0u8; 4096];
    while matches!(stream.read(&mut buf), Ok(n) if n > 0) {}
}

/// Takes the client's hello and answers with the header of a TLS record of 16 kB, then its
/// bytes one every 2 s: a handshake that never ends, though the client never waits 2 s in vain.
fn dribble(tcp: &mut TcpStream) {
    let _ = tcp.set_read_timeout(Some(Duration::from_secs(1)));
    let mut buf = [0u8; 4096];
    let _ = tcp.read(&mut buf);
    if tcp.write_all(&[0x16, 0x03, 0x03, 0x40, 0x00]).is_err() {
        return;
    }
    for _ in 0..30 {
        std::thread::sleep(Duration::from_secs(2));
        if tcp.write_all(&[0x02]).is_err() {
            return;
        }
    }
}

/// Our own session on every hostile server.
const US: u32 = 1;

fn channel(id: u32, name: &str) -> Vec<u8> {
    messages::frame(
        MessageType::ChannelState,
        &ChannelState {
            channel_id: Some(id),
            parent: (id > 0).then_some(0),
            name: Some(name.into()),
            max_users: None,
        },
    )
}

fn user(session: u32, name: &str, channel: u32) -> Vec<u8> {
    messages::frame(
        MessageType::UserState,
        &UserState {
            session: Some(session),
            name: Some(name.into()),
            channel_id: Some(channel),
            ..Default::default()
        },
    )
}

fn moved(channel: u32) -> Vec<u8> {
    messages::frame(
        MessageType::UserState,
        &UserState {
            session: Some(US),
            channel_id: Some(channel),
            ..Default::default()
        },
    )
}

fn removed(session: u32) -> Vec<u8> {
    messages::frame(
        MessageType::UserRemove,
        &UserRemove {
            session: Some(session),
            ..Default::default()
        },
    )
}

/// Channels Root (0) and Side (1), `users`, us in Root, and the ServerSync.
fn welcome(users: &[u8]) -> Vec<u8> {
    let mut out = channel(0, "Root");
    out.extend(channel(1, "Side"));
    out.extend_from_slice(users);
    out.extend(user(US, "Rx", 0));
    out.extend(messages::frame(
        MessageType::ServerSync,
        &ServerSync {
            session: Some(US),
            welcome_text: Some("hostile".into()),
            ..Default::default()
        },
    ));
    out
}

/// A running `lipcall receive --mumble`, its stderr watched: lines counted, the first and last
/// kept, and when it said it had joined.
struct Receive {
    child: Child,
    log: Arc<Mutex<Log>>,
    started: Instant,
}

#[derive(Default)]
struct Log {
    lines: usize,
    first: Vec<String>,
    last: std::collections::VecDeque<String>,
    joined: Option<Instant>,
    closed: bool,
}

impl Log {
    fn text(&self) -> String {
        format!(
            "{} lines:\n{}\n...\n{}",
            self.lines,
            self.first.join("\n"),
            self.last.iter().cloned().collect::<Vec<_>>().join("\n")
        )
    }

    fn contains(&self, what: &str) -> bool {
        self.first
            .iter()
            .chain(&self.last)
            .any(|l| l.contains(what))
    }
}

impl Receive {
    fn start(dir: &std::path::Path, server: &str, seconds: u32) -> Self {
        let mut child = lipcall_as(dir, "rx")
            .args(["receive", "--mumble", server, "--name", "Rx"])
            .args(["--seconds", &seconds.to_string()])
            .stderr(Stdio::piped())
            .stdout(Stdio::null())
            .spawn()
            .unwrap();
        let log = Arc::new(Mutex::new(Log::default()));
        let (stderr, shared) = (child.stderr.take().unwrap(), log.clone());
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines() {
                let Ok(line) = line else { break };
                let mut log = shared.lock().unwrap();
                log.lines += 1;
                if log.joined.is_none() && line.contains("joined as session") {
                    log.joined = Some(Instant::now());
                }
                if log.first.len() < 40 {
                    log.first.push(line);
                } else {
                    log.last.push_back(line);
                    if log.last.len() > 40 {
                        log.last.pop_front();
                    }
                }
            }
            shared.lock().unwrap().closed = true;
        });
        Self {
            child,
            log,
            started: Instant::now(),
        }
    }

    /// Waits up to `limit` for the exit, sampling the resident memory; the peak RSS in MB and
    /// when it exited (`None`: killed at `limit`).
    fn watch(&mut self, limit: Duration) -> (f64, Option<Instant>) {
        let pid = self.child.id();
        let mut peak: f64 = 0.0;
        loop {
            if let Some(mb) = rss_mb(pid) {
                peak = peak.max(mb);
            }
            if self.child.try_wait().unwrap().is_some() {
                let ended = Instant::now();
                // The reader has the last lines once the pipe closes.
                let wait = Instant::now() + Duration::from_secs(5);
                while !self.log.lock().unwrap().closed && Instant::now() < wait {
                    std::thread::sleep(Duration::from_millis(10));
                }
                return (peak, Some(ended));
            }
            if self.started.elapsed() > limit {
                let _ = self.child.kill();
                let _ = self.child.wait();
                return (peak, None);
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for Receive {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn a_server_moving_us_300_times_between_crowded_channels_neither_floods_nor_holds_the_call() {
    let server = Hostile::start(|_, tcp, tls| {
        let Some(mut stream) = greet(tcp, tls) else {
            return;
        };
        let mut crowd = Vec::new();
        for i in 0..8000u32 {
            crowd.extend(user(100 + i, &format!("user{i}"), i % 2));
        }
        if stream.write_all(&welcome(&crowd)).is_err() {
            return;
        }
        // Give the client a moment to settle into the receive loop, then the storm.
        std::thread::sleep(Duration::from_millis(500));
        let mut storm = Vec::new();
        for m in 0..300u32 {
            storm.extend(moved(1 - m % 2));
        }
        if stream.write_all(&storm).is_err() {
            return;
        }
        ignore(&mut stream);
    });
    let dir = tempfile::tempdir().unwrap();
    let seconds = 6;
    let mut rx = Receive::start(dir.path(), &server.address(), seconds);
    let (peak, ended) = rx.watch(Duration::from_secs(40));
    let log = rx.log.lock().unwrap();
    let text = log.text();
    eprintln!("peak RSS {peak:.1} MB; {text}");
    let joined = log.joined.unwrap_or_else(|| panic!("never joined: {text}"));
    let ended = ended.unwrap_or_else(|| panic!("still running after 40 s: {text}"));
    let took = ended.saturating_duration_since(joined);
    eprintln!("ended {took:?} after joining (--seconds {seconds})");
    assert!(
        took < Duration::from_secs(u64::from(seconds) + 2),
        "ended {took:?} after joining, with --seconds {seconds}: {text}"
    );
    assert!(peak < 100.0, "peak RSS {peak:.1} MB: {text}");
    assert!(log.lines < 200, "{text}");
    assert!(
        log.contains("\"user0\" (session 100)"),
        "the first of the channel are still named: {text}"
    );
    assert!(log.contains("too fast to list one by one"), "{text}");
}

#[test]
fn a_server_adding_and_removing_300000_speakers_keeps_memory_flat() {
    let server = Hostile::start(|_, tcp, tls| {
        let Some(mut stream) = greet(tcp, tls) else {
            return;
        };
        if stream.write_all(&welcome(&[])).is_err() {
            return;
        }
        // Each newcomer says one word (a tunnelled Opus packet) and leaves.
        let word = [0x08u8, 0xaa, 0x55, 0xaa, 0x55];
        let mut batch = Vec::new();
        for i in 0..300_000u32 {
            let session = 100 + i;
            batch.extend(user(session, &format!("guest{i}"), 0));
            batch.extend(messages::tunnel(&voice::server_opus(
                session, 0, &word, false,
            )));
            batch.extend(removed(session));
            if batch.len() > 64 * 1024 {
                if stream.write_all(&batch).is_err() {
                    return;
                }
                batch.clear();
            }
        }
        let _ = stream.write_all(&batch);
        ignore(&mut stream);
    });
    let dir = tempfile::tempdir().unwrap();
    let seconds = 15;
    let mut rx = Receive::start(dir.path(), &server.address(), seconds);
    let (peak, ended) = rx.watch(Duration::from_secs(45));
    let log = rx.log.lock().unwrap();
    let text = log.text();
    eprintln!("peak RSS {peak:.1} MB; {text}");
    assert!(ended.is_some(), "still running after 45 s: {text}");
    assert!(peak < 100.0, "peak RSS {peak:.1} MB: {text}");
    assert!(log.lines < 300, "{text}");
}

#[test]
fn a_server_gone_silent_is_noticed_and_a_reconnect_stuck_in_its_handshake_keeps_seconds() {
    let server = Hostile::start(|index, mut tcp, tls| {
        if index == 0 {
            // Joins us, then says nothing more, the connection open.
            if let Some(mut stream) = greet(tcp, tls)
                && stream.write_all(&welcome(&[])).is_ok()
            {
                ignore(&mut stream);
            }
        } else {
            // The reconnect: a handshake that never finishes.
            dribble(&mut tcp);
        }
    });
    let dir = tempfile::tempdir().unwrap();
    let seconds = 27;
    let mut rx = Receive::start(dir.path(), &server.address(), seconds);
    let (_, ended) = rx.watch(Duration::from_secs(50));
    let log = rx.log.lock().unwrap();
    let text = log.text();
    let joined = log.joined.unwrap_or_else(|| panic!("never joined: {text}"));
    let ended = ended.unwrap_or_else(|| panic!("still running after 50 s: {text}"));
    let took = ended.saturating_duration_since(joined);
    eprintln!("ended {took:?} after joining (--seconds {seconds}): {text}");
    assert!(
        log.contains("lost the Mumble server") && log.contains("nothing from the server"),
        "{text}"
    );
    assert!(
        server.accepted.load(Ordering::Relaxed) >= 2,
        "no reconnect: {text}"
    );
    assert!(
        took < Duration::from_secs(u64::from(seconds) + 2),
        "ended {took:?} after joining, with --seconds {seconds}: {text}"
    );
}

#[test]
fn a_dribbled_tls_handshake_times_out_with_a_clear_error() {
    let server = Hostile::start(|_, mut tcp, _| dribble(&mut tcp));
    let dir = tempfile::tempdir().unwrap();
    // --seconds bounds a join too: longer than the handshake's own 10 s, so that it is the
    // handshake's timeout that ends this one.
    let mut rx = Receive::start(dir.path(), &server.address(), 25);
    let (_, ended) = rx.watch(Duration::from_secs(30));
    let took = rx.started.elapsed();
    let log = rx.log.lock().unwrap();
    let text = log.text();
    eprintln!("took {took:?}: {text}");
    assert!(ended.is_some(), "still in the handshake after 30 s: {text}");
    assert_eq!(
        rx.child.try_wait().unwrap().and_then(|s| s.code()),
        Some(1),
        "{text}"
    );
    assert!(took < Duration::from_secs(16), "took {took:?}: {text}");
    assert!(log.contains("TLS handshake"), "{text}");
}
