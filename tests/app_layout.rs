//! The window's layout, driven through egui_kittest and read through AccessKit as a screen
//! reader reads it: the keys M and Space say what they did in a slot that moves nothing; the
//! call bar keeps its controls whatever is typed and Tab reaches them; the settings window
//! holds each server's fields; tiles keep the order peers joined in, and one who leaves
//! leaves a notice.

mod common;

use std::time::{Duration, Instant};

use eframe::egui;
use egui::accesskit::Role;
use egui_kittest::Harness;
use egui_kittest::kittest::{NodeT, Queryable, by};
use lipcall::app::call_panel::connect_plan;
use lipcall::app::engine::{CallPhase, Engine, lock};
use lipcall::app::peer_panel::{peer_colours, peer_heads};
use lipcall::app::settings::Settings;
use lipcall::app::{
    CallForm, MicKeys, SettingsParts, ShownPeer, SipForm, audio_ui, call_ui, left_notice_ui,
    settings_ui, tiles_ui,
};
use lipcall::audio::MicControls;
use lipcall::audio::capture::capture_pipeline;
use lipcall::render::VARIANTS;

/// The audio bar with the keyboard's hold on a microphone (none: no device).
struct AudioBar {
    keys: MicKeys,
    mic: Option<MicControls>,
    settings: Settings,
}

fn audio_bar(mic: Option<MicControls>) -> Harness<'static, AudioBar> {
    let bar = AudioBar {
        keys: MicKeys::default(),
        mic,
        settings: Settings::default(),
    };
    Harness::new_ui_state(
        |ui: &mut egui::Ui, bar: &mut AudioBar| {
            bar.keys.handle(ui.ctx(), bar.mic.as_ref());
            audio_ui(
                ui,
                &bar.keys,
                &mut bar.settings,
                bar.mic.as_ref(),
                "Playing on Test (48 kHz, stereo)",
                "",
            );
        },
        bar,
    )
}

fn rect_of(h: &Harness<'_, AudioBar>, label: &str) -> egui::Rect {
    h.get_by_label_contains(label).rect()
}

#[test]
fn m_mutes_and_says_so_and_nothing_in_the_bar_moves() {
    let mut h = audio_bar(Some(MicControls::default()));
    h.run();
    assert!(
        h.query_by_label_contains("Microphone on: M mutes")
            .is_some()
    );
    let before = rect_of(&h, "Push-to-talk");
    let slot = rect_of(&h, "Microphone on");

    h.key_press(egui::Key::M);
    h.run();
    assert!(h.state().mic.as_ref().unwrap().muted());
    assert!(
        h.query_by_label_contains("Muted: press M to unmute")
            .is_some()
    );
    assert_eq!(rect_of(&h, "Push-to-talk"), before);
    assert_eq!(
        rect_of(&h, "Muted"),
        slot,
        "the slot keeps its place and size"
    );

    h.key_press(egui::Key::M);
    h.run();
    assert!(!h.state().mic.as_ref().unwrap().muted());
    assert_eq!(rect_of(&h, "Microphone on"), slot);
}

#[test]
fn space_talks_in_push_to_talk_mode_and_says_why_not_otherwise() {
    let mic = MicControls::default();
    let mut h = audio_bar(Some(mic.clone()));
    h.run();
    let slot = rect_of(&h, "Microphone on");
    h.key_down(egui::Key::Space);
    h.run();
    assert!(
        h.query_by_label_contains("Space talks in push-to-talk mode only")
            .is_some()
    );
    h.key_up(egui::Key::Space);
    h.run();

    h.get_by_label_contains("Push-to-talk").click();
    h.run();
    assert!(mic.push_to_talk());
    assert!(!mic.transmitting());
    // The note of the Space before stays a few seconds, then the state is shown again.
    h.state_mut().keys = MicKeys::default();
    h.run();
    assert!(h.query_by_label_contains("Hold Space to talk").is_some());
    h.key_down(egui::Key::Space);
    h.run();
    assert!(mic.transmitting());
    assert!(h.query_by_label_contains("Talking (Space held)").is_some());
    assert_eq!(rect_of(&h, "Talking"), slot);
    h.key_up(egui::Key::Space);
    h.run();
    assert!(!mic.transmitting());
    assert!(h.query_by_label_contains("Hold Space to talk").is_some());
}

#[test]
fn without_a_microphone_the_keys_say_there_is_none() {
    let mut h = audio_bar(None);
    h.run();
    assert!(h.query_by_label_contains("No microphone").is_some());
    h.key_press(egui::Key::M);
    h.run();
    assert!(
        h.query_by_label_contains("No microphone: nothing to mute or send")
            .is_some()
    );
}

/// The call bar as the window draws it.
struct Bar {
    form: CallForm,
    settings: Settings,
    engine: Engine,
}

fn call_bar() -> Harness<'static, Bar> {
    let bar = Bar {
        form: CallForm::default(),
        settings: Settings::default(),
        engine: common::app::headless_engine("Alice", None),
    };
    Harness::new_ui_state(
        |ui: &mut egui::Ui, bar: &mut Bar| {
            let call = lock(&bar.engine.shared).call.clone();
            call_ui(ui, &mut bar.form, &mut bar.settings, &call, &bar.engine);
        },
        bar,
    )
}

/// The roles a user acts on.
const CONTROLS: [Role; 6] = [
    Role::Button,
    Role::TextInput,
    Role::PasswordInput,
    Role::CheckBox,
    Role::ComboBox,
    Role::SpinButton,
];

fn role(n: &egui_kittest::Node<'_>) -> Role {
    n.accesskit_node().role()
}

/// A node's name as a screen reader says it.
fn label(n: &egui_kittest::Node<'_>) -> String {
    n.accesskit_node().label().unwrap_or_default()
}

/// Every control of the bar: its role, its name and where it is.
fn controls(h: &Harness<'_, Bar>) -> Vec<(Role, String, egui::Rect)> {
    h.query_all(by().predicate(|n| CONTROLS.contains(&n.role())))
        .map(|n| (role(&n), label(&n), n.rect()))
        .collect()
}

#[test]
fn the_call_bar_has_the_same_controls_in_the_same_places_whatever_is_typed() {
    let mut h = call_bar();
    h.state_mut().form.address = "127.0.0.1:5004".into();
    h.run();
    let first = controls(&h);
    let names: Vec<&str> = first.iter().map(|(_, name, _)| name.as_str()).collect();
    for wanted in ["Address", "Room", "Connect", "Leave", "Settings"] {
        assert!(names.contains(&wanted), "{wanted} in {names:?}");
    }
    for typed in [
        "",
        "http://127.0.0.1:8088/janus",
        "ws://janus.example:8188",
        "mumble://127.0.0.1/Lobby",
        "sip:bob@127.0.0.1",
        "+46 8-123 45",
        "a.very.long.host.name.example.org:5004",
    ] {
        for room in ["", "standup"] {
            h.state_mut().form.address = typed.into();
            h.state_mut().form.room = room.into();
            h.run();
            assert_eq!(controls(&h), first, "{typed:?} in room {room:?}");
        }
    }
}

#[test]
fn tab_reaches_the_address_connect_and_settings() {
    let mut h = call_bar();
    h.state_mut().form.address = "127.0.0.1:5004".into();
    h.run();
    let mut reached = Vec::new();
    for _ in 0..12 {
        h.key_press(egui::Key::Tab);
        h.run();
        if let Some(n) = h
            .query_all(by().predicate(|n| CONTROLS.contains(&n.role())))
            .find(|n| n.is_focused())
        {
            reached.push(label(&n));
        }
    }
    for wanted in ["Address", "Room", "Connect", "Settings"] {
        assert!(
            reached.iter().any(|r| r == wanted),
            "{wanted} by Tab: {reached:?}"
        );
    }
}

#[test]
fn connect_says_what_it_will_do_with_the_address() {
    assert_eq!(
        connect_plan("127.0.0.1:5004", ""),
        "Call 127.0.0.1:5004 directly"
    );
    assert_eq!(
        connect_plan("relay.example:7000", "standup"),
        "Join the room \"standup\" on the relay relay.example:7000"
    );
    assert!(connect_plan("mumble://h/Lobby", "").starts_with("Join the Mumble server"));
    assert!(connect_plan("http://h:8088/janus", "1234").starts_with("Join the Janus room"));
    assert_eq!(connect_plan("sip:bob@h", ""), "Phone sip:bob@h");
}

/// The settings window's contents.
struct Window {
    settings: Settings,
    form: CallForm,
    sip: SipForm,
    engine: Engine,
}

/// The settings window's contents drawn from `window`, tall enough for all of them.
fn settings_harness(window: Window) -> Harness<'static, Window> {
    Harness::builder()
        .with_size(egui::vec2(520.0, 900.0))
        .build_ui_state(
            |ui: &mut egui::Ui, w: &mut Window| {
                let parts = SettingsParts {
                    form: &mut w.form,
                    sip_form: &mut w.sip,
                    inputs: &[],
                    outputs: &[],
                    engine: &w.engine,
                };
                settings_ui(ui, &mut w.settings, parts);
            },
            window,
        )
}

#[test]
fn the_settings_window_holds_each_server_s_fields_and_names_them() {
    let window = Window {
        settings: Settings {
            name: String::new(),
            ..Settings::default()
        },
        form: CallForm::default(),
        sip: SipForm::default(),
        engine: common::app::headless_engine("Alice", None),
    };
    let mut h = settings_harness(window);
    h.run();
    for field in [
        "Name",
        "Listening port",
        "Microphone",
        "Speaker",
        "Passphrase",
        "Janus API secret",
        "Janus token",
        "STUN server",
        "TURN server",
        "TURN user",
        "TURN password",
        "Account",
        "Registrar",
        "Password",
    ] {
        let found = h
            .query_all(by().predicate(|n| CONTROLS.contains(&n.role())))
            .any(|n| label(&n) == field);
        assert!(found, "no control named {field:?}");
    }
    h.get_by_label("Name").focus();
    h.run();
    h.get_by_label("Name").type_text("Carol");
    h.run();
    assert_eq!(h.state().settings.name, "Carol");
}

/// The tiles and the notice row above them, as the central panel draws them.
struct Tiles {
    peers: Vec<ShownPeer>,
    left: Vec<String>,
}

fn peer(name: &str, ssrc: u32, joined_ms: u64) -> ShownPeer {
    common::app::shown_peer(name, ssrc, "127.0.0.1:5004".parse().unwrap(), joined_ms)
}

fn tiles(peers: Vec<ShownPeer>) -> Harness<'static, Tiles> {
    Harness::builder()
        .with_size(egui::vec2(1050.0, 610.0))
        .build_ui_state(
            |ui: &mut egui::Ui, t: &mut Tiles| {
                left_notice_ui(ui, &t.left);
                tiles_ui(ui, &mut t.peers, None);
            },
            Tiles {
                peers,
                left: Vec::new(),
            },
        )
}

/// The names of the faces, in reading order (row by row, left to right).
fn faces_in_reading_order(h: &Harness<'_, Tiles>) -> Vec<String> {
    let mut faces: Vec<(egui::Rect, String)> = h
        .query_all(by().predicate(|n| n.role() == Role::Image))
        .map(|n| (n.rect(), label(&n)))
        .collect();
    faces.sort_by(|(a, _), (b, _)| {
        (a.min.y.round() as i32, a.min.x.round() as i32)
            .cmp(&(b.min.y.round() as i32, b.min.x.round() as i32))
    });
    faces
        .into_iter()
        .map(|(_, name)| name.trim_end_matches("'s face").to_owned())
        .collect()
}

#[test]
fn tiles_keep_the_order_peers_joined_in_as_others_join_and_leave() {
    // SSRCs in another order than the joins, and two who joined at once (then by name).
    let mut h = tiles(vec![
        peer("Dan", 5, 30),
        peer("Ann", 900, 0),
        peer("Cid", 42, 10),
        peer("Bea", 7, 10),
    ]);
    h.run();
    assert_eq!(faces_in_reading_order(&h), ["Ann", "Bea", "Cid", "Dan"]);

    h.state_mut().peers.push(peer("Eve", 1, 50));
    h.run();
    assert_eq!(
        faces_in_reading_order(&h),
        ["Ann", "Bea", "Cid", "Dan", "Eve"]
    );

    h.state_mut().peers.retain(|p| p.view.name != "Cid");
    h.state_mut().left = vec!["Cid".into()];
    h.run();
    assert_eq!(faces_in_reading_order(&h), ["Ann", "Bea", "Dan", "Eve"]);
    assert!(h.query_by_label("Cid left").is_some());
    // Each tile says how long its peer has been in the call and how loud it is now.
    assert!(h.query_by_label("Ann's level").is_some());
    assert!(h.query_all_by_label_contains(":0").next().is_some());
}

#[test]
fn the_left_notice_comes_and_goes_without_moving_the_tiles() {
    let mut h = tiles(vec![peer("Ann", 1, 0), peer("Bob", 2, 10)]);
    h.run();
    let before = h.get_by_label("Ann's face").rect();
    h.state_mut().left = vec!["Cid".into(), "Dan".into()];
    h.run();
    assert!(h.query_by_label("Cid left · Dan left").is_some());
    assert_eq!(h.get_by_label("Ann's face").rect(), before);
    h.state_mut().left.clear();
    h.run();
    assert!(h.query_by_label_contains("left").is_none());
    assert_eq!(h.get_by_label("Ann's face").rect(), before);
}

#[test]
fn each_peer_has_a_colour_of_its_own_from_its_name() {
    let names: Vec<String> = (0..16).map(|i| format!("Peer {i}")).collect();
    let colours = peer_colours(names.iter().map(String::as_str));
    let distinct: std::collections::BTreeSet<[u8; 4]> =
        colours.iter().map(|c| c.to_array()).collect();
    assert_eq!(distinct.len(), 16, "16 peers, 16 colours");
    // A name keeps its colour from call to call while no one else in the call has it.
    assert_eq!(peer_colours(["Ann"]), peer_colours(["Ann"]));
    assert_eq!(peer_colours(["Bob", "Ann"])[1], peer_colours(["Ann"])[0]);
}

#[test]
fn each_peer_has_a_head_of_its_own_from_its_name_unless_one_is_picked() {
    let names: Vec<String> = (0..16).map(|i| format!("Peer {i}")).collect();
    let automatic = |names: &[String]| peer_heads(names.iter().map(|n| (n.as_str(), "")));
    let heads = automatic(&names);
    let n = VARIANTS.len();
    let first: std::collections::BTreeSet<&str> = heads[..n].iter().map(|v| v.name).collect();
    assert_eq!(
        first.len(),
        n,
        "the first {n} peers of a call share no head: {heads:?}"
    );
    // Past that, heads repeat, each still one of the set.
    assert!(heads.iter().all(|h| VARIANTS.contains(h)));
    // A name keeps its head from call to call while no one else in the call has it.
    let ann = peer_heads([("Ann", "")])[0];
    assert_eq!(peer_heads([("Ann", "")]), [ann]);
    let bob = peer_heads([("Bob", "")])[0];
    if bob != ann {
        assert_eq!(peer_heads([("Bob", ""), ("Ann", "")])[1], ann);
    }
    // A head picked is kept, and the automatic ones go round it.
    let pick = VARIANTS.iter().find(|v| **v != ann).unwrap();
    let picked = peer_heads([("Bob", pick.name), ("Ann", "")]);
    assert_eq!(picked[0], *pick);
    assert_eq!(picked[1], ann);
    let picked = peer_heads([("Bob", ann.name), ("Ann", "")]);
    assert_eq!(picked[0], ann);
    assert_ne!(picked[1], ann, "Ann's own head is taken by Bob's pick");
    // An unknown name is the automatic choice.
    assert_eq!(peer_heads([("Ann", "no such head")]), [ann]);
}

/// What the call's phase says of `address` once the engine has tried it.
fn failure_of(address: &str) -> String {
    use lipcall::app::engine::{CallPhase, CallSpec, Command};
    let engine = common::app::headless_engine("Alice", None);
    engine.send(Command::Call(Box::new(CallSpec {
        address: address.into(),
        ..CallSpec::default()
    })));
    common::app::wait_for(&engine, address, Duration::from_secs(10), |s| {
        matches!(s.call.phase, CallPhase::Failed { .. })
    });
    let phase = lock(&engine.shared).call.phase.clone();
    match phase {
        CallPhase::Failed { reason } => reason,
        other => panic!("{other:?}"),
    }
}

#[test]
fn an_address_without_a_port_or_host_is_told_in_a_sentence() {
    assert_eq!(failure_of("127.0.0.1"), "give the port: 127.0.0.1:5004");
    assert_eq!(
        failure_of("sip:bob@"),
        "sip:bob@ has no host (expected sip:USER@HOST)"
    );
}

#[test]
fn the_settings_window_shows_the_microphone_s_level() {
    let engine = common::app::headless_engine("Alice", None);
    common::app::wait_for(
        &engine,
        "the microphone tried",
        Duration::from_secs(10),
        |s| !s.input_status.is_empty(),
    );
    let window = Window {
        settings: Settings::default(),
        form: CallForm::default(),
        sip: SipForm::default(),
        engine,
    };
    let mut h = settings_harness(window);
    h.run();
    // Without a microphone the settings say why, where the meter would be.
    assert!(h.query_by_label("Microphone level").is_none());
    assert!(h.query_by_label_contains("No microphone").is_some());
    // With one, its meter, moving with what it hears (the audio bar's data and widget).
    let (mut feeder, reader) = capture_pipeline(48_000, 1, Duration::from_secs(1)).unwrap();
    lock(&h.state().engine.shared).mic = Some(reader.controls().clone());
    h.run();
    let level = |h: &Harness<'_, Window>| {
        h.get_by_label("Microphone level")
            .accesskit_node()
            .numeric_value()
            .expect("the meter's value")
    };
    let silent = level(&h);
    feeder.feed(&[0.5_f32; 960]);
    h.run();
    let heard = level(&h);
    assert!(
        silent < 0.05 && heard > 0.8,
        "meter {silent} in silence, {heard} at -6 dBFS"
    );
}

#[test]
fn the_settings_speaker_test_rings_for_a_moment_and_stops() {
    let window = Window {
        settings: Settings::default(),
        form: CallForm::default(),
        sip: SipForm::default(),
        engine: common::app::headless_engine("Alice", None),
    };
    let mut h = settings_harness(window);
    h.run();
    let ringing = |h: &Harness<'_, Window>| lock(&h.state().engine.shared).playback.is_ringing();
    assert!(!ringing(&h));
    h.get_by_label("Test speaker").click();
    h.run();
    let clicked = Instant::now();
    while !ringing(&h) {
        assert!(
            clicked.elapsed() < Duration::from_secs(2),
            "the test never rang"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    while ringing(&h) {
        assert!(
            clicked.elapsed() < Duration::from_secs(10),
            "the test rang on past its 2 s"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(clicked.elapsed() >= Duration::from_millis(1500));
    let call = lock(&h.state().engine.shared).call.clone();
    assert!(matches!(call.phase, CallPhase::Idle), "{call:?}");
}
