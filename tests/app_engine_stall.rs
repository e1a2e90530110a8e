//! The app's engine never waits on a peer or a server: dialling a SIP host that never answers,
//! leaving a Janus room whose server hangs, and joining a Mumble server that accepts and says
//! nothing all happen off the worker, whose every pass comes within 50 ms of the last (a pass
//! that blocks holds up every peer's audio and face). So does looking up the host of a call
//! (direct, SIP, a Janus room) when the resolver never answers, deriving a passphrase's room key,
//! and opening an output device or a microphone (the
//! PulseAudio null sink and its monitor).

mod common;

use std::net::{TcpListener, UdpSocket};
use std::process::Command as Process;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use lipcall::app::engine::{CallSpec, Command, Engine, lock};
use lipcall::app::sip_call::{PhoneCommand, PhoneNetwork};
use lipcall::audio::DeviceChoice;
use lipcall::codec::any::Codec;
use lipcall::net::sip::register::Account;

/// The longest the worker's loop may take between two passes, beyond what a busy machine
/// delays every thread ([`Oversleep`]).
const STALL: Duration = Duration::from_millis(50);

fn call(engine: &Engine, address: &str, room: Option<&str>) {
    engine.send(Command::Call(Box::new(CallSpec {
        address: address.into(),
        room: room.map(Into::into),
        name: "Eve".into(),
        codec: Codec::Opus,
        ..CallSpec::default()
    })));
}

/// How late a thread of this process that only sleeps woke, at worst, while it ran. A busy
/// machine delays every thread alike (a CI run once read a pass of 52 ms with nothing waited
/// on); a worker that waits on a peer is late alone, by the wait's timeout.
struct Oversleep {
    stop: Arc<AtomicBool>,
    sleeper: std::thread::JoinHandle<Duration>,
}

impl Oversleep {
    const NAP: Duration = Duration::from_millis(5);

    fn start() -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = Arc::clone(&stop);
        let sleeper = std::thread::spawn(move || {
            let mut worst = Duration::ZERO;
            while !stopped.load(Ordering::Relaxed) {
                let began = Instant::now();
                std::thread::sleep(Self::NAP);
                worst = worst.max(began.elapsed().saturating_sub(Self::NAP));
            }
            worst
        });
        Self { stop, sleeper }
    }

    fn worst(self) -> Duration {
        self.stop.store(true, Ordering::Relaxed);
        self.sleeper.join().unwrap()
    }
}

/// The longest pass the worker took since the counter was last read, less `noise`'s worst.
fn longest_pass_beyond(engine: &Engine, noise: Oversleep) -> Duration {
    let longest = engine.counters.take_longest_pass();
    let noise = noise.worst();
    if !noise.is_zero() {
        eprintln!("longest pass {longest:?}, of which the machine's own delay {noise:?}");
    }
    longest.saturating_sub(noise)
}

/// Runs for `span`, then returns the longest pass the worker took meanwhile, beyond the
/// machine's own delays.
fn longest_pass_within(engine: &Engine, span: Duration) -> Duration {
    let noise = Oversleep::start();
    std::thread::sleep(span);
    longest_pass_beyond(engine, noise)
}

fn wait_for(engine: &Engine, what: &str, done: impl Fn(&Engine) -> bool) {
    let deadline = Instant::now() + Duration::from_secs(20);
    while !done(engine) {
        assert!(
            Instant::now() < deadline,
            "{what}: {:?}",
            lock(&engine.shared).call
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn dialling_a_silent_sip_host_and_hanging_up_never_stall_the_engine() {
    let silent = UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = silent.local_addr().unwrap().port();
    let engine = common::app::headless_engine("Eve", None);
    let settled = longest_pass_within(&engine, Duration::from_millis(500));
    eprintln!("idle: longest pass {settled:?}");
    engine.counters.take_longest_pass();
    call(&engine, &format!("sip:bob@127.0.0.1:{port}"), None);
    let dialling = longest_pass_within(&engine, Duration::from_secs(2));
    engine.send(Command::Leave);
    let hanging_up = longest_pass_within(&engine, Duration::from_secs(4));
    assert!(
        dialling < STALL && hanging_up < STALL,
        "longest pass while dialling {dialling:?}, while hanging up {hanging_up:?}"
    );
}

/// With a STUN server set, a SIP call's media sockets ask it for their outside address before
/// the INVITE offers it: a STUN server that never answers costs the call 1.5 s, off the worker.
#[test]
fn dialling_sip_with_a_silent_stun_server_never_stalls_the_engine() {
    let silent_sip = UdpSocket::bind("127.0.0.1:0").unwrap();
    let silent_stun = UdpSocket::bind("127.0.0.1:0").unwrap();
    let engine = common::app::headless_engine("Eve", None);
    engine.send(Command::Phone(PhoneCommand::Network(PhoneNetwork {
        stun: Some(silent_stun.local_addr().unwrap().to_string()),
        ..PhoneNetwork::default()
    })));
    longest_pass_within(&engine, Duration::from_millis(500));
    let port = silent_sip.local_addr().unwrap().port();
    call(&engine, &format!("sip:bob@127.0.0.1:{port}"), None);
    let dialling = longest_pass_within(&engine, Duration::from_secs(3));
    assert!(dialling < STALL, "longest pass while dialling {dialling:?}");
    // The call went out once the STUN server's silence was given up on.
    let mut invite = [0u8; 4096];
    silent_sip
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let (n, _) = silent_sip.recv_from(&mut invite).expect("an INVITE");
    assert!(
        invite[..n].starts_with(b"INVITE sip:bob@"),
        "{:?}",
        String::from_utf8_lossy(&invite[..n])
    );
    let mut ask = [0u8; 512];
    silent_stun
        .set_read_timeout(Some(Duration::from_secs(1)))
        .unwrap();
    assert!(silent_stun.recv_from(&mut ask).is_ok(), "STUN was asked");
}

/// With an account whose registrar never answers, dialling stops the account's listener
/// (unregistering waits on the registrar) and the call goes through the same silence.
#[test]
fn dialling_with_an_account_at_a_silent_registrar_never_stalls_the_engine() {
    let silent = UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = silent.local_addr().unwrap().port();
    let engine = common::app::headless_engine("Eve", None);
    let account = Account::parse(&format!("sip:eve@127.0.0.1:{port}"), "not-a-secret").unwrap();
    engine.send(Command::Phone(PhoneCommand::Account(Some(account))));
    std::thread::sleep(Duration::from_secs(1));
    engine.counters.take_longest_pass();
    call(&engine, &format!("sip:bob@127.0.0.1:{port}"), None);
    let dialling = longest_pass_within(&engine, Duration::from_secs(2));
    engine.send(Command::Leave);
    let hanging_up = longest_pass_within(&engine, Duration::from_secs(4));
    engine.send(Command::Phone(PhoneCommand::Account(None)));
    let forgetting = longest_pass_within(&engine, Duration::from_secs(1));
    assert!(
        dialling < STALL && hanging_up < STALL && forgetting < STALL,
        "longest pass while dialling {dialling:?}, hanging up {hanging_up:?}, \
         forgetting the account {forgetting:?}"
    );
}

#[test]
fn joining_a_silent_mumble_server_and_leaving_never_stall_the_engine() {
    let silent = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = silent.local_addr().unwrap().port();
    // Accepts and keeps every connection, saying nothing.
    std::thread::spawn(move || {
        let mut held = Vec::new();
        for stream in silent.incoming().take(8) {
            held.push(stream);
        }
        std::thread::sleep(Duration::from_secs(60));
    });
    let dir = tempfile::tempdir().unwrap();
    let engine = common::app::headless_engine("Eve", None);
    engine.counters.take_longest_pass();
    engine.send(Command::Call(Box::new(CallSpec {
        address: format!("mumble://127.0.0.1:{port}/"),
        name: "Eve".into(),
        codec: Codec::Opus,
        mumble_identity: Some(dir.path().to_path_buf()),
        ..CallSpec::default()
    })));
    let joining = longest_pass_within(&engine, Duration::from_secs(2));
    engine.send(Command::Leave);
    let leaving = longest_pass_within(&engine, Duration::from_secs(3));
    assert!(
        joining < STALL && leaving < STALL,
        "longest pass while joining {joining:?}, while leaving {leaving:?}"
    );
}

#[test]
fn leaving_the_room_of_a_hung_janus_never_stalls_the_engine() {
    if !common::janus::runs_here("leaving_the_room_of_a_hung_janus_never_stalls_the_engine") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let janus = common::janus::start_janus(dir.path());
    let engine = common::app::headless_engine("Eve", None);
    call(&engine, &janus.url, Some("stall-room"));
    wait_for(&engine, "in the Janus room", |e| {
        lock(&e.shared).call.state.starts_with("in ")
    });
    std::thread::sleep(Duration::from_millis(500));
    janus.freeze();
    engine.counters.take_longest_pass();
    engine.send(Command::Leave);
    let leaving = longest_pass_within(&engine, Duration::from_secs(4));
    assert!(leaving < STALL, "longest pass while leaving {leaving:?}");
}

/// Set, to the silent resolver's address, in the run of a test inside a mount namespace whose
/// `/etc/resolv.conf` names that resolver.
const SILENT_RESOLVER: &str = "LIPCALL_TEST_SILENT_RESOLVER";

/// A name only DNS could answer (no hosts file or mDNS has it).
const SLOW_NAME: &str = "slow.lipcall.test";

/// Runs the test `test` again, alone, in a mount namespace of its own whose resolver is a
/// socket on loopback that never answers (glibc then waits 2 s per try, 2 tries). True when
/// it ran there and passed: the caller returns; false when this is that run. Needs root (a
/// mount namespace, port 53): elsewhere the test says why, and fails under CI.
fn ran_with_a_silent_resolver(test: &str) -> bool {
    if std::env::var_os(SILENT_RESOLVER).is_some() {
        return false;
    }
    let probe = Process::new("unshare").args(["--mount", "true"]).output();
    if !probe.is_ok_and(|o| o.status.success()) {
        common::unavailable("a mount namespace of its own (`unshare --mount`, root)");
        return true;
    }
    // An address of loopback's own for each test process, so that parallel runs never meet.
    let pid = std::process::id();
    let resolver = format!("127.83.{}.{}", (pid >> 8) & 0xff, (pid & 0xff).max(1));
    let dir = tempfile::tempdir().unwrap();
    let conf = dir.path().join("resolv.conf");
    std::fs::write(
        &conf,
        format!("nameserver {resolver}\noptions timeout:2 attempts:2\n"),
    )
    .unwrap();
    let run = Process::new("unshare")
        .args(["--mount", "--propagation", "private", "sh", "-c"])
        .arg(r#"mount --bind "$0" /etc/resolv.conf && exec "$@""#)
        .arg(&conf)
        .arg(std::env::current_exe().unwrap())
        .args(["--exact", test, "--nocapture", "--test-threads=1"])
        .env(SILENT_RESOLVER, &resolver)
        .output()
        .unwrap();
    passed_rerun(
        &run,
        test,
        "with a silent resolver (in its own mount namespace)",
    );
    true
}

/// The test `test`, rerun in a child process `with` something, ran there and passed.
fn passed_rerun(run: &std::process::Output, test: &str, with: &str) {
    eprintln!(
        "--- {with}:\n{}{}",
        String::from_utf8_lossy(&run.stdout),
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(run.status.success(), "{test} failed {with}");
    assert!(
        String::from_utf8_lossy(&run.stdout).contains("1 passed"),
        "{test} did not run {with}"
    );
}

#[test]
fn calling_a_host_whose_resolver_never_answers_never_stalls_the_engine() {
    let test = "calling_a_host_whose_resolver_never_answers_never_stalls_the_engine";
    if ran_with_a_silent_resolver(test) {
        return;
    }
    let resolver = std::env::var(SILENT_RESOLVER).unwrap();
    // Takes the queries and never answers (no "port unreachable" either).
    let _silent = UdpSocket::bind((resolver.as_str(), 53)).expect("port 53 on loopback (root)");
    let engine = common::app::headless_engine("Eve", None);
    engine.counters.take_longest_pass();
    let mut longest = Vec::new();
    for (address, room, how) in [
        (format!("{SLOW_NAME}:4000"), None, "a direct call"),
        (format!("sip:bob@{SLOW_NAME}"), None, "a SIP call"),
        (
            format!("http://{SLOW_NAME}:8088/janus"),
            Some("stall-room"),
            "a Janus room",
        ),
    ] {
        call(&engine, &address, room);
        let looking = longest_pass_within(&engine, Duration::from_secs(1));
        let state = lock(&engine.shared).call.state.clone();
        eprintln!("{how}: longest pass in its first second {looking:?}; {state}");
        assert!(state.contains(SLOW_NAME), "{how}: {state}");
        // The resolver gives up (2 tries of 2 s); the call fails naming the host.
        let noise = Oversleep::start();
        wait_for(&engine, "the look-up failed", |e| {
            let s = lock(&e.shared);
            s.call.error.is_some() && !s.call.state.contains("looking up")
        });
        let failed = longest_pass_beyond(&engine, noise).max(looking);
        let error = lock(&engine.shared).call.error.clone().unwrap();
        eprintln!("{how}: longest pass {failed:?}; {error}");
        assert!(error.contains(SLOW_NAME), "{how}: {error}");
        longest.push((how, failed));
    }
    // An account at a registrar of that name: its listener is opened off the worker too.
    let account = Account::parse(&format!("sip:eve@{SLOW_NAME}"), "not-a-secret").unwrap();
    let noise = Oversleep::start();
    engine.send(Command::Phone(PhoneCommand::Account(Some(account))));
    wait_for(&engine, "the registration failed", |e| {
        lock(&e.shared)
            .phone
            .registration
            .starts_with("not registered")
    });
    let registering = longest_pass_beyond(&engine, noise);
    let registration = lock(&engine.shared).phone.registration.clone();
    eprintln!("an account: longest pass {registering:?}; {registration}");
    assert!(registration.contains(SLOW_NAME), "{registration}");
    longest.push(("an account", registering));
    engine.send(Command::Phone(PhoneCommand::Account(None)));
    // A look-up forgotten: leaving while it waits ends the call at once; nothing follows.
    call(&engine, &format!("{SLOW_NAME}:4000"), None);
    std::thread::sleep(Duration::from_millis(300));
    engine.send(Command::Leave);
    let left = longest_pass_within(&engine, Duration::from_secs(6));
    let s = lock(&engine.shared).call.clone();
    assert!(
        s.phase.word() == "idle" && s.error.is_none(),
        "after leaving: {s:?}"
    );
    longest.push(("leaving", left));
    assert!(
        longest.iter().all(|(_, pass)| *pass < STALL),
        "longest passes: {longest:?}"
    );
}

/// A name the resolver knows at once (the hosts file's `localhost`) takes the same road: the
/// call is placed when the answer comes back to the worker.
#[test]
fn a_direct_call_to_a_name_is_placed_once_the_name_is_found() {
    let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = peer.local_addr().unwrap().port();
    let engine = common::app::headless_engine("Eve", None);
    call(&engine, &format!("localhost:{port}"), None);
    wait_for(&engine, "calling the address found", |e| {
        lock(&e.shared).call.state.starts_with("calling ")
    });
    let status = lock(&engine.shared).call.clone();
    assert!(status.in_call && status.error.is_none(), "{status:?}");
    assert!(status.state.contains(&port.to_string()), "{status:?}");
}

#[test]
fn choosing_an_output_device_never_stalls_the_engine() {
    if !common::pulse_running() {
        common::unavailable("PulseAudio (bash .ci/pulse-null-sink.sh)");
        return;
    }
    let engine = common::app::headless_engine("Eve", None);
    longest_pass_within(&engine, Duration::from_millis(500));
    engine.send(Command::SetOutput(DeviceChoice::Default));
    let opening = longest_pass_within(&engine, Duration::from_secs(3));
    wait_for(&engine, "the speaker open", |e| {
        lock(&e.shared).output_status.starts_with("Playing on ")
    });
    // And again, replacing the device just opened (which closes off the worker too).
    engine.counters.take_longest_pass();
    engine.send(Command::SetOutput(DeviceChoice::Default));
    let replacing = longest_pass_within(&engine, Duration::from_secs(3));
    let status = lock(&engine.shared).output_status.clone();
    eprintln!("longest pass opening {opening:?}, replacing {replacing:?}: {status}");
    assert!(
        opening < OPENING_STALL && replacing < OPENING_STALL,
        "longest pass opening {opening:?}, replacing {replacing:?}"
    );
    assert!(status.starts_with("Playing on "), "{status}");
    assert!(lock(&engine.shared).call.error.is_none());
}

/// Opened on the worker, a PulseAudio output held it for about 0.5 s; a loaded machine's
/// passes may pass [`STALL`] without any device in them.
const OPENING_STALL: Duration = Duration::from_millis(200);

fn microphone_open(engine: &Engine) -> bool {
    let s = lock(&engine.shared);
    s.input_status.starts_with("microphone: ") && s.mic.is_some()
}

#[test]
fn choosing_a_microphone_never_stalls_the_engine() {
    if !common::pulse_running() {
        common::unavailable("PulseAudio (bash .ci/pulse-null-sink.sh)");
        return;
    }
    let engine = common::app::engine_with_audio("Eve", None);
    wait_for(&engine, "the microphone open", microphone_open);
    let first = lock(&engine.shared).mic.clone().unwrap();
    first.set_muted(true);
    first.set_push_to_talk(true);
    longest_pass_within(&engine, Duration::from_millis(500));

    engine.send(Command::SetInput(DeviceChoice::Default));
    let reopening = longest_pass_within(&engine, Duration::from_secs(3));
    eprintln!("longest pass reopening {reopening:?}");
    wait_for(&engine, "the microphone open again", microphone_open);
    // The new device's controls keep the user's mute and push-to-talk.
    let second = lock(&engine.shared).mic.clone().unwrap();
    assert!(
        second.muted() && second.push_to_talk(),
        "mute or push-to-talk lost"
    );

    // An unknown device: a clear line and receive-only, soon, the worker never waiting.
    engine.counters.take_longest_pass();
    let noise = Oversleep::start();
    engine.send(Command::SetInput(DeviceChoice::Id(
        "no-such-microphone".into(),
    )));
    wait_for(&engine, "the unknown device refused", |e| {
        lock(&e.shared).input_status.contains("no-such-microphone")
    });
    let refusing = longest_pass_beyond(&engine, noise);
    eprintln!("longest pass refusing {refusing:?}");
    let status = lock(&engine.shared).input_status.clone();
    assert!(status.contains("receive-only"), "{status}");
    assert!(lock(&engine.shared).mic.is_none(), "{status}");

    // A choice made while another opens replaces it: the last one is the microphone.
    engine.send(Command::SetInput(DeviceChoice::Default));
    engine.send(Command::SetInput(DeviceChoice::Id(
        "no-such-microphone".into(),
    )));
    engine.send(Command::SetInput(DeviceChoice::Default));
    let replacing = longest_pass_within(&engine, Duration::from_secs(3));
    wait_for(&engine, "the last choice open", microphone_open);
    eprintln!("longest pass replacing {replacing:?}");
    assert!(
        reopening < OPENING_STALL && refusing < OPENING_STALL && replacing < OPENING_STALL,
        "longest pass reopening {reopening:?}, refusing {refusing:?}, replacing {replacing:?}"
    );
    assert!(lock(&engine.shared).call.error.is_none());
}

/// Set, to a FIFO's path, in the run of a test whose ALSA configuration has [`SLOW_MIC`].
const SLOW_MIC_FIFO: &str = "LIPCALL_TEST_SLOW_MIC";

/// An ALSA capture device that reads the FIFO: opening it waits until a writer opens the
/// FIFO, as a device slow to wake does; reading it waits for the writer's bytes.
const SLOW_MIC: &str = "alsa:lipcall_slow_mic";

/// Runs the test `test` again, alone, with an ALSA configuration that adds [`SLOW_MIC`] (ALSA
/// reads it once a process). True when it ran there and passed: the caller returns; false
/// when this is that run.
fn ran_with_a_slow_microphone(test: &str) -> bool {
    if std::env::var_os(SLOW_MIC_FIFO).is_some() {
        return false;
    }
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("mic.fifo");
    let made = Process::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success(), "mkfifo failed");
    let conf = dir.path().join("asound.conf");
    let name = SLOW_MIC.trim_start_matches("alsa:");
    std::fs::write(
        &conf,
        format!(
            "</usr/share/alsa/alsa.conf>\n\
             pcm.{name} {{ type file slave.pcm \"null\" file \"/dev/null\" \
             infile \"{}\" format \"raw\" }}\n",
            fifo.display()
        ),
    )
    .unwrap();
    let run = Process::new(std::env::current_exe().unwrap())
        .args(["--exact", test, "--nocapture", "--test-threads=1"])
        .env("ALSA_CONFIG_PATH", &conf)
        .env(SLOW_MIC_FIFO, &fifo)
        .output()
        .unwrap();
    passed_rerun(&run, test, "with a slow microphone");
    true
}

#[test]
fn choosing_a_microphone_slow_to_open_never_stalls_the_engine() {
    let test = "choosing_a_microphone_slow_to_open_never_stalls_the_engine";
    if !common::pulse_running() {
        common::unavailable("PulseAudio (bash .ci/pulse-null-sink.sh)");
        return;
    }
    if ran_with_a_slow_microphone(test) {
        return;
    }
    let fifo = std::env::var(SLOW_MIC_FIFO).unwrap();
    let engine = common::app::engine_with_audio("Eve", None);
    wait_for(&engine, "the first microphone open", microphone_open);
    engine.counters.take_longest_pass();
    let noise = Oversleep::start();
    engine.send(Command::SetInput(DeviceChoice::Id(SLOW_MIC.into())));
    // The device opens once the FIFO has a writer: a second from now (the open waits on a
    // thread of the test's, which a device never opened leaves waiting).
    std::thread::sleep(Duration::from_secs(1));
    let (opened, writer) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = opened.send(std::fs::OpenOptions::new().write(true).open(&fifo));
    });
    let writer = writer
        .recv_timeout(Duration::from_secs(20))
        .expect("the slow microphone was never opened")
        .unwrap();
    wait_for(&engine, "the slow microphone open", |e| {
        microphone_open(e) && lock(&e.shared).input_status.contains("slow_mic")
    });
    let opening = longest_pass_beyond(&engine, noise);
    eprintln!("longest pass opening a microphone that took 1 s: {opening:?}");
    // Replaced, it closes once its reader stops waiting on the FIFO: when the writer goes.
    engine.send(Command::SetInput(DeviceChoice::Default));
    wait_for(&engine, "the default microphone back", |e| {
        microphone_open(e) && !lock(&e.shared).input_status.contains("slow_mic")
    });
    let replacing = longest_pass_within(&engine, Duration::from_millis(500));
    drop(writer);
    eprintln!("longest pass replacing it: {replacing:?}");
    assert!(
        opening < OPENING_STALL && replacing < OPENING_STALL,
        "longest pass opening {opening:?}, replacing {replacing:?}"
    );
}

/// A passphrase's room key takes 100,000 PBKDF2 rounds (about 0.6 s here): derived off the
/// worker, and the call is placed, encrypted, once it is.
#[test]
fn calling_with_a_passphrase_never_stalls_the_engine() {
    let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = peer.local_addr().unwrap().port();
    let engine = common::app::headless_engine("Eve", None);
    longest_pass_within(&engine, Duration::from_millis(500));
    engine.send(Command::Call(Box::new(CallSpec {
        address: format!("127.0.0.1:{port}"),
        name: "Eve".into(),
        codec: Codec::Opus,
        passphrase: Some("correct horse battery staple".into()),
        ..CallSpec::default()
    })));
    let calling = longest_pass_within(&engine, Duration::from_secs(3));
    let status = lock(&engine.shared).call.clone();
    assert!(calling < STALL, "longest pass while calling {calling:?}");
    assert!(
        status.in_call && status.error.is_none() && status.state.starts_with("calling "),
        "{status:?}"
    );
    assert!(
        matches!(
            status.encryption,
            lipcall::app::engine::Encryption::EndToEnd
        ),
        "{status:?}"
    );
}
