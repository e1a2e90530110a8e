//! The grid of head tiles, driven through egui_kittest: however many peers (1 to 16), in the
//! app's default window every face lies whole inside it, no two overlap, and each peer's
//! controls stay on screen and work.

mod common;

use std::net::SocketAddr;

use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use lipcall::app::ShownPeer;
use lipcall::app::tiles_ui;
use lipcall::audio::PeerId;
use lipcall::render::VARIANTS;

/// The space the app's 1280x720 window leaves for the tiles (screenshot of the real app under
/// Xvfb): less the peer list (about 212 points), the call bar's two rows and the audio row,
/// and the panel's margins.
const CENTRAL: egui::Vec2 = egui::vec2(1050.0, 610.0);

/// When the first peer joined: each next one a millisecond later.
fn peer(i: u32) -> ShownPeer {
    let addr: SocketAddr = format!("127.0.0.1:{}", 40000 + i).parse().unwrap();
    let mut peer = common::app::shown_peer(&format!("Peer {i}"), 1000 + i, addr, u64::from(i));
    peer.view.feed = PeerId(i);
    peer.view.talking = i.is_multiple_of(2);
    peer
}

fn harness(n: u32, size: egui::Vec2) -> Harness<'static, Vec<ShownPeer>> {
    harness_of((0..n).map(peer).collect(), size)
}

fn harness_of(peers: Vec<ShownPeer>, size: egui::Vec2) -> Harness<'static, Vec<ShownPeer>> {
    let mut h = Harness::builder().with_size(size).build_ui_state(
        |ui: &mut egui::Ui, peers: &mut Vec<ShownPeer>| tiles_ui(ui, peers, None),
        peers,
    );
    h.run();
    h
}

fn inside(outer: egui::Rect, inner: egui::Rect) -> bool {
    outer.expand(0.5).contains_rect(inner)
}

/// Checks the layout of `n` tiles in a window of `size`; returns the faces' rectangles.
fn check_layout(n: u32, size: egui::Vec2) -> Vec<egui::Rect> {
    let h = harness(n, size);
    let window = egui::Rect::from_min_size(egui::Pos2::ZERO, size);
    let mutes: Vec<egui::Rect> = h.get_all_by_label("Mute").map(|m| m.rect()).collect();
    assert_eq!(mutes.len(), n as usize, "{n} peers: mute boxes");
    for (i, m) in mutes.iter().enumerate() {
        assert!(
            inside(window, *m),
            "{n} peers: mute {i} at {m:?} outside {window:?}"
        );
    }
    let faces: Vec<egui::Rect> = (0..n)
        .map(|i| h.get_by_label(&format!("Peer {i}'s face")).rect())
        .collect();
    for (i, f) in faces.iter().enumerate() {
        assert!(
            inside(window, *f),
            "{n} peers: face {i} at {f:?} outside {window:?}"
        );
        for (j, g) in faces.iter().enumerate().skip(i + 1) {
            let overlap = f.intersect(*g);
            assert!(
                overlap.width() <= 0.0 || overlap.height() <= 0.0,
                "{n} peers: faces {i} {f:?} and {j} {g:?} overlap"
            );
        }
    }
    faces
}

fn smallest_side(faces: &[egui::Rect]) -> f32 {
    faces
        .iter()
        .map(|f| f.width().min(f.height()))
        .fold(f32::INFINITY, f32::min)
}

#[test]
fn eight_peers_all_faces_whole_inside_the_window() {
    let faces = check_layout(8, CENTRAL);
    // Four columns of two rows: each face about a quarter of the width.
    assert!(smallest_side(&faces) >= 200.0, "{faces:?}");
}

#[test]
fn one_to_sixteen_peers_fit_the_window() {
    for n in 1..=16 {
        let faces = check_layout(n, CENTRAL);
        // Not shrunk more than the count asks: the face's side at least the side of a square
        // grid's cell, less the header.
        let cells = (n as f32).sqrt().ceil();
        let fair = (CENTRAL.y / cells - 40.0).min(CENTRAL.x / cells - 10.0);
        assert!(
            smallest_side(&faces) >= fair,
            "{n} peers: {faces:?} < {fair}"
        );
    }
    // The whole window (no side panel) and a small one.
    check_layout(16, egui::vec2(1280.0, 720.0));
    check_layout(8, egui::vec2(640.0, 400.0));
}

#[test]
fn each_tiles_menu_reaches_that_peers_controls() {
    let mut h = harness(8, CENTRAL);
    h.get_all_by_label("Mute").nth(5).unwrap().click();
    h.run();
    assert!(h.state()[5].prefs.muted);
    assert!(h.state().iter().filter(|p| p.prefs.muted).count() == 1);

    h.get_all_by_label("More").nth(6).unwrap().click();
    h.run();
    h.get_by_label("Animate").click();
    h.run();
    assert!(!h.state()[6].prefs.animate);
    h.get_by_label("Lipreading").click();
    h.run();
    assert!(h.state()[6].prefs.lipreading);
    h.get_by_label("Visemes").click();
    h.run();
    h.get_by_label("3 visemes").click();
    h.run();
    assert_eq!(h.state()[6].prefs.visemes, "3");
    let others = h.state().iter().enumerate().filter(|(i, _)| *i != 6);
    for (_, p) in others {
        assert!(p.prefs.animate && !p.prefs.lipreading && p.prefs.visemes.is_empty());
    }
}

/// Sixteen peers in the window: the tiles are narrow, and the name is what tells them apart, so
/// each is shown whole (as wide as in a tile of its own), the mute box and menu giving up their
/// words (kept as their accessible names) instead. A tile with room keeps the words.
#[test]
fn names_stay_whole_on_sixteen_narrow_tiles() {
    let named = |n: u32| -> Vec<ShownPeer> {
        (0..n)
            .map(|i| {
                let mut p = peer(i);
                p.view.name = format!("Caller number {i}");
                p
            })
            .collect()
    };
    let alone = harness_of(named(1), CENTRAL);
    let whole = alone.get_by_label("Caller number 0").rect().width();
    assert!(alone.query_by_label("Mute").is_some() && alone.query_by_label("More").is_some());
    assert!(alone.query_by_label("…").is_none());

    let mut h = harness_of(named(16), CENTRAL);
    for i in 0..16 {
        let name = h.get_by_label(&format!("Caller number {i}")).rect();
        assert!(
            name.width() >= whole - 0.5,
            "peer {i}'s name is cut short: {} of {whole} points",
            name.width()
        );
    }
    h.get_all_by_label("Mute").nth(11).unwrap().click();
    h.run();
    assert!(h.state()[11].prefs.muted);
    h.get_all_by_label("More").nth(3).unwrap().click();
    h.run();
    h.get_by_label("Lipreading").click();
    h.run();
    assert!(h.state()[3].prefs.lipreading);
}

#[test]
fn a_tiles_menu_picks_that_peers_head() {
    let mut h = harness(4, CENTRAL);
    h.get_all_by_label("More").nth(2).unwrap().click();
    h.run();
    assert!(h.query_by_label("automatic head").is_some());
    h.get_by_label("Head").click();
    h.run();
    assert!(h.query_by_label("Automatic").is_some());
    h.get_by_label(VARIANTS[3].name).click();
    h.run();
    assert_eq!(h.state()[2].prefs.head, VARIANTS[3].name);
    // The menu says the head chosen beside the choice.
    assert!(h.query_all_by_label(VARIANTS[3].name).count() >= 1);
    assert!(h.query_by_label("automatic head").is_none());
    assert!(
        h.state()
            .iter()
            .enumerate()
            .all(|(i, p)| i == 2 || p.prefs.head.is_empty())
    );
    // Back to the automatic choice (the submenu may have stayed open).
    if h.query_by_label("Automatic").is_none() {
        h.get_by_label("Head").click();
        h.run();
    }
    h.get_by_label("Automatic").click();
    h.run();
    assert!(h.state()[2].prefs.head.is_empty());
}

/// The keyboard alone: Tab reaches each tile's mute box and menu, Enter opens the menu, and its
/// controls are reached and changed with Tab and Space.
#[test]
fn the_keyboard_alone_reaches_and_works_a_tiles_menu() {
    use egui_kittest::kittest::{NodeT, by};
    let focused_label = |h: &Harness<'static, Vec<ShownPeer>>| {
        h.query_all(by())
            .find(|n| n.is_focused())
            .map(|n| n.accesskit_node().label().unwrap_or_default())
    };
    let mut h = harness(2, CENTRAL);
    let mut reached = Vec::new();
    for _ in 0..4 {
        h.key_press(egui::Key::Tab);
        h.run();
        let at = h
            .query_all(by())
            .find(|n| n.is_focused())
            .map(|n| n.rect().min.x);
        reached.push((focused_label(&h).unwrap_or_default(), at));
    }
    // Each tile's menu and mute box, the first tile's and then the second's.
    let labels: Vec<&str> = reached.iter().map(|(l, _)| l.as_str()).collect();
    assert_eq!(labels, ["More", "Mute", "More", "Mute"], "{reached:?}");
    assert!(reached[2].1 > reached[0].1, "{reached:?}");
    let mut h = harness(2, CENTRAL);
    for _ in 0..6 {
        h.key_press(egui::Key::Tab);
        h.run();
        if focused_label(&h).as_deref() == Some("More") {
            break;
        }
    }
    assert_eq!(focused_label(&h).as_deref(), Some("More"));
    h.key_press(egui::Key::Enter);
    h.run();
    let mut in_menu = Vec::new();
    for _ in 0..12 {
        h.key_press(egui::Key::Tab);
        h.run();
        let now = focused_label(&h).unwrap_or_default();
        in_menu.push(now.clone());
        if now == "Animate" {
            break;
        }
    }
    assert_eq!(
        in_menu.last().map(String::as_str),
        Some("Animate"),
        "{in_menu:?}"
    );
    h.key_press(egui::Key::Space);
    h.run();
    let changed: Vec<bool> = h.state().iter().map(|p| p.prefs.animate).collect();
    assert_eq!(changed.iter().filter(|a| !**a).count(), 1, "{changed:?}");
}
