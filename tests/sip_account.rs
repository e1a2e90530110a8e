//! The SIP account against hostile servers on 127.0.0.1, each a raw UDP socket of the test: a
//! registrar answering 423 Interval Too Brief forever costs two REGISTERs and a clear error (the
//! command line's exit, the app's "not registered"); a callee that challenges our INVITE itself
//! gets no digest, in a foreign realm or in ours; and the password, the SRTP keys and the
//! digest stay out of the arguments, core dumps and a trace-level log of a call.

mod common;

use std::net::{SocketAddr, UdpSocket};
use std::path::PathBuf;
use std::process::{Command, Output, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use lipcall::app::engine::{Command as EngineCommand, lock};
use lipcall::app::sip_call::PhoneCommand;
use lipcall::net::sip::agent::Account;

const PASSWORD: &str = "correct-horse-battery-staple";
const REALM: &str = "lipcall.test";
/// The callee's SDES key: 30 bytes of key and salt, in base64.
const CALLEE_KEY: &str = "Y2FsbGVlLW1hc3Rlci1rZXkrc2FsdC0zMGJ5dGVz";

/// A SIP request as a fake server got it.
#[derive(Clone, Debug)]
struct Sip {
    text: String,
}

impl Sip {
    fn method(&self) -> &str {
        self.text.split(' ').next().unwrap_or("")
    }

    fn headers<'s>(&'s self, name: &str) -> impl Iterator<Item = &'s str> {
        let name = name.to_owned();
        self.head().lines().filter_map(move |line| {
            let (n, value) = line.split_once(':')?;
            n.trim().eq_ignore_ascii_case(&name).then(|| value.trim())
        })
    }

    fn header(&self, name: &str) -> Option<&str> {
        self.headers(name).next()
    }

    fn head(&self) -> &str {
        self.text.split("\r\n\r\n").next().unwrap_or("")
    }

    fn body(&self) -> &str {
        self.text.split_once("\r\n\r\n").map_or("", |(_, b)| b)
    }

    /// A response with the request's Via, From, To (tagged), Call-ID and CSeq, `extra` header
    /// lines and an SDP `body`.
    fn reply(&self, status: &str, extra: &str, body: &str) -> String {
        let mut out = format!("SIP/2.0 {status}\r\n");
        for via in self.headers("Via") {
            out += &format!("Via: {via}\r\n");
        }
        for name in ["From", "Call-ID", "CSeq"] {
            out += &format!("{name}: {}\r\n", self.header(name).unwrap_or(""));
        }
        let to = self.header("To").unwrap_or("");
        let tag = if to.contains(";tag=") {
            ""
        } else {
            ";tag=fake"
        };
        out += &format!("To: {to}{tag}\r\n{extra}");
        if !body.is_empty() {
            out += "Content-Type: application/sdp\r\n";
        }
        out + &format!("Content-Length: {}\r\n\r\n{body}", body.len())
    }
}

/// A UDP socket on 127.0.0.1 answering each SIP request as `answer` says, keeping them all.
struct FakeServer {
    addr: SocketAddr,
    seen: Arc<Mutex<Vec<Sip>>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

fn serve(answer: impl Fn(&Sip) -> Option<String> + Send + 'static) -> FakeServer {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    socket
        .set_read_timeout(Some(Duration::from_millis(50)))
        .unwrap();
    let addr = socket.local_addr().unwrap();
    let seen = Arc::new(Mutex::new(Vec::new()));
    let stop = Arc::new(AtomicBool::new(false));
    let thread = {
        let (seen, stop) = (Arc::clone(&seen), Arc::clone(&stop));
        std::thread::spawn(move || {
            let mut buf = vec![0u8; 65536];
            while !stop.load(Ordering::Relaxed) {
                let Ok((n, from)) = socket.recv_from(&mut buf) else {
                    continue;
                };
                let request = Sip {
                    text: String::from_utf8_lossy(&buf[..n]).into_owned(),
                };
                if request.text.starts_with("SIP/2.0") {
                    continue;
                }
                if let Some(response) = answer(&request) {
                    let _ = socket.send_to(response.as_bytes(), from);
                }
                seen.lock().unwrap().push(request);
            }
        })
    };
    FakeServer {
        addr,
        seen,
        stop,
        thread: Some(thread),
    }
}

impl FakeServer {
    fn seen(&self, method: &str) -> Vec<Sip> {
        let seen = self.seen.lock().unwrap();
        seen.iter()
            .filter(|r| r.method() == method)
            .cloned()
            .collect()
    }

    fn wait_for(&self, method: &str, limit: Duration) -> Sip {
        let deadline = Instant::now() + limit;
        loop {
            if let Some(request) = self.seen(method).pop() {
                return request;
            }
            assert!(Instant::now() < deadline, "no {method} came");
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for FakeServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// A registrar of [`REALM`] that challenges every REGISTER without credentials and takes the
/// rest (it checks no digest: the test looks at what was sent).
fn registrar() -> FakeServer {
    serve(|request| {
        if request.method() != "REGISTER" {
            return None;
        }
        if request.header("Authorization").is_none() {
            let challenge = format!(
                "WWW-Authenticate: Digest realm=\"{REALM}\", nonce=\"registrar-nonce\", algorithm=MD5\r\n"
            );
            return Some(request.reply("401 Unauthorized", &challenge, ""));
        }
        let contact = request.header("Contact").unwrap_or("<sip:x@127.0.0.1>");
        Some(request.reply("200 OK", &format!("Contact: {contact};expires=300\r\n"), ""))
    })
}

/// A registrar that answers every REGISTER 423 Interval Too Brief, asking for `min_expires`.
fn registrar_423(min_expires: u32) -> FakeServer {
    serve(move |request| {
        (request.method() == "REGISTER").then(|| {
            request.reply(
                "423 Interval Too Brief",
                &format!("Min-Expires: {min_expires}\r\n"),
                "",
            )
        })
    })
}

fn speech() -> PathBuf {
    common::repo_file("assets/speech/demo.wav")
}

fn account_arg(registrar: &FakeServer) -> String {
    format!("sip:alice@{}", registrar.addr)
}

/// The value of `name=` in a header (quoted or not).
fn param<'h>(header: &'h str, name: &str) -> Option<&'h str> {
    let at = header.find(&format!("{name}="))? + name.len() + 1;
    let value = header[at..].trim_start_matches('"');
    value.split(['"', ',', ' ', '\r']).next()
}

/// Runs `lipcall` with `args` until it exits or `limit` passes (then it is killed).
fn lipcall_within(args: &[&str], password: &str, limit: Duration) -> (Output, Duration) {
    let started = Instant::now();
    let mut child = common::lipcall()
        .args(args)
        .env("LIPCALL_SIP_PASSWORD", password)
        .env_remove("RUST_LOG")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    while started.elapsed() < limit && child.try_wait().unwrap().is_none() {
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = child.kill();
    (child.wait_with_output().unwrap(), started.elapsed())
}

#[test]
fn a_registrar_that_answers_423_forever_costs_two_registers_and_a_clear_error() {
    for (min_expires, registers, said) in [
        (3600, 2, "answered 423 Interval Too Brief again"),
        (86_400, 1, "demands registrations of at least 86400 s"),
    ] {
        let registrar = registrar_423(min_expires);
        let listen = format!("127.0.0.1:{}", common::sip::free_port(false));
        let account = account_arg(&registrar);
        let play = speech();
        let args = [
            "sip",
            "answer",
            "--listen",
            &listen,
            "--account",
            &account,
            "--play",
            play.to_str().unwrap(),
        ];
        // No --seconds: only the error may end it.
        let (out, took) = lipcall_within(&args, PASSWORD, Duration::from_secs(20));
        let log = String::from_utf8_lossy(&out.stderr).into_owned();
        let sent = registrar.seen("REGISTER").len();
        eprintln!("Min-Expires {min_expires}: {sent} REGISTERs, ended after {took:?}");
        assert_eq!(
            out.status.code(),
            Some(1),
            "{sent} REGISTERs in {took:?}: {log}"
        );
        assert_eq!(sent, registers, "{log}");
        let last = log.lines().last().unwrap_or("");
        eprintln!("{last}");
        assert!(
            last.starts_with("lipcall: ") && last.contains(said),
            "{log}"
        );
        assert!(took < Duration::from_secs(10), "{took:?}");
    }
}

#[test]
fn the_password_never_comes_from_the_arguments() {
    let play = speech();
    let answer = |extra: &[&str]| {
        common::lipcall()
            .args(["sip", "answer", "--listen", "127.0.0.1:0", "--account"])
            .arg("sip:alice@127.0.0.1:9")
            .arg("--play")
            .arg(&play)
            .args(extra)
            .env_remove("LIPCALL_SIP_PASSWORD")
            .output()
            .unwrap()
    };
    let out = answer(&[]);
    let log = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{log}");
    assert!(
        log.contains("needs its password: set LIPCALL_SIP_PASSWORD"),
        "{log}"
    );
    let out = answer(&["--password", PASSWORD]);
    assert_eq!(out.status.code(), Some(2), "a usage error");
}

#[test]
fn the_apps_listener_stops_at_a_423_loop_and_says_so() {
    let registrar = registrar_423(3600);
    let engine = common::app::headless_engine("Alice", None);
    let account = Account::parse(&account_arg(&registrar), PASSWORD).unwrap();
    let started = Instant::now();
    engine.send(EngineCommand::Phone(PhoneCommand::Account(Some(account))));
    let failed = |line: &str| line.starts_with("not registered") && line.contains("423");
    let deadline = started + Duration::from_secs(15);
    while !failed(&lock(&engine.shared).phone.registration) {
        let sent = registrar.seen("REGISTER").len();
        assert!(
            Instant::now() < deadline,
            "{sent} REGISTERs; phone {:?}",
            lock(&engine.shared).phone
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    // The listener waits before it tries again: nothing more for a while.
    std::thread::sleep(Duration::from_secs(5));
    let sent = registrar.seen("REGISTER").len();
    let rate = sent as f64 / started.elapsed().as_secs_f64();
    eprintln!("{sent} REGISTERs in {:?}", started.elapsed());
    assert!(
        sent <= 2 && rate < 3.0,
        "{sent} REGISTERs ({rate:.1} a second)"
    );
    let line = lock(&engine.shared).phone.registration.clone();
    assert!(line.contains("trying again in 30 s"), "{line}");
}

/// A callee that answers every INVITE with a 401 (or with `proxy`, a 407) of `realm`.
fn challenging_callee(realm: &'static str, proxy: bool) -> FakeServer {
    serve(move |request| {
        let header = if proxy {
            "Proxy-Authenticate"
        } else {
            "WWW-Authenticate"
        };
        let challenge = format!(
            "{header}: Digest realm=\"{realm}\", nonce=\"callee-nonce\", algorithm=MD5\r\n"
        );
        let status = if proxy {
            "407 Proxy Authentication Required"
        } else {
            "401 Unauthorized"
        };
        (request.method() == "INVITE").then(|| request.reply(status, &challenge, ""))
    })
}

#[test]
fn a_callee_that_asks_for_our_password_gets_no_digest() {
    let dir = tempfile::tempdir().unwrap();
    let password_file = dir.path().join("password");
    std::fs::write(&password_file, format!("{PASSWORD}\n")).unwrap();
    // A realm of its own, and ours (which a callee can read in any of our digests).
    for (realm, proxy) in [("elsewhere.example", false), (REALM, true)] {
        let registrar = registrar();
        let callee = challenging_callee(realm, proxy);
        let target = format!("sip:bob@{}", callee.addr);
        let account = account_arg(&registrar);
        let play = speech();
        let args = [
            "sip",
            "call",
            &target,
            "--account",
            &account,
            "--password-file",
            password_file.to_str().unwrap(),
            "--play",
            play.to_str().unwrap(),
            "--seconds",
            "15",
        ];
        // The environment's password is not the file's: the file is used.
        let (out, took) = lipcall_within(&args, "not-this-one", Duration::from_secs(20));
        let log = String::from_utf8_lossy(&out.stderr).into_owned();
        let registers = registrar.seen("REGISTER");
        assert!(
            registers
                .iter()
                .any(|r| r.header("Authorization").is_some()),
            "the registrar's own challenge is answered: {log}"
        );
        let invites = callee.seen("INVITE");
        for invite in &invites {
            for header in ["Authorization", "Proxy-Authorization"] {
                assert!(
                    invite.header(header).is_none(),
                    "realm {realm}: the callee got a digest: {}",
                    invite.text
                );
            }
        }
        assert_eq!(invites.len(), 1, "realm {realm}: {log}");
        assert_eq!(out.status.code(), Some(1), "{log}");
        eprintln!("{}", log.lines().last().unwrap_or(""));
        let said = format!("asked for our password in realm \"{realm}\"");
        assert!(log.lines().last().unwrap_or("").contains(&said), "{log}");
        assert!(took < Duration::from_secs(10), "{took:?}: {log}");
        assert!(!log.contains(PASSWORD), "{log}");
    }
}

/// A callee that answers with SRTP keyed by [`CALLEE_KEY`] and takes the BYE.
fn answering_callee(media: SocketAddr) -> FakeServer {
    serve(move |request| match request.method() {
        "INVITE" => {
            let sdp = format!(
                "v=0\r\no=callee 1 1 IN IP4 127.0.0.1\r\ns=-\r\nc=IN IP4 127.0.0.1\r\nt=0 0\r\n\
                 m=audio {} RTP/SAVP 0\r\na=rtpmap:0 PCMU/8000\r\n\
                 a=crypto:1 AES_CM_128_HMAC_SHA1_80 inline:{CALLEE_KEY}\r\n",
                media.port()
            );
            let contact = format!("Contact: <sip:bob@{}>\r\n", request_target(request));
            Some(request.reply("200 OK", &contact, &sdp))
        }
        "BYE" => Some(request.reply("200 OK", "", "")),
        _ => None,
    })
}

/// Where a request was sent: the HOST:PORT of its Request-URI.
fn request_target(request: &Sip) -> String {
    let uri = request.text.split(' ').nth(1).unwrap_or("");
    uri.rsplit('@').next().unwrap_or(uri).to_owned()
}

#[test]
fn a_traced_srtp_call_shows_no_password_key_or_digest_and_cannot_dump_core() {
    let registrar = registrar();
    let media = UdpSocket::bind("127.0.0.1:0").unwrap();
    let callee = answering_callee(media.local_addr().unwrap());
    let target = format!("sip:bob@{}", callee.addr);
    let play = speech();
    // Core files allowed where it starts, as a user's shell may: lipcall must turn them off.
    let mut child = Command::new("sh")
        .args(["-c", "ulimit -c unlimited && exec \"$0\" \"$@\""])
        .arg(env!("CARGO_BIN_EXE_lipcall"))
        .args(["sip", "call", &target, "--srtp", "--seconds", "4"])
        .args(["--account", &account_arg(&registrar)])
        .arg("--play")
        .arg(&play)
        .env("LIPCALL_SIP_PASSWORD", PASSWORD)
        .env("RUST_LOG", "trace")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let invite = callee.wait_for("INVITE", Duration::from_secs(10));
    let proc = PathBuf::from(format!("/proc/{}", child.id()));
    let cmdline = std::fs::read(proc.join("cmdline")).unwrap();
    let limits = std::fs::read_to_string(proc.join("limits")).unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    while Instant::now() < deadline && child.try_wait().unwrap().is_none() {
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = child.kill();
    let out = child.wait_with_output().unwrap();
    let log = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{}", log.lines().last().unwrap_or(""));
    assert_eq!(callee.seen("BYE").len(), 1, "the call was hung up");

    assert!(
        !String::from_utf8_lossy(&cmdline).contains(PASSWORD),
        "the password is in the arguments"
    );
    let core = limits
        .lines()
        .find(|l| l.starts_with("Max core file size"))
        .unwrap_or("");
    assert_eq!(
        core.split_whitespace().collect::<Vec<_>>()[4..6],
        ["0", "0"],
        "{core}"
    );

    let digest = registrar
        .seen("REGISTER")
        .iter()
        .find_map(|r| param(r.header("Authorization")?, "response").map(str::to_owned))
        .expect("the registrar's challenge was answered");
    let our_key = invite
        .body()
        .split("inline:")
        .nth(1)
        .and_then(|k| k.split(['|', '\r', '\n']).next())
        .expect("our offer carries a key")
        .to_owned();
    assert!(
        log.contains("REGISTER sip:") && log.contains("a=crypto:1"),
        "the messages are in the trace: {}",
        log.len()
    );
    for (what, secret) in [
        ("the password", PASSWORD),
        ("the digest response", &digest),
        ("our SRTP key", &our_key),
        ("the callee's SRTP key", CALLEE_KEY),
    ] {
        assert!(secret.len() >= 20, "{what}: {secret:?}");
        let shown = log.lines().find(|l| l.contains(secret));
        assert!(shown.is_none(), "{what} is in the log: {shown:?}");
    }
}
