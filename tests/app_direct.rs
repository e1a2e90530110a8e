//! Direct calls between apps, both ways: a caller rings at the listening app, which sends
//! nothing of its microphone until the user answers; then it sends it back to the caller,
//! from its listening socket to where the caller's packets come from. One that stops first is
//! a missed call. Decline and Leave on a caller hold (a sender that keeps sending stays out)
//! until the user calls it.
//!
//! The two-way case runs two engines with real microphones in a child process of this test
//! binary (its `#[ignore]`d `two_engines_call`), whose PulseAudio source is a null sink's
//! monitor a tone is played into (`PULSE_SOURCE`) and whose output another null sink
//! (`PULSE_SINK`): both apps speak the tone, each must hear the other's.

mod common;

use std::net::{SocketAddr, UdpSocket};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::app::engine_with_audio;
use common::pulse::NullSink;
use common::{pulse_running, run};
use lipcall::app::engine::{CallPhase, CallSpec, Command as EngineCommand, Engine};
use lipcall::app::engine::{Shared, lock};
use lipcall::app::peer::PeerView;

const LIMIT: Duration = Duration::from_secs(30);

fn peer<'a>(s: &'a [PeerView], name: &str) -> Option<&'a PeerView> {
    s.iter().find(|p| p.name == name)
}

fn call(engine: &Engine, address: &str, name: &str) {
    engine.send(EngineCommand::Call(Box::new(CallSpec {
        address: address.into(),
        name: name.into(),
        ..CallSpec::default()
    })));
}

fn hears(s: &Shared, name: &str) -> bool {
    peer(&s.peers.views(), name).is_some_and(|p| p.frames_received > 100 && p.level_db > -40.0)
}

/// The child: Alice listens, Bob calls her and rings: Bob hears nothing of her until she
/// answers; then each hears the other's microphone; Alice muted is heard no more; Alice's
/// Leave ends Bob's call with her name.
#[test]
#[ignore = "run by two_apps_in_a_direct_call_hear_each_other in a child process"]
fn two_engines_call() {
    if std::env::var_os("LIPCALL_DIRECT_CHILD").is_none() {
        return;
    }
    let alice = engine_with_audio("Alice", Some("127.0.0.1:0"));
    let bob = engine_with_audio("Bob", Some("127.0.0.1:0"));
    for e in [&alice, &bob] {
        let s = lock(&e.shared);
        assert!(s.mic.is_some(), "a microphone: {}", s.input_status);
    }
    let to = lock(&alice.shared).call.local_addr.expect("listening");
    call(&bob, &to.to_string(), "Bob");
    let ringing = |s: &Shared| matches!(&s.call.phase, CallPhase::Ringing { from, caller: Some(_) } if from == "Bob");
    common::app::wait_for(&alice, "Bob rings at Alice", LIMIT, ringing);
    assert_eq!(lock(&alice.shared).call.phase.word(), "ringing");
    // Not answered: for 5 s Bob gets nothing of Alice's microphone, while she hears him.
    let asked = Instant::now();
    while asked.elapsed() < Duration::from_secs(5) {
        {
            let (a, b) = (lock(&alice.shared), lock(&bob.shared));
            assert!(ringing(&a), "Alice: {:?}", a.call.phase);
            let alice_seen = peer(&b.peers.views(), "Alice").map(|p| p.frames_received);
            assert!(
                alice_seen.is_none_or(|frames| frames == 0),
                "Bob got {alice_seen:?} frames of Alice before she answered"
            );
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    common::app::wait_for(&alice, "Alice hears Bob ringing", LIMIT, |s| {
        hears(s, "Bob")
    });
    // Bob's app says where his call stands: it rings at Alice's (her reports say so), and
    // it is no call yet.
    common::app::wait_for(&bob, "Bob's call rings there", LIMIT, |s| {
        matches!(&s.call.phase, CallPhase::Calling { ringing: true, .. })
    });
    assert_eq!(lock(&bob.shared).call.phase.word(), "calling");
    let bob_at = match &lock(&alice.shared).call.phase {
        CallPhase::Ringing { caller, .. } => caller.expect("a direct caller"),
        other => panic!("not ringing: {other:?}"),
    };
    alice.send(EngineCommand::AnswerCaller(bob_at));
    common::app::wait_for(&bob, "Bob hears Alice", LIMIT, |s| hears(s, "Alice"));
    {
        let (a, b) = (lock(&alice.shared), lock(&bob.shared));
        eprintln!(
            "Alice hears {:?}; Bob hears {:?}",
            peer(&a.peers.views(), "Bob").map(|p| (p.codec, p.frames_received, p.level_db)),
            peer(&b.peers.views(), "Alice").map(|p| (p.codec, p.frames_received, p.level_db))
        );
        let alice_at = peer(&b.peers.views(), "Alice").unwrap().addr;
        assert_eq!(alice_at, to, "Alice answers from the socket she listens on");
        assert!(matches!(&a.call.phase, CallPhase::InCall { with, .. } if with == "Bob"));
        assert!(matches!(&b.call.phase, CallPhase::InCall { with, .. } if with == "Alice"));
    }
    lock(&alice.shared).mic.as_ref().unwrap().set_muted(true);
    common::app::wait_for(&bob, "Alice muted is silent", LIMIT, |s| {
        peer(&s.peers.views(), "Alice").is_none_or(|p| p.level_db < -50.0)
    });
    lock(&alice.shared).mic.as_ref().unwrap().set_muted(false);
    common::app::wait_for(&bob, "Alice unmuted", LIMIT, |s| hears(s, "Alice"));
    // Carol calls Alice during the call and rings; Alice declines, and Carol's app says so.
    let carol = engine_with_audio("Carol", Some("127.0.0.1:0"));
    call(&carol, &to.to_string(), "Carol");
    common::app::wait_for(
        &alice,
        "Carol rings at Alice",
        LIMIT,
        |s| matches!(&s.call.phase, CallPhase::Ringing { from, .. } if from == "Carol"),
    );
    common::app::wait_for(&carol, "Carol's call rings there", LIMIT, |s| {
        matches!(&s.call.phase, CallPhase::Calling { ringing: true, .. })
    });
    let carol_at = match &lock(&alice.shared).call.phase {
        CallPhase::Ringing { caller, .. } => caller.expect("a direct caller"),
        other => panic!("not ringing: {other:?}"),
    };
    alice.send(EngineCommand::DeclineCaller(carol_at));
    common::app::wait_for(
        &carol,
        "Carol hears she was declined",
        LIMIT,
        |s| matches!(&s.call.phase, CallPhase::Failed { reason } if reason.ends_with("declined the call")),
    );
    common::app::wait_for(
        &alice,
        "Alice back in her call with Bob",
        LIMIT,
        |s| matches!(&s.call.phase, CallPhase::InCall { with, .. } if with == "Bob"),
    );
    alice.send(EngineCommand::Leave);
    common::app::wait_for(
        &bob,
        "Alice's Leave ends Bob's call",
        LIMIT,
        |s| matches!(&s.call.phase, CallPhase::Ended { by } if by.contains("Alice")),
    );
    let a = lock(&alice.shared);
    assert!(
        matches!(&a.call.phase, CallPhase::Ended { by } if by == "you hung up"),
        "{:?}",
        a.call.phase
    );
}

#[test]
fn two_apps_in_a_direct_call_hear_each_other() {
    if !pulse_running() {
        common::unavailable("no PulseAudio server (start .ci/pulse-null-sink.sh): not run");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let tone = dir.path().join("tone.wav");
    run(Command::new("sox")
        .args(["-n", "-D", "-b", "16", "-c", "1", "-r", "48000"])
        .arg(&tone)
        .args(["synth", "90", "sine", "440", "gain", "-12"]));
    let mic = NullSink::load("direct_mic", 48_000);
    let ear = NullSink::load("direct_ear", 48_000);
    let mut speaker = Command::new("paplay")
        .arg(format!("--device={}", mic.name))
        .arg(&tone)
        .stderr(Stdio::null())
        .spawn()
        .expect("paplay (pulseaudio-utils) runs");
    let child = Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "two_engines_call", "--ignored", "--nocapture"])
        .env("LIPCALL_DIRECT_CHILD", "1")
        .env("PULSE_SOURCE", format!("{}.monitor", mic.name))
        .env("PULSE_SINK", &ear.name)
        .output()
        .expect("the test binary runs");
    let _ = speaker.kill();
    let _ = speaker.wait();
    let log = String::from_utf8_lossy(&child.stderr);
    let out = String::from_utf8_lossy(&child.stdout);
    eprintln!("{log}");
    assert!(
        child.status.success(),
        "the two engines' call:\n{out}\n{log}"
    );
    assert!(out.contains("1 passed"), "the child ran its case:\n{out}");
}

/// A loopback port nothing listens on now (bound, then let go): the engine's listening port,
/// which stays across its sessions.
fn free_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// `lipcall send` of a long tone to `to`, named Sender: it keeps sending.
fn sender(dir: &std::path::Path, to: SocketAddr) -> std::process::Child {
    sender_for(dir, to, 120)
}

/// `lipcall send` of a tone `seconds` long to `to`, named Sender; it says BYE at its end.
fn sender_for(dir: &std::path::Path, to: SocketAddr, seconds: u32) -> std::process::Child {
    let wav = dir.join("tone.wav");
    run(Command::new("sox")
        .args(["-n", "-D", "-b", "16", "-c", "1", "-r", "16000"])
        .arg(&wav)
        .args(["synth", &seconds.to_string(), "sine", "300", "gain", "-12"]));
    common::lipcall()
        .arg("send")
        .arg(&wav)
        .args(["--to", &to.to_string(), "--name", "Sender"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("lipcall send runs")
}

struct Killed(std::process::Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Decline on a ringing sender holds it out while it keeps sending; answered, it is in the
/// call and Leave holds it out the same; calling it lifts that.
#[test]
fn decline_and_leave_on_a_sender_hold_while_it_keeps_sending_until_the_user_calls_it() {
    let listen: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
    let engine = common::app::headless_engine("Alice", Some(&listen.to_string()));
    let dir = tempfile::tempdir().unwrap();
    let _sender = Killed(sender(dir.path(), listen));
    let sender_rings = |s: &Shared| matches!(&s.call.phase, CallPhase::Ringing { from, caller: Some(_) } if from == "Sender");
    common::app::wait_for(&engine, "the sender rings", LIMIT, |s| {
        sender_rings(s) && peer(&s.peers.views(), "Sender").is_some()
    });
    let from = peer(&lock(&engine.shared).peers.views(), "Sender")
        .expect("shown")
        .addr;
    engine.send(EngineCommand::DeclineCaller(from));
    common::app::wait_for(&engine, "declined, its tile gone", LIMIT, |s| {
        matches!(&s.call.phase, CallPhase::Ended { by } if by == "you declined Sender")
            && s.peers.views().is_empty()
    });
    assert_held_out(&engine);
    assert!(lock(&engine.shared).call.error.is_none());
    // A second sender from another address rings; answered, it is in the call; Leave holds it.
    let dir2 = tempfile::tempdir().unwrap();
    let _second = Killed(sender(dir2.path(), listen));
    common::app::wait_for(&engine, "the second sender rings", LIMIT, sender_rings);
    let second = match &lock(&engine.shared).call.phase {
        CallPhase::Ringing { caller, .. } => caller.expect("a direct caller"),
        other => panic!("not ringing: {other:?}"),
    };
    assert_ne!(second, from, "the declined one stays out");
    engine.send(EngineCommand::AnswerCaller(second));
    common::app::wait_for(
        &engine,
        "answered",
        LIMIT,
        |s| matches!(&s.call.phase, CallPhase::InCall { with, .. } if with == "Sender"),
    );
    engine.send(EngineCommand::Leave);
    common::app::wait_for(
        &engine,
        "hung up",
        LIMIT,
        |s| matches!(&s.call.phase, CallPhase::Ended { by } if by == "you hung up"),
    );
    assert_held_out(&engine);
    // The user calls it: the block is lifted; once that call is cancelled the listening
    // port hears the sender again.
    call(&engine, &from.to_string(), "Alice");
    common::app::wait_for(&engine, "calling the sender", LIMIT, |s| {
        s.call.phase.word() == "calling" || s.call.phase.word() == "in_call"
    });
    engine.send(EngineCommand::Leave);
    common::app::wait_for(
        &engine,
        "the sender rings again after the call",
        LIMIT,
        sender_rings,
    );
    assert_eq!(lock(&engine.shared).call.local_addr, Some(listen));
}

/// The senders go on; for 6 s (within the block's minute) none is heard or rings again.
fn assert_held_out(engine: &Engine) {
    let held = Instant::now();
    while held.elapsed() < Duration::from_secs(6) {
        {
            let s = lock(&engine.shared);
            assert!(
                s.peers.views().is_empty()
                    && !s.call.phase.is_active()
                    && s.call.phase.word() != "ringing",
                "back after {:?}: {:?}",
                held.elapsed(),
                s.call
            );
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn a_call_whose_peer_dies_without_a_word_ends_after_its_silence() {
    let engine = common::app::headless_engine("Bob", None);
    // Where Bob calls: a socket of the test's, which never answers.
    let quiet = UdpSocket::bind("127.0.0.1:0").unwrap();
    call(&engine, &quiet.local_addr().unwrap().to_string(), "Bob");
    // Placed: the call's own socket (until then the address is the listening session's).
    common::app::wait_for(&engine, "calling", LIMIT, |s| {
        s.call.phase.word() == "calling" && s.call.in_call && s.call.local_addr.is_some()
    });
    let bob_at = lock(&engine.shared).call.local_addr.unwrap();
    // A sender that reaches Bob's call, then dies without a BYE.
    let dir = tempfile::tempdir().unwrap();
    let mut sender = Killed(sender(dir.path(), bob_at));
    common::app::wait_for(
        &engine,
        "in a call with the sender",
        LIMIT,
        |s| matches!(&s.call.phase, CallPhase::InCall { with, .. } if with == "Sender"),
    );
    sender.0.kill().unwrap();
    // Forgotten after the session's 30 s of silence: the phase says so, not "in a call".
    common::app::wait_for(
        &engine,
        "the call ended",
        Duration::from_secs(60),
        |s| matches!(&s.call.phase, CallPhase::Ended { by } if by == "Sender went quiet and was dropped"),
    );
    assert!(!lock(&engine.shared).call.in_call);
}

#[test]
fn a_caller_that_stops_before_it_is_answered_is_a_missed_call() {
    let engine = common::app::headless_engine("Alice", Some("127.0.0.1:0"));
    let listen = lock(&engine.shared).call.local_addr.expect("listening");
    let dir = tempfile::tempdir().unwrap();
    let _sender = Killed(sender_for(dir.path(), listen, 3));
    common::app::wait_for(
        &engine,
        "the sender rings",
        LIMIT,
        |s| matches!(&s.call.phase, CallPhase::Ringing { from, .. } if from == "Sender"),
    );
    common::app::wait_for(
        &engine,
        "a missed call once it stops",
        LIMIT,
        |s| matches!(&s.call.phase, CallPhase::Missed { from } if from == "Sender"),
    );
    let s = lock(&engine.shared);
    assert_eq!(s.call.phase.word(), "idle");
    assert_eq!(
        s.call.phase.describe(Instant::now()),
        "missed call from Sender"
    );
}
