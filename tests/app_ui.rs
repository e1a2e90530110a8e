//! The per-peer controls, driven through egui_kittest, and what the engine does with them.

use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use lipcall::app::peer::{FaceRow, PeerAnimation};
use lipcall::app::peer_controls_ui;
use lipcall::app::settings::PeerPrefs;
use lipcall::vocab::FrameFeatures;

fn voiced() -> FrameFeatures {
    let mut f = lipcall::vocab::FrameFeatures::silent();
    f.energy_db = -25.0;
    f
}

/// One frame's weights and pose now: pushed, and given out at once if the look-ahead holds it
/// back.
fn face_now(
    animation: &mut PeerAnimation,
    prefs: &PeerPrefs,
    tag: u64,
    f: &FrameFeatures,
) -> Option<FaceRow> {
    let out = animation
        .step(prefs, tag, f, &[])
        .or_else(|| prefs.animate.then(|| animation.flush()).flatten());
    out.map(|(_, row)| row)
}

/// One frame's weights now.
fn animate_now(
    animation: &mut PeerAnimation,
    prefs: &PeerPrefs,
    f: &FrameFeatures,
) -> Option<[f32; 15]> {
    face_now(animation, prefs, 0, f).map(|row| row.weights)
}

fn harness() -> Harness<'static, PeerPrefs> {
    Harness::new_ui_state(
        |ui: &mut egui::Ui, prefs: &mut PeerPrefs| peer_controls_ui(ui, prefs),
        PeerPrefs::default(),
    )
}

#[test]
fn animation_off_runs_no_network_for_that_peer() {
    let mut h = harness();
    let mut animation = PeerAnimation::new(h.state());
    assert!(animate_now(&mut animation, h.state(), &voiced()).is_some());
    assert_eq!(animation.frames_animated, 1);

    h.get_by_label("Animate").click();
    h.run();
    assert!(!h.state().animate);
    for _ in 0..10 {
        assert_eq!(animate_now(&mut animation, h.state(), &voiced()), None);
    }
    assert_eq!(animation.frames_animated, 1, "the network ran while off");

    h.get_by_label("Animate").click();
    h.run();
    assert!(animate_now(&mut animation, h.state(), &voiced()).is_some());
    assert_eq!(animation.frames_animated, 2);
}

#[test]
fn viseme_set_change_reprojects_onto_the_chosen_shapes() {
    let mut h = harness();
    h.get_by_label("Visemes").click();
    h.run();
    h.get_by_label("3 visemes").click();
    h.run();
    assert_eq!(h.state().visemes, "3");
    let mut animation = PeerAnimation::new(h.state());
    assert_eq!(animation.target().map(|t| t.len()), Some(3));
    let w = animate_now(&mut animation, h.state(), &voiced()).unwrap();
    let used = w.iter().filter(|&&x| x > 1e-6).count();
    assert!(used <= 3, "weights outside the 3-shape set: {w:?}");
    assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-3);
}

#[test]
fn the_closures_slider_changes_how_readily_the_lips_shut() {
    let h = harness();
    h.get_by_label("Closures");
    // Features of real speech through the codec: count full closures at both ends.
    let (_, _, features) = lipcall::commands::animate::receiver_features(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/speech/demo.wav"),
    )
    .unwrap();
    let closed = |closures: f32| {
        let prefs = PeerPrefs {
            closures,
            ..PeerPrefs::default()
        };
        let mut animation = PeerAnimation::new(&prefs);
        features
            .iter()
            .filter_map(|f| animate_now(&mut animation, &prefs, f))
            .filter(|w| w[lipcall::vocab::Viseme::PP.index()] > 0.999)
            .count()
    };
    assert!(
        closed(1.0) > closed(-1.0),
        "{} vs {}",
        closed(1.0),
        closed(-1.0)
    );
}

#[test]
fn mute_and_jaw_mode_toggle() {
    let mut h = harness();
    h.get_by_label("Mute").click();
    h.run();
    assert!(h.state().muted);
    h.get_by_label("Jaw only").click();
    h.run();
    assert!(h.state().jaw);
    let mut animation = PeerAnimation::new(h.state());
    let w = animate_now(&mut animation, h.state(), &voiced()).unwrap();
    assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-3);
    h.get_by_label("Lipreading").click();
    h.run();
    assert!(h.state().lipreading);
}

#[test]
fn the_living_face_blinks_in_silence_and_switches_off() {
    let mut h = harness();
    assert!(h.state().life, "on by default");
    let silence = lipcall::vocab::FrameFeatures::silent();
    let mut animation = PeerAnimation::with_seed(h.state(), 99);
    // Five seconds of digital silence: the eyes blink, the head and mouth stay still.
    let rows: Vec<FaceRow> = (0..250)
        .filter_map(|n| face_now(&mut animation, h.state(), n, &silence))
        .collect();
    assert_eq!(rows.len(), 250);
    assert!(rows.iter().any(|r| r.pose.blink > 0.9), "no blink in 5 s");
    assert!(
        rows.iter()
            .all(|r| r.pose.head_is_still() && r.weights == rows[0].weights)
    );
    // Each frame's pose comes out with that frame's weights, through the look-ahead.
    let mut again = PeerAnimation::with_seed(h.state(), 99);
    let mut tagged = Vec::new();
    for n in 0..250u64 {
        tagged.extend(again.step(h.state(), n, &silence, &[]));
    }
    tagged.extend(again.flush());
    assert_eq!(tagged.len(), 250);
    for (k, (tag, row)) in tagged.iter().enumerate() {
        assert_eq!((*tag, row), (k as u64, &rows[k]));
    }

    h.get_by_label("Living face").click();
    h.run();
    assert!(!h.state().life);
    for n in 250..500 {
        let row = face_now(&mut animation, h.state(), n, &silence).unwrap();
        assert_eq!(row.pose, lipcall::vocab::FacePose::REST);
    }
    // Back on, it starts from rest and lives again.
    h.get_by_label("Living face").click();
    h.run();
    let rows: Vec<FaceRow> = (500..800)
        .filter_map(|n| face_now(&mut animation, h.state(), n, &silence))
        .collect();
    assert!(rows.iter().any(|r| r.pose.blink > 0.9));
}
