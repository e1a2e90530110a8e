//! The peers' panels: the list with each peer's link statistics, and the grid of head tiles,
//! each with that peer's controls beneath.

use eframe::egui;

use super::call_panel::codec_label;
use super::peer::{FaceRow, PeerView};
use super::settings::PeerPrefs;
use super::tiles::{HeadTile, HeadTiles};
use crate::render::Framing;
use crate::vocab::{FacePose, VisemeWeights};

/// One peer as a UI frame shows it: what the engine says of it, its face for the audio heard
/// now, and its choices (which the controls edit).
#[derive(Debug, Clone)]
pub struct ShownPeer {
    pub view: PeerView,
    pub face: Option<FaceRow>,
    pub prefs: PeerPrefs,
    /// UI frames that showed weights for it.
    pub frames_shown: u64,
}

/// Names, talking indicators and link statistics.
pub fn peer_list_ui(ui: &mut egui::Ui, peers: &[ShownPeer]) {
    ui.heading("Peers");
    if peers.is_empty() {
        ui.label("Nobody here yet.");
    }
    for p in peers.iter().map(|p| &p.view) {
        ui.horizontal(|ui| {
            let colour = if p.talking {
                egui::Color32::LIGHT_GREEN
            } else {
                egui::Color32::DARK_GRAY
            };
            let (dot, _) = ui.allocate_exact_size(egui::vec2(12.0, 12.0), egui::Sense::hover());
            ui.painter().circle_filled(dot.center(), 5.0, colour);
            ui.strong(&p.name);
            if let Some(codec) = p.codec {
                ui.label(codec_label(codec));
            }
            if p.is_demo {
                ui.weak("(demo)");
            }
        });
        ui.weak(format!(
            "{}  loss {:.1}%  jitter {:.1} ms  delay {:.0} ms",
            p.addr, p.loss_percent, p.jitter_ms, p.delay_ms
        ));
        if p.frames_recovered > 0 {
            ui.weak(format!(
                "{} lost frames rebuilt from FEC",
                p.frames_recovered
            ));
        }
        if p.unknown_payload > 0 {
            ui.colored_label(
                egui::Color32::from_rgb(230, 160, 60),
                format!(
                    "{} packets of an unknown payload type dropped",
                    p.unknown_payload
                ),
            );
        }
        ui.separator();
    }
}

/// The viseme sets offered: the network's own, the paper's reduced sets and the full one.
pub const VISEME_CHOICES: [&str; 7] = ["", "2", "3", "4", "5", "6", "15"];

fn visemes_label(choice: &str) -> String {
    if choice.is_empty() {
        "network's visemes".into()
    } else {
        format!("{choice} visemes")
    }
}

/// One peer's controls: animation, the living face, mute, volume, lipreading view, jaw mode,
/// viseme set, lip closures.
pub fn peer_controls_ui(ui: &mut egui::Ui, id: u32, prefs: &mut PeerPrefs) {
    ui.horizontal_wrapped(|ui| {
        ui.checkbox(&mut prefs.animate, "Animate");
        ui.add_enabled(
            prefs.animate,
            egui::Checkbox::new(&mut prefs.life, "Living face"),
        )
        .on_hover_text("Blinks, glances, and head nods and tilts with the voice");
        ui.checkbox(&mut prefs.muted, "Mute");
        ui.add(
            egui::Slider::new(&mut prefs.volume, 0.0..=2.0)
                .text("Vol")
                .max_decimals(1),
        );
        ui.checkbox(&mut prefs.lipreading, "Lipreading");
        ui.checkbox(&mut prefs.jaw, "Jaw only");
        egui::ComboBox::new(("visemes", id), "Visemes")
            .selected_text(visemes_label(&prefs.visemes))
            .width(140.0)
            .show_ui(ui, |ui| {
                for c in VISEME_CHOICES {
                    ui.selectable_value(&mut prefs.visemes, c.to_owned(), visemes_label(c));
                }
            });
        ui.scope(|ui| {
            // Narrower than the volume slider, so the row fits a third-of-the-window tile.
            ui.spacing_mut().slider_width = 64.0;
            ui.add_enabled(
                !prefs.jaw,
                egui::Slider::new(&mut prefs.closures, -1.0..=1.0)
                    .text("Closures")
                    .step_by(0.25)
                    .show_value(false),
            )
            .on_hover_text(
                "Lip closures for /p b m/: left, only the surest; right, nearly all of them, \
                 at the cost of closing where there is none",
            );
        });
    });
}

/// A grid of head tiles, each with its controls beneath.
pub fn tiles_ui(ui: &mut egui::Ui, peers: &mut [ShownPeer], mut heads: Option<&mut HeadTiles>) {
    if peers.is_empty() {
        ui.centered_and_justified(|ui| {
            ui.label("Waiting for someone to talk… (call a peer or join a room above)");
        });
        return;
    }
    let n = peers.len();
    let avail = ui.available_size();
    let cols = (1..=n)
        .min_by_key(|&c| {
            let rows = n.div_ceil(c);
            let w = avail.x / c as f32;
            let h = avail.y / rows as f32 - 100.0;
            // The largest square head that fits.
            -(w.min(h).max(1.0) as i64)
        })
        .unwrap_or(1);
    let rows = n.div_ceil(cols);
    let tile_w = (avail.x / cols as f32 - 8.0).max(50.0);
    let tile_h = (avail.y / rows as f32 - 8.0).max(80.0);
    egui::Grid::new("tiles").spacing([8.0, 8.0]).show(ui, |ui| {
        for (i, shown) in peers.iter_mut().enumerate() {
            let p = &shown.view;
            ui.allocate_ui(egui::vec2(tile_w, tile_h), |ui| {
                ui.set_min_size(egui::vec2(tile_w, tile_h));
                ui.vertical(|ui| {
                    ui.horizontal(|ui| {
                        ui.strong(&p.name);
                        if p.talking {
                            ui.colored_label(egui::Color32::LIGHT_GREEN, "talking");
                        }
                    });
                    // Room for the name line and up to three rows of controls.
                    let head_h = (tile_h - 100.0).max(40.0);
                    let (rect, _) =
                        ui.allocate_exact_size(egui::vec2(tile_w, head_h), egui::Sense::hover());
                    let (w, mut pose) = match (shown.prefs.animate, shown.face) {
                        (true, Some(face)) if shown.prefs.life => {
                            (VisemeWeights(face.weights), face.pose)
                        }
                        (true, Some(face)) => (VisemeWeights(face.weights), FacePose::REST),
                        _ => (VisemeWeights::neutral(), FacePose::REST),
                    };
                    // The lipreading close-up keeps the mouth steady in the frame.
                    if shown.prefs.lipreading {
                        pose = pose.without_head_motion();
                    }
                    if let Some(heads) = heads.as_deref_mut() {
                        let tile = HeadTile {
                            id: u64::from(p.ssrc),
                            framing: if shown.prefs.lipreading {
                                Framing::Mouth
                            } else {
                                Framing::Face
                            },
                            weights: w,
                            pose,
                        };
                        heads.show(ui, rect, tile);
                    } else {
                        ui.painter()
                            .rect_filled(rect, 6.0, egui::Color32::from_gray(38));
                    }
                    peer_controls_ui(ui, p.ssrc, &mut shown.prefs);
                });
            });
            if (i + 1) % cols == 0 {
                ui.end_row();
            }
        }
    });
}
