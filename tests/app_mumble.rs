//! The app on a real Mumble server (Debian's murmurd, started here with a second channel):
//! `mumble://HOST:PORT/` in the call bar joins it; a `lipcall send --mumble` speaker becomes a
//! peer whose frames play and whose talking light is on; the app's mute and push-to-talk reach
//! the server as self-mute and a second lipcall on the server sees them; a channel switch moves
//! the app (the second lipcall sees it there); a restarted murmurd is said and rejoined, back
//! in the channel the app had moved to; and a wrong server password and a server whose
//! certificate changed are refused with the reason in the call bar.

mod common;

use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

use lipcall::app::engine::{CallSpec, Command, Encryption, Engine, lock};
use lipcall::app::mumble_call::MumbleView;
use lipcall::audio::MicControls;

use common::mumble::{Murmur, lipcall_as, runs_here};

fn wait_for(what: &str, engine: &Engine, limit_s: u64, mut done: impl FnMut(&Engine) -> bool) {
    let deadline = Instant::now() + Duration::from_secs(limit_s);
    while !done(engine) {
        let s = lock(&engine.shared);
        assert!(
            Instant::now() < deadline,
            "{what}: state {:?}, error {:?}, peers {:?}, mumble {:?}",
            s.call.state,
            s.call.error,
            s.peers.views(),
            s.mumble
        );
        drop(s);
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn engine(name: &str) -> Engine {
    common::app::headless_engine(name, None)
}

/// Joins `mumble://` + `server` as `name`, with its own certificate folder under `dir`.
fn join(engine: &Engine, dir: &Path, server: &str, name: &str) {
    engine.send(Command::Call(Box::new(CallSpec {
        address: format!("mumble://{server}"),
        name: name.into(),
        mumble_identity: Some(dir.join(format!("identity-{name}"))),
        ..CallSpec::default()
    })));
}

fn view(engine: &Engine) -> Option<MumbleView> {
    lock(&engine.shared).mumble.clone()
}

/// What `seer` sees of `whom`: the channel's name and whether they muted themselves.
fn seen(seer: &Engine, whom: &str) -> Option<(String, bool)> {
    let v = view(seer)?;
    v.members()
        .find(|(_, m)| m.name == whom)
        .map(|(c, m)| (c.name.clone(), m.self_mute))
}

#[test]
fn the_app_joins_a_mumble_server_hears_a_speaker_switches_channel_and_shows_self_mute() {
    let test = "the_app_joins_a_mumble_server_hears_a_speaker_switches_channel_and_shows_self_mute";
    if !runs_here(test) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut murmur = Murmur::start(dir.path(), "");
    murmur.add_channels(&["Cellar"]);
    let server = murmur.address();

    let app = engine("Carol");
    join(&app, dir.path(), &format!("{server}/Root"), "Carol");
    wait_for("the app is in Root", &app, 20, |e| {
        lock(&e.shared).call.state.contains("in channel \"Root\"")
    });
    {
        let s = lock(&app.shared);
        assert!(s.call.in_call && s.call.error.is_none(), "{:?}", s.call);
        assert_eq!(s.call.phase.word(), "in_call", "{:?}", s.call);
        assert_eq!(s.call.encryption, Encryption::HopByHop);
        let v = s.mumble.as_ref().unwrap();
        assert!(v.first_visit, "{v:?}");
        assert_eq!(v.fingerprint.len(), 95, "SHA-256 as 32 hex pairs: {v:?}");
        let names: Vec<&str> = v.channels.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(names, ["Root", "Cellar"]);
    }

    // A second lipcall on the server sees what the app tells it.
    let observer = engine("Obs");
    join(&observer, dir.path(), &server, "Obs");
    // No microphone: nothing of Carol's can be heard, and the server says so.
    wait_for("Obs sees Carol muted", &observer, 20, |e| {
        seen(e, "Carol") == Some(("Root".into(), true))
    });
    // Carol has said nothing, yet Obs shows her as a peer of the channel (a still head).
    wait_for("Obs shows the silent Carol as a peer", &observer, 10, |e| {
        let s = lock(&e.shared);
        s.peers
            .views()
            .iter()
            .any(|p| p.name == "Carol" && p.named && p.frames_received == 0)
    });
    let mic = MicControls::default();
    lock(&app.shared).mic = Some(mic.clone());
    wait_for("Obs sees Carol unmuted", &observer, 10, |e| {
        seen(e, "Carol") == Some(("Root".into(), false))
    });
    mic.set_muted(true);
    wait_for("Carol's mute reaches Obs", &observer, 10, |e| {
        seen(e, "Carol") == Some(("Root".into(), true))
    });
    assert!(view(&app).unwrap().self_muted);
    mic.set_muted(false);
    mic.set_push_to_talk(true);
    wait_for(
        "push-to-talk with the key up is muted",
        &observer,
        10,
        |e| seen(e, "Carol") == Some(("Root".into(), true)),
    );
    mic.set_talk_pressed(true);
    wait_for("the talk key held unmutes", &observer, 10, |e| {
        seen(e, "Carol") == Some(("Root".into(), false))
    });

    // Ann speaks in Root: a peer with her name, her frames played, her talking light on.
    let ann = lipcall_as(dir.path(), "ann")
        .arg("send")
        .arg(common::repo_file("assets/speech/demo.wav"))
        .args(["--mumble", &server, "--name", "Ann"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for("Ann is heard, animated and lit", &app, 30, |e| {
        let s = lock(&e.shared);
        s.peers.views().iter().any(|p| {
            p.name == "Ann"
                && p.named
                && p.frames_received > 50
                && p.frames_animated > 50
                && p.talking
        })
    });
    {
        let s = lock(&app.shared);
        let views = s.peers.views();
        let ann = views.iter().find(|p| p.name == "Ann").unwrap();
        assert!(s.playback.peer_controls(ann.feed).is_some());
    }
    let out = ann.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Ann is gone once she left; Obs, silent in the channel, stays.
    wait_for("Ann is gone once she left", &app, 20, |e| {
        let names: Vec<String> = lock(&e.shared)
            .peers
            .views()
            .into_iter()
            .map(|p| p.name)
            .collect();
        names == ["Obs"]
    });

    // The app moves to Cellar: Obs sees it there.
    let cellar = view(&app)
        .unwrap()
        .channels
        .iter()
        .find(|c| c.name == "Cellar")
        .unwrap()
        .id;
    app.send(Command::Channel(cellar));
    wait_for("Obs sees Carol in Cellar", &observer, 10, |e| {
        seen(e, "Carol").is_some_and(|(c, _)| c == "Cellar")
    });
    wait_for("the app says it is in Cellar", &app, 10, |e| {
        let s = lock(&e.shared);
        s.call.state.contains("in channel \"Cellar\"")
            && s.mumble
                .as_ref()
                .is_some_and(|v| v.channels.iter().any(|c| c.ours && c.name == "Cellar"))
    });

    // murmurd stops and starts again: said, rejoined, back in Cellar and still unmuted. The
    // loss is looked for while the server is down: a restart that takes about as long as the
    // app's first retry can be over, and said, before the test looks.
    murmur.stop();
    wait_for("the loss is said", &app, 20, |e| {
        let s = lock(&e.shared);
        s.call.error.as_deref().is_some_and(|e| {
            e.contains("lost the Mumble server")
                || e.contains("cannot reconnect to the Mumble server")
        }) || s.call.state.contains("reconnecting")
    });
    murmur.launch();
    wait_for("rejoined, in Cellar again", &app, 30, |e| {
        let s = lock(&e.shared);
        s.call.error.is_none() && s.call.state.contains("in channel \"Cellar\"")
    });
    wait_for(
        "Obs, rejoined too, sees Carol in Cellar",
        &observer,
        30,
        |e| seen(e, "Carol") == Some(("Cellar".into(), false)),
    );

    app.send(Command::Leave);
    wait_for("the app left the server", &app, 10, |e| {
        let s = lock(&e.shared);
        !s.call.in_call && s.mumble.is_none()
    });
    wait_for("Obs sees Carol gone", &observer, 10, |e| {
        seen(e, "Carol").is_none()
    });
}

#[test]
fn a_changed_server_certificate_is_refused_in_the_call_bar() {
    if !runs_here("a_changed_server_certificate_is_refused_in_the_call_bar") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut murmur = Murmur::start(dir.path(), "");
    let app = engine("Dana");
    join(&app, dir.path(), &murmur.address(), "Dana");
    wait_for("the app is on the server", &app, 20, |e| {
        lock(&e.shared).call.state.contains("in channel")
    });

    // Another certificate under the same address than the one trusted on the first visit,
    // seen when the restarted server is rejoined: the call ends, saying why.
    let known = dir.path().join("identity-Dana/known_servers");
    let text = std::fs::read_to_string(&known).unwrap();
    assert!(text.contains(&murmur.address()), "{text}");
    std::fs::write(&known, format!("{} AA:BB:CC\n", murmur.address())).unwrap();
    murmur.restart(Duration::from_millis(300));
    wait_for("the call ends on the changed certificate", &app, 20, |e| {
        let s = lock(&e.shared);
        !s.call.in_call
            && s.call.error.as_deref().is_some_and(|e| {
                e.contains("certificate of")
                    && e.contains("AA:BB:CC")
                    && e.contains("not reconnecting")
            })
    });

    // And a new join is refused.
    join(&app, dir.path(), &murmur.address(), "Dana");
    wait_for("the changed certificate is refused", &app, 20, |e| {
        let s = lock(&e.shared);
        !s.call.in_call
            && s.call.error.as_deref().is_some_and(|e| {
                e.contains("certificate of") && e.contains("changed") && e.contains("AA:BB:CC")
            })
    });
    assert!(view(&app).is_none());
}

#[test]
fn a_wrong_server_password_is_said_in_the_call_bar() {
    if !runs_here("a_wrong_server_password_is_said_in_the_call_bar") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let murmur = Murmur::start(dir.path(), "serverpassword=open sesame");
    let app = engine("Eve");
    let call = |password: &str| {
        app.send(Command::Call(Box::new(CallSpec {
            address: format!("mumble://{}", murmur.address()),
            passphrase: Some(password.into()),
            mumble_identity: Some(dir.path().join("identity-Eve")),
            ..CallSpec::default()
        })));
    };
    call("guess");
    wait_for("the wrong password is said", &app, 20, |e| {
        let s = lock(&e.shared);
        !s.call.in_call
            && s.call.error.as_deref().is_some_and(|e| {
                e.contains("wrong server password (give it as the server password)")
            })
    });
    call("open sesame");
    wait_for("the right one lets the app in", &app, 20, |e| {
        let s = lock(&e.shared);
        s.call.state.contains("in channel") && s.call.error.is_none()
    });
}
