//! The app's phone without a window, against Debian's baresip (and kamailio as registrar and
//! proxy) on 127.0.0.1: the engine dials baresip, whose speech arrives as a peer in the roster,
//! heard and animated, takes DTMF from the keypad, and baresip's hang-up brings the app back to
//! idle; with an account, the app registers, baresip's call rings, is declined (603), rings
//! again and is answered, and while the app is in another call a caller hears 486; and the
//! phone's row, driven through egui_kittest: the account registered from the form, the banner's
//! Answer, the keypad's keys.

mod common;

use std::time::{Duration, Instant};

use common::sip::{PASSWORD, baresip, free_port, have, kamailio, reversed_8k, tell_baresip};
use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use lipcall::app::engine::{CallPhase, CallSpec, Command, Engine, Shared, lock};
use lipcall::app::settings::Settings;
use lipcall::app::sip_call::PhoneCommand;
use lipcall::app::{RingingBanner, SipForm, sip_ui};
use lipcall::codec::any::Codec;
use lipcall::net::relay::{Relay, RelayConfig};
use lipcall::net::sip::agent::Account;

fn engine() -> Engine {
    common::app::headless_engine("Alice", None)
}

/// A peer whose name contains `name` was heard and animated for a second and more, in PCMU.
fn heard(s: &Shared, name: &str) -> bool {
    heard_in(s, name, Codec::Pcmu)
}

fn heard_in(s: &Shared, name: &str, codec: Codec) -> bool {
    s.peers.views().iter().any(|p| {
        p.name.contains(name)
            && !p.is_demo
            && p.codec == Some(codec)
            && p.frames_received > 50
            && p.frames_animated > 50
    })
}

fn call(engine: &Engine, address: &str) {
    engine.send(Command::Call(Box::new(CallSpec {
        address: address.into(),
        name: "Alice".into(),
        ..CallSpec::default()
    })));
}

#[test]
fn the_app_dials_baresip_hears_it_sends_keys_and_idles_when_baresip_hangs_up() {
    if !have(&["baresip", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (bob_port, control) = (free_port(false), free_port(false));
    let bob = baresip(
        dir.path(),
        bob_port,
        control,
        "<sip:bob@127.0.0.1>;regint=0;answermode=auto;audio_codecs=PCMU",
        &reversed_8k(dir.path()),
    );
    let engine = engine();
    call(&engine, &format!("sip:bob@127.0.0.1:{bob_port}"));
    let limit = Duration::from_secs(15);
    common::app::wait_for(&engine, "bob is heard and animated", limit, |s| {
        heard(s, "bob")
    });
    {
        let s = lock(&engine.shared);
        assert!(s.call.in_call && s.call.error.is_none(), "{:?}", s.call);
        assert!(s.call.state.contains("in a SIP call with"), "{:?}", s.call);
        assert_eq!(s.call.phase.word(), "in_call", "{:?}", s.call);
        assert_eq!(s.call.codec, Some(Codec::Pcmu));
    }
    common::app::wait_for(&engine, "the keypad", limit, |s| s.phone.keypad);
    for key in ["4", "#"] {
        engine.send(Command::Phone(PhoneCommand::Keys(key.into())));
    }
    for key in ['4', '#'] {
        assert!(
            bob.wait_for(&format!("received event: '{key}' (end=1)"), limit),
            "DTMF {key} did not reach baresip: {}",
            bob.text()
        );
    }
    common::app::wait_for(&engine, "the keys shown as sent", limit, |s| {
        s.phone.keys_sent == "4#"
    });

    tell_baresip(control, "hangup", "");
    common::app::wait_for(&engine, "back to idle on baresip's BYE", limit, |s| {
        !s.call.in_call && s.peers.views().is_empty() && !s.phone.keypad
    });
    let phase = lock(&engine.shared).call.phase.clone();
    assert_eq!(
        phase,
        CallPhase::Ended {
            by: format!("sip:bob@127.0.0.1:{bob_port} hung up")
        }
    );
    assert_eq!(phase.word(), "idle");
}

#[test]
fn the_app_calls_a_wideband_baresip_in_g722() {
    if !have(&["baresip", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (bob_port, control) = (free_port(false), free_port(false));
    // baresip's G.722 reads its microphone file at 16 kHz.
    let speech = dir.path().join("reversed16k.wav");
    common::run(
        std::process::Command::new("sox")
            .arg(reversed_8k(dir.path()))
            .args(["-r", "16000"])
            .arg(&speech),
    );
    let bob = baresip(
        dir.path(),
        bob_port,
        control,
        "<sip:bob@127.0.0.1>;regint=0;answermode=manual;audio_codecs=G722/16000/1",
        &speech,
    );
    let engine = engine();
    call(&engine, &format!("sip:bob@127.0.0.1:{bob_port}"));
    // Bob's phone rings (his 180) before he answers: the app says so, still calling.
    common::app::wait_for(&engine, "ringing bob", Duration::from_secs(15), |s| {
        matches!(s.call.phase, CallPhase::Calling { ringing: true, .. })
    });
    {
        let s = lock(&engine.shared);
        assert_eq!(s.call.phase.word(), "calling", "{:?}", s.call);
        assert!(
            s.call
                .phase
                .describe(std::time::Instant::now())
                .starts_with("ringing sip:bob@"),
            "{:?}",
            s.call
        );
    }
    tell_baresip(control, "accept", "");
    common::app::wait_for(
        &engine,
        "bob heard in G.722",
        Duration::from_secs(15),
        |s| heard_in(s, "bob", Codec::G722) && s.call.codec == Some(Codec::G722),
    );
    assert!(
        bob.text().contains("Set audio decoder: G722"),
        "{}",
        bob.text()
    );
    engine.send(Command::Leave);
    common::app::wait_for(&engine, "idle", Duration::from_secs(10), |s| {
        !s.call.in_call
    });
}

#[test]
fn the_app_registers_declines_answers_and_is_busy_in_another_call() {
    if !have(&["kamailio", "baresip", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (kam_port, bob_port, control) = (free_port(false), free_port(false), free_port(false));
    let _kamailio = kamailio(dir.path(), kam_port, "");
    let bob = baresip(
        dir.path(),
        bob_port,
        control,
        "<sip:bob@127.0.0.1>;regint=0;audio_codecs=PCMU",
        &reversed_8k(dir.path()),
    );
    let engine = engine();
    let account = Account::parse(&format!("sip:alice@127.0.0.1:{kam_port}"), PASSWORD).unwrap();
    engine.send(Command::Phone(PhoneCommand::Account(Some(account))));
    let limit = Duration::from_secs(15);
    let registered = |s: &Shared| s.phone.registration.starts_with("registered with");
    common::app::wait_for(&engine, "registered", limit, registered);
    let alice = format!("sip:alice@127.0.0.1:{kam_port}");
    let closed = |n: usize| {
        let deadline = Instant::now() + limit;
        while bob.text().matches("session closed").count() < n {
            assert!(Instant::now() < deadline, "baresip: {}", bob.text());
            std::thread::sleep(Duration::from_millis(50));
        }
    };

    // Declined: baresip hears 603.
    tell_baresip(control, "dial", &alice);
    common::app::wait_for(&engine, "the call rings", limit, |s| {
        s.phone.ringing.is_some()
    });
    {
        let s = lock(&engine.shared);
        assert!(!s.call.in_call);
        assert_eq!(s.call.phase.word(), "ringing", "{:?}", s.call);
    }
    engine.send(Command::Phone(PhoneCommand::Decline));
    closed(1);
    assert!(
        bob.text().contains("603 Decline"),
        "baresip: {}",
        bob.text()
    );

    // A fresh listener registers; the next call is answered and heard.
    common::app::wait_for(&engine, "registered again", limit, registered);
    tell_baresip(control, "dial", &alice);
    common::app::wait_for(&engine, "the call rings again", limit, |s| {
        s.phone
            .ringing
            .as_deref()
            .is_some_and(|c| c.contains("bob"))
    });
    engine.send(Command::Phone(PhoneCommand::Answer));
    common::app::wait_for(&engine, "the caller is heard and animated", limit, |s| {
        s.call.in_call && s.phone.ringing.is_none() && heard(s, "bob")
    });
    {
        let s = lock(&engine.shared);
        assert!(s.call.state.contains("in a SIP call"));
        assert_eq!(s.call.phase.word(), "in_call", "{:?}", s.call);
    }
    // Our hang-up ends baresip's call too.
    engine.send(Command::Leave);
    closed(2);
    common::app::wait_for(&engine, "idle after our hang-up", limit, |s| {
        !s.call.in_call && s.peers.views().is_empty()
    });
    assert_eq!(
        lock(&engine.shared).call.phase,
        CallPhase::Ended {
            by: "you hung up".into()
        }
    );

    // In a call on a relay, a SIP caller is refused busy.
    common::app::wait_for(&engine, "registered after the call", limit, registered);
    let relay = Relay::start("127.0.0.1:0".parse().unwrap(), RelayConfig::default()).unwrap();
    engine.send(Command::Call(Box::new(CallSpec {
        address: relay.local_addr().to_string(),
        room: Some("lab".into()),
        name: "Alice".into(),
        ..CallSpec::default()
    })));
    common::app::wait_for(&engine, "in the relay's room", limit, |s| s.call.in_call);
    tell_baresip(control, "dial", &alice);
    closed(3);
    assert!(
        bob.text().contains("486 Busy Here"),
        "baresip: {}",
        bob.text()
    );
    let s = lock(&engine.shared);
    assert!(s.phone.ringing.is_none(), "{:?}", s.phone);
    assert!(
        s.phone.note.as_deref().is_some_and(|n| n.ends_with("busy")),
        "{:?}",
        s.phone
    );
    assert!(
        s.call.in_call && s.call.state.contains("lab"),
        "{:?}",
        s.call
    );
}

/// What the phone's row is drawn from, as the app keeps it.
struct Row {
    banner: RingingBanner,
    form: SipForm,
    settings: Settings,
    engine: Engine,
    /// The settings window, open once the row's Account… was clicked.
    call_form: lipcall::app::CallForm,
}

#[test]
fn the_banner_answers_and_the_keypad_sends_keys_through_the_ui() {
    if !have(&["kamailio", "baresip", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (kam_port, bob_port, control) = (free_port(false), free_port(false), free_port(false));
    let _kamailio = kamailio(dir.path(), kam_port, "");
    let bob = baresip(
        dir.path(),
        bob_port,
        control,
        "<sip:bob@127.0.0.1>;regint=0;audio_codecs=PCMU",
        &reversed_8k(dir.path()),
    );
    let mut settings = Settings::default();
    settings.sip.account = format!("sip:alice@127.0.0.1:{kam_port}");
    settings.sip.password = PASSWORD.into();
    let row = Row {
        banner: RingingBanner::default(),
        form: SipForm::default(),
        settings,
        engine: engine(),
        call_form: lipcall::app::CallForm::default(),
    };
    // Tall enough for the banner and the settings' account fields under the row.
    let mut h = Harness::builder()
        .with_size(egui::vec2(800.0, 1200.0))
        .build_ui_state(
            |ui: &mut egui::Ui, row: &mut Row| {
                let (call, phone) = {
                    let s = lock(&row.engine.shared);
                    (s.call.clone(), s.phone.clone())
                };
                row.banner.show(ui, &call, &row.engine);
                sip_ui(ui, &mut row.form, &phone, &row.engine);
                if row.form.editing {
                    let parts = lipcall::app::SettingsParts {
                        form: &mut row.call_form,
                        sip_form: &mut row.form,
                        inputs: &[],
                        outputs: &[],
                        engine: &row.engine,
                    };
                    lipcall::app::settings_ui(ui, &mut row.settings, parts);
                }
            },
            row,
        );
    // The account typed in and registered through the form.
    h.get_by_label("Account…").click();
    h.run();
    h.get_by_label("Register").click();
    h.run();
    let limit = Duration::from_secs(15);
    let wait = |h: &mut Harness<'_, Row>, what: &str, done: &dyn Fn(&Shared) -> bool| {
        let deadline = Instant::now() + limit;
        loop {
            h.run();
            if done(&lock(&h.state().engine.shared)) {
                return;
            }
            assert!(
                Instant::now() < deadline,
                "{what}: {:?}",
                lock(&h.state().engine.shared).phone
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    };
    wait(&mut h, "registered", &|s| {
        s.phone.registration.starts_with("registered with")
    });
    tell_baresip(control, "dial", &format!("sip:alice@127.0.0.1:{kam_port}"));
    wait(&mut h, "the banner", &|s| s.phone.ringing.is_some());
    h.run();
    assert!(h.query_by_label_contains("is calling").is_some());
    h.get_by_label("Answer").click();
    wait(&mut h, "the caller heard", &|s| heard(s, "bob"));
    wait(&mut h, "the keypad", &|s| s.phone.keypad);
    h.get_by_label("7").click();
    h.run();
    assert!(
        bob.wait_for("received event: '7' (end=1)", limit),
        "baresip: {}",
        bob.text()
    );
    wait(&mut h, "the key shown as sent", &|s| {
        s.phone.keys_sent == "7"
    });
    assert!(h.query_by_label("sent 7").is_some());
}
