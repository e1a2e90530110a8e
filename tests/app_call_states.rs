//! The call's phase, as the call bar and the `--status` file show it: a direct call nobody
//! answers fails; a caller into the listening app rings, and once answered is a call until it
//! hangs up; the demo peer never rings; a SIP call rings out as "calling"; the app's listening
//! port stays across starts.

mod common;

use std::net::{SocketAddr, UdpSocket};
use std::process::Stdio;
use std::time::{Duration, Instant};

use lipcall::app::engine::{CallPhase, CallSpec, Command, DEMO_NAME, Engine, EngineConfig, lock};
use lipcall::audio::DeviceChoice;
use lipcall::net::session::{Session, SessionConfig};

fn wait_for_phase(engine: &Engine, what: &str, limit: Duration, done: impl Fn(&CallPhase) -> bool) {
    common::app::wait_for(engine, what, limit, |s| done(&s.call.phase));
}

fn call(engine: &Engine, address: &str) {
    engine.send(Command::Call(Box::new(CallSpec {
        address: address.into(),
        name: "Alice".into(),
        ..CallSpec::default()
    })));
}

/// A loopback port nothing listens on (bound, then let go).
fn dead_port() -> u16 {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    socket.local_addr().unwrap().port()
}

#[test]
fn a_direct_call_to_a_dead_address_fails_and_the_next_call_forgets_why() {
    let engine = common::app::headless_engine("Alice", Some("127.0.0.1:0"));
    let dead = format!("127.0.0.1:{}", dead_port());
    let started = Instant::now();
    call(&engine, &dead);
    wait_for_phase(&engine, "calling", Duration::from_secs(5), |p| {
        p.word() == "calling"
    });
    wait_for_phase(
        &engine,
        "failed",
        Duration::from_secs(20),
        |p| matches!(p, CallPhase::Failed { reason } if reason.contains("nobody answered")),
    );
    assert!(started.elapsed() < Duration::from_secs(20));
    {
        let s = lock(&engine.shared);
        assert!(!s.call.in_call, "back to listening: {:?}", s.call);
        assert!(s.call.local_addr.is_some(), "{:?}", s.call);
    }
    // The failure belongs to that call: the next one starts clean.
    call(&engine, &format!("127.0.0.1:{}", dead_port()));
    wait_for_phase(&engine, "calling again", Duration::from_secs(5), |p| {
        p.word() == "calling"
    });
    assert!(lock(&engine.shared).call.error.is_none());
}

#[test]
fn a_caller_into_the_listening_app_rings_and_once_answered_is_in_a_call_until_it_hangs_up() {
    let engine = common::app::headless_engine("Alice", Some("127.0.0.1:0"));
    let listening = lock(&engine.shared).call.local_addr.expect("listening");
    assert_eq!(lock(&engine.shared).call.phase, CallPhase::Idle);
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
    config.destinations = vec![listening];
    config.name = Some("Bob".into());
    let bob = Session::start(config).unwrap();
    let talker = std::thread::spawn(move || {
        common::net::talk(&bob, 150);
        bob
    });
    wait_for_phase(
        &engine,
        "Bob rings",
        Duration::from_secs(10),
        |p| matches!(p, CallPhase::Ringing { from, caller: Some(_) } if from == "Bob"),
    );
    let bob_at = match lock(&engine.shared).call.phase.clone() {
        CallPhase::Ringing { caller, .. } => caller.unwrap(),
        other => panic!("{other:?}"),
    };
    engine.send(Command::AnswerCaller(bob_at));
    wait_for_phase(
        &engine,
        "in a call with Bob",
        Duration::from_secs(10),
        |p| matches!(p, CallPhase::InCall { with, .. } if with == "Bob"),
    );
    let bob = talker.join().unwrap();
    bob.leave();
    let left = Instant::now();
    wait_for_phase(
        &engine,
        "idle after Bob left",
        Duration::from_secs(10),
        |p| p.word() == "idle",
    );
    assert!(left.elapsed() < Duration::from_secs(10));
    let phase = lock(&engine.shared).call.phase.clone();
    assert!(
        matches!(&phase, CallPhase::Ended { by } if by.contains("Bob")),
        "{phase:?}"
    );
}

#[test]
fn a_sip_call_rings_out_as_calling() {
    // A SIP "server" that takes the INVITE and never answers.
    let silent = UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = silent.local_addr().unwrap().port();
    let engine = common::app::headless_engine("Alice", None);
    call(&engine, &format!("sip:bob@127.0.0.1:{port}"));
    wait_for_phase(
        &engine,
        "calling",
        Duration::from_secs(10),
        |p| matches!(p, CallPhase::Calling { to, .. } if to.contains("bob")),
    );
    let mut buf = [0u8; 4096];
    silent
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let (n, _) = silent.recv_from(&mut buf).expect("the INVITE");
    assert!(buf[..n].starts_with(b"INVITE sip:bob@"));
    assert_eq!(lock(&engine.shared).call.phase.word(), "calling");
}

/// The port the app said it listens on, started with `settings` and no display (the window
/// fails to open; the engine has started and said where it listens before).
fn listening_port(settings: &std::path::Path) -> u16 {
    let out = common::lipcall()
        .args(["--no-audio", "--no-demo", "--quit-after", "1", "--settings"])
        .arg(settings)
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .stdin(Stdio::null())
        .output()
        .expect("lipcall runs");
    let log = String::from_utf8_lossy(&out.stderr);
    let line = log
        .lines()
        .find_map(|l| l.strip_prefix("lipcall: listening on "))
        .unwrap_or_else(|| panic!("no listening line: {log}"));
    let addr: SocketAddr = line.split(' ').next().unwrap().parse().unwrap();
    assert!(addr.ip().is_unspecified(), "all interfaces: {line}");
    assert!(
        line.contains(&format!("127.0.0.1:{}", addr.port())),
        "{line}"
    );
    addr.port()
}

#[test]
fn the_listening_port_stays_across_starts_and_moves_up_while_taken() {
    let dir = tempfile::tempdir().unwrap();
    let settings = dir.path().join("settings.json");
    // A port of this test's own, not 5004: tests run side by side.
    let mine = UdpSocket::bind("0.0.0.0:0").unwrap();
    let port = mine.local_addr().unwrap().port();
    drop(mine);
    std::fs::write(&settings, format!("{{\"listen_port\": {port}}}")).unwrap();
    let first = listening_port(&settings);
    let second = listening_port(&settings);
    assert_eq!(first, port);
    assert_eq!(second, first, "the port stays across starts");

    let held = UdpSocket::bind(("0.0.0.0", port)).unwrap();
    let moved = listening_port(&settings);
    assert!(moved > port, "taken {port}: listened on {moved}");
    drop(held);
    let kept = std::fs::read_to_string(&settings).unwrap();
    assert!(kept.contains(&format!("\"listen_port\": {port}")), "{kept}");
    assert_eq!(listening_port(&settings), port, "back once it is free");
}

/// The call bar, as the window draws it.
struct Bar {
    form: lipcall::app::CallForm,
    settings: lipcall::app::settings::Settings,
    engine: Engine,
}

#[test]
fn enter_in_the_address_field_calls_and_the_bar_shows_the_phase() {
    use eframe::egui;
    use egui_kittest::Harness;
    use egui_kittest::kittest::Queryable;

    let bar = Bar {
        form: lipcall::app::CallForm::default(),
        settings: lipcall::app::settings::Settings::default(),
        engine: common::app::headless_engine("Alice", Some("127.0.0.1:0")),
    };
    let mut h = Harness::new_ui_state(
        |ui: &mut egui::Ui, bar: &mut Bar| {
            let call = lock(&bar.engine.shared).call.clone();
            lipcall::app::call_ui(ui, &mut bar.form, &mut bar.settings, &call, &bar.engine);
        },
        bar,
    );
    h.run();
    assert!(h.query_by_label_contains("not in a call").is_some());
    let dead = format!("127.0.0.1:{}", dead_port());
    h.get_by_label("Address").focus();
    h.run();
    h.get_by_label("Address").type_text(&dead);
    h.run();
    h.key_press(egui::Key::Enter);
    h.run();
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        h.run();
        if h.query_all_by_label_contains("calling 127.0.0.1")
            .next()
            .is_some()
        {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "no calling after Enter: {:?}",
            lock(&h.state().engine.shared).call
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(lock(&h.state().engine.shared).call.phase.word(), "calling");
}

#[test]
fn the_demo_peer_talks_into_the_listening_app_without_ringing() {
    let engine = Engine::start(EngineConfig {
        listen: Some("127.0.0.1:0".parse().unwrap()),
        demo: true,
        name: "Alice".into(),
        input: DeviceChoice::Default,
        output: DeviceChoice::Default,
        no_audio: true,
        output_margin: lipcall::audio::DEFAULT_OUTPUT_MARGIN,
    })
    .expect("the engine starts");
    let watched = Instant::now();
    let mut demo_heard = false;
    while watched.elapsed() < Duration::from_secs(6) {
        {
            let s = lock(&engine.shared);
            assert_eq!(s.call.phase, CallPhase::Idle, "{:?}", s.call);
            demo_heard |= s
                .peers
                .views()
                .iter()
                .any(|p| p.name == DEMO_NAME && p.frames_received > 0);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(demo_heard, "the demo peer was never heard");
}
