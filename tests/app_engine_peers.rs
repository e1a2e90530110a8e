//! The app's engine frees a peer's state when it leaves (its choices and weight schedule once
//! went on growing with every caller; now the peer is one struct, dropped with its mixer slot),
//! and a named peer is told apart from one known only by its CNAME (which changes with every
//! run, so its choices are not saved).

mod common;

use std::time::{Duration, Instant};

use lipcall::app::engine::{Engine, lock};
use lipcall::audio::DeviceChoice;
use lipcall::net::session::{Session, SessionConfig};
use lipcall::net::transport::PeerId;

fn wait_for(what: &str, engine: &Engine, mut done: impl FnMut(&Engine) -> bool) {
    let deadline = Instant::now() + Duration::from_secs(15);
    while !done(engine) {
        assert!(Instant::now() < deadline, "{what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Talks for a second from its own session, then says BYE.
fn caller(to: std::net::SocketAddr, name: Option<&str>) -> std::thread::JoinHandle<u32> {
    let name = name.map(str::to_string);
    std::thread::spawn(move || {
        let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
        config.destinations = vec![to];
        config.name = name;
        config.rtcp_interval = Duration::from_millis(200);
        let session = Session::start(config).unwrap();
        common::net::talk(&session, 50);
        session.leave();
        session.ssrc()
    })
}

#[test]
fn a_peer_that_leaves_leaves_no_state_behind() {
    let engine = common::app::headless_engine("Eve", Some("127.0.0.1:0"));
    let to = lock(&engine.shared)
        .call
        .local_addr
        .expect("the idle session listens");
    for (round, name) in [Some("Alice"), None, Some("Bob")].into_iter().enumerate() {
        let call = caller(to, name);
        // A name comes with the caller's first report (until then the peer goes by its SSRC).
        wait_for("the caller is shown", &engine, |e| {
            let s = lock(&e.shared);
            let views = s.peers.views();
            views.len() == 1 && (name.is_none() || views[0].named)
        });
        let feed = {
            let s = lock(&engine.shared);
            let p = &s.peers.views()[0];
            assert_eq!(p.named, name.is_some(), "{p:?}");
            assert!(s.playback.peer_controls(p.feed).is_some());
            p.feed
        };
        let ssrc = call.join().unwrap();
        wait_for("the caller is forgotten", &engine, |e| {
            lock(&e.shared).peers.views().is_empty()
        });
        let s = lock(&engine.shared);
        assert!(
            s.peers.is_empty(),
            "round {round}: the peer's state is kept"
        );
        assert!(s.peers.get(PeerId::Ssrc(ssrc)).is_none());
        assert!(
            s.playback.peer_controls(feed).is_none(),
            "round {round}: its mixer slot is kept"
        );
        assert!(s.call.error.is_none(), "{:?}", s.call.error);
    }
}

/// Whether a PulseAudio server answers (the null sink of .ci/pulse-null-sink.sh).
fn pulse_running() -> bool {
    std::process::Command::new("pactl")
        .arg("info")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

#[test]
fn switching_the_output_leaves_the_ui_lock_free() {
    if !pulse_running() {
        common::unavailable(
            "no PulseAudio server (.ci/pulse-null-sink.sh): output switch not timed",
        );
        return;
    }
    let engine = common::app::engine_with_audio("Eve", None);
    let before = lock(&engine.shared).output_status.clone();
    lock(&engine.shared).output_status = "switching".into();
    let started = Instant::now();
    engine.send(lipcall::app::engine::Command::SetOutput(
        DeviceChoice::Default,
    ));
    // The UI takes the lock every frame; opening a device (which took the lock with it for
    // its whole duration, about 2 s on PulseAudio) must not keep it waiting.
    let mut longest = Duration::ZERO;
    loop {
        let asked = Instant::now();
        let s = lock(&engine.shared);
        longest = longest.max(asked.elapsed());
        if s.output_status != "switching" {
            assert_eq!(s.output_status, before, "{:?}", s.call.error);
            break;
        }
        drop(s);
        assert!(started.elapsed() < Duration::from_secs(15), "no switch");
        std::thread::sleep(Duration::from_millis(1));
    }
    let switch = started.elapsed();
    eprintln!("switch took {switch:?}; the lock waited at most {longest:?}");
    // Held through the open, a lock taken every millisecond waits most of it (10 of 15 ms on
    // a null sink; seconds on an idle PulseAudio sink); swapped in only, microseconds.
    assert!(
        longest < (switch / 2).max(Duration::from_millis(1)),
        "the lock waited {longest:?} of a {switch:?} switch"
    );
}
