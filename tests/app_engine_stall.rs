//! The app's engine never waits on a peer or a server: dialling a SIP host that never answers,
//! leaving a Janus room whose server hangs, and joining a Mumble server that accepts and says
//! nothing all happen off the worker, whose every pass comes within 50 ms of the last (a pass
//! that blocks holds up every peer's audio and face).

mod common;

use std::net::{TcpListener, UdpSocket};
use std::time::{Duration, Instant};

use lipcall::app::engine::{CallSpec, Command, Engine, lock};
use lipcall::app::sip_call::PhoneCommand;
use lipcall::codec::any::Codec;
use lipcall::net::sip::register::Account;

/// The longest the worker's loop may take between two passes.
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

/// Runs for `span`, then returns the longest pass the worker took meanwhile.
fn longest_pass_within(engine: &Engine, span: Duration) -> Duration {
    std::thread::sleep(span);
    engine.counters.take_longest_pass()
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
