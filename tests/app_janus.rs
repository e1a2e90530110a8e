//! The app joins a room on a real Janus (Debian's, with the repository's config) when the call
//! address is a Janus URL: each publisher becomes a peer with its name and an animated head,
//! the call says that Janus can hear it, and a publisher leaving leaves no peer behind.

mod common;

use std::process::{Command as Process, Stdio};
use std::time::{Duration, Instant};

use lipcall::app::engine::{CallSpec, Command, Encryption, Engine, lock};
use lipcall::codec::any::Codec;

use common::janus::{STOCK_VIDEOROOM, start_janus, start_janus_with};
use lipcall::net::janus::candidates::{IceServers, TurnServer};

fn wait_for(what: &str, engine: &Engine, mut done: impl FnMut(&Engine) -> bool) {
    let deadline = Instant::now() + Duration::from_secs(20);
    while !done(engine) {
        let s = lock(&engine.shared);
        assert!(
            Instant::now() < deadline,
            "{what}: state {:?}, error {:?}, peers {:?}",
            s.call.state,
            s.call.error,
            s.peers.views()
        );
        drop(s);
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn engine(name: &str) -> Engine {
    common::app::headless_engine(name, None)
}

fn join(engine: &Engine, url: &str, room: &str, pin: Option<&str>) {
    join_with(engine, url, room, pin, IceServers::default());
}

fn join_with(engine: &Engine, url: &str, room: &str, pin: Option<&str>, ice: IceServers) {
    engine.send(Command::Call(Box::new(CallSpec {
        address: url.into(),
        room: Some(room.into()),
        passphrase: pin.map(Into::into),
        name: "Carol".into(),
        codec: Codec::Opus,
        ice,
        ..CallSpec::default()
    })));
}

#[test]
fn the_app_joins_a_janus_room_and_animates_each_publisher() {
    if !common::janus::runs_here("the_app_joins_a_janus_room_and_animates_each_publisher") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let janus = start_janus(dir.path());
    app_animates_a_publisher(&janus.url, "app-room", IceServers::default());
}

/// Debian's janus with its own configuration (numbered rooms, as stock deployments run it):
/// the app joins its demo room 1234.
#[test]
fn the_app_joins_a_room_of_a_stock_janus() {
    if !common::janus::runs_here("the_app_joins_a_room_of_a_stock_janus") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let janus = start_janus_with(dir.path(), &[std::path::Path::new(STOCK_VIDEOROOM)]);
    app_animates_a_publisher(&janus.url, "1234", IceServers::default());
}

/// The app's media relayed only through a TURN server (the settings' NAT menu): coturn on the
/// namespace's address, and a publisher heard and animated through it.
#[test]
fn the_app_joins_through_a_turn_relay_only() {
    if !common::janus::runs_here("the_app_joins_through_a_turn_relay_only") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let Some(coturn) =
        common::nat::start_coturn(dir.path(), &common::nat::media_ip(), Some("ann:s3cret"))
    else {
        return;
    };
    let janus = start_janus(dir.path());
    let ice = IceServers {
        stun: None,
        turn: Some(TurnServer {
            server: coturn.addr.to_string(),
            username: "ann".into(),
            password: "s3cret".into(),
        }),
        relay_only: true,
    };
    app_animates_a_publisher(&janus.url, "turn-room", ice);
}

/// The app joins `room` at `url`, a `send --janus` publisher there animates her head, and she
/// is gone once she left.
fn app_animates_a_publisher(url: &str, room: &str, ice: IceServers) {
    let app = engine("Carol");
    join_with(&app, url, room, None, ice);
    wait_for("the app is in the room", &app, |e| {
        lock(&e.shared).call.state.contains("in Janus room")
    });
    {
        let s = lock(&app.shared);
        assert_eq!(s.call.encryption, Encryption::HopByHop);
        assert!(s.call.in_call);
        assert_eq!(s.call.phase.word(), "in_call", "{:?}", s.call);
        assert!(s.call.error.is_none(), "{:?}", s.call.error);
    }

    let alice = Process::new(env!("CARGO_BIN_EXE_lipcall"))
        .arg("send")
        .arg(common::repo_file("assets/speech/demo.wav"))
        .args(["--janus", url, "--room", room, "--name", "Alice"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for("Alice's speech animates her head", &app, |e| {
        let s = lock(&e.shared);
        s.peers
            .views()
            .iter()
            .any(|p| p.name == "Alice" && p.named && p.frames_animated > 50 && p.talking)
    });
    {
        let s = lock(&app.shared);
        let views = s.peers.views();
        let alice = views.iter().find(|p| p.name == "Alice").unwrap();
        assert_eq!(alice.codec, Some(Codec::Opus));
        assert!(s.playback.peer_controls(alice.feed).is_some());
    }
    let out = alice.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    wait_for("Alice is gone once she left", &app, |e| {
        lock(&e.shared).peers.views().is_empty()
    });

    app.send(Command::Leave);
    wait_for("the app left the room", &app, |e| {
        !lock(&e.shared).call.in_call
    });
}

#[test]
fn a_wrong_pin_or_an_unreachable_janus_is_a_clear_error() {
    if !common::janus::runs_here("a_wrong_pin_or_an_unreachable_janus_is_a_clear_error") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let janus = start_janus(dir.path());
    // The first member creates the room with its pin.
    let owner = engine("Dave");
    join(&owner, &janus.url, "pinned", Some("right"));
    wait_for("the owner is in the room", &owner, |e| {
        lock(&e.shared).call.state.contains("in Janus room")
    });

    let app = engine("Carol");
    join(&app, &janus.url, "pinned", Some("wrong"));
    wait_for("a wrong pin is said", &app, |e| {
        lock(&e.shared)
            .call
            .error
            .as_deref()
            .is_some_and(|e| e.contains("pin"))
    });
    assert!(!lock(&app.shared).call.in_call);

    // Nothing listens on port 9: refused at once.
    join(&app, "http://127.0.0.1:9/janus", "any", None);
    wait_for("an unreachable Janus is said", &app, |e| {
        let s = lock(&e.shared);
        !s.call.in_call
            && s.call
                .error
                .as_deref()
                .is_some_and(|e| e.contains("cannot reach Janus at http://127.0.0.1:9/janus"))
    });
}
