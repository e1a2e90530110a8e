//! The peers' panels: the list with each peer's link statistics, and the grid of head tiles,
//! each with that peer's controls beneath.

use eframe::egui;

use super::call_panel::codec_label;
use super::peer::{FaceRow, LEVEL_FLOOR_DB, PeerView};
use super::settings::PeerPrefs;
use super::tiles::{HeadTile, HeadTiles};
use crate::render::{Framing, HeadVariant, VARIANTS};
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

/// The order peers are shown in, in the list and the tiles: as they joined, then by name
/// (never by SSRC, which is random).
pub fn join_order(peers: &mut [ShownPeer]) {
    peers.sort_by(|a, b| (a.view.joined, &a.view.name).cmp(&(b.view.joined, &b.view.name)));
}

/// Each peer's colour, in the order given: the one its name hashes to (the same name, the same
/// colour, call after call), or the next one free where another peer of the call has that one,
/// so that up to [`PEER_COLOURS`] peers all differ. The background behind the head and the mark
/// in the list.
pub fn peer_colours<'a>(names: impl IntoIterator<Item = &'a str>) -> Vec<egui::Color32> {
    let starts = names
        .into_iter()
        .map(|name| Some(name_hash(name) as usize % PEER_COLOURS));
    spread(starts, [false; PEER_COLOURS])
        .into_iter()
        .flatten()
        .map(palette)
        .collect()
}

/// Each peer's head, in the order given as (name, the peer's `head` choice): the variant picked,
/// or where the choice is automatic (empty) the one its name hashes to, or the next one that no
/// other peer of the call has, so that the first [`VARIANTS`]`.len()` peers all differ.
pub fn peer_heads<'a>(peers: impl IntoIterator<Item = (&'a str, &'a str)>) -> Vec<HeadVariant> {
    let peers: Vec<(&str, Option<usize>)> = peers
        .into_iter()
        .map(|(name, head)| (name, VARIANTS.iter().position(|v| v.name == head)))
        .collect();
    let mut picked = [false; VARIANTS.len()];
    for i in peers.iter().filter_map(|(_, p)| *p) {
        picked[i] = true;
    }
    // Picked heads are kept as picked; the automatic ones spread over the rest.
    let automatic = spread(
        peers.iter().map(|(name, p)| {
            p.is_none()
                .then(|| (name_hash(name) >> 8) as usize % VARIANTS.len())
        }),
        picked,
    );
    peers
        .iter()
        .zip(automatic)
        .map(|((_, p), auto)| VARIANTS[p.or(auto).unwrap_or(0)])
        .collect()
}

/// For each start, the first of the `N` indices from it on (round the end) not yet `used`, which
/// it then uses (the start itself where all are); `None` (an entry fixed otherwise) takes none.
fn spread<const N: usize>(
    starts: impl IntoIterator<Item = Option<usize>>,
    mut used: [bool; N],
) -> Vec<Option<usize>> {
    starts
        .into_iter()
        .map(|start| {
            let start = start?;
            let i = (0..N)
                .map(|k| (start + k) % N)
                .find(|&i| !used[i])
                .unwrap_or(start);
            used[i] = true;
            Some(i)
        })
        .collect()
}

/// Colours to tell peers apart by.
pub const PEER_COLOURS: usize = 16;

/// FNV-1a, then murmur3's finaliser (FNV's own bits are poor for names that differ in their
/// last letter): stable across runs and platforms, unlike the standard hasher.
fn name_hash(name: &str) -> u32 {
    let mut h = name.bytes().fold(0x811c_9dc5_u32, |h, b| {
        (h ^ u32::from(b)).wrapping_mul(0x0100_0193)
    });
    h ^= h >> 16;
    h = h.wrapping_mul(0x85eb_ca6b);
    h ^= h >> 13;
    h = h.wrapping_mul(0xc2b2_ae35);
    h ^= h >> 16;
    h
}

/// Dark hues (the face stays the brightest thing in its tile), neighbours far apart on the
/// colour wheel.
fn palette(i: usize) -> egui::Color32 {
    let hue = (i * 7 % PEER_COLOURS) as f32 / PEER_COLOURS as f32;
    egui::ecolor::Hsva::new(hue, 0.6, 0.05, 1.0).into()
}

/// How long a peer has been in the call: `m:ss`, or `h:mm:ss` past an hour.
pub fn call_time(since: std::time::Duration) -> String {
    let s = since.as_secs();
    if s >= 3600 {
        format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
    } else {
        format!("{}:{:02}", s / 60, s % 60)
    }
}

/// "NAME left" for each peer who left lately, on a row of fixed height (empty without), so
/// that the tiles below do not move when it comes and goes.
pub fn left_notice_ui(ui: &mut egui::Ui, left: &[String]) {
    let height = ui.spacing().interact_size.y;
    let width = ui.available_width();
    ui.allocate_ui_with_layout(
        egui::vec2(width, height),
        egui::Layout::left_to_right(egui::Align::Center),
        |ui| {
            ui.set_min_size(egui::vec2(width, height));
            let text = left
                .iter()
                .map(|name| format!("{name} left"))
                .collect::<Vec<_>>()
                .join(" · ");
            ui.add(
                egui::Label::new(
                    egui::RichText::new(text).color(egui::Color32::from_rgb(240, 200, 120)),
                )
                .truncate(),
            );
        },
    );
}

/// Names, talking indicators and link statistics.
pub fn peer_list_ui(ui: &mut egui::Ui, peers: &[ShownPeer]) {
    ui.heading("Peers");
    if peers.is_empty() {
        ui.label("Nobody here yet.");
    }
    let colours = peer_colours(peers.iter().map(|p| p.view.name.as_str()));
    for (p, colour) in peers.iter().map(|p| &p.view).zip(colours) {
        ui.horizontal(|ui| {
            talking_dot(ui, p.talking, 12.0);
            let (mark, _) = ui.allocate_exact_size(egui::vec2(10.0, 10.0), egui::Sense::hover());
            // The tile's colour, brighter: a small mark on the panel's dark grey.
            let mut bright = egui::ecolor::Hsva::from(colour);
            bright.v = (bright.v * 8.0).min(1.0);
            ui.painter().rect_filled(mark, 2.0, bright);
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
/// viseme set, head, lip closures.
pub fn peer_controls_ui(ui: &mut egui::Ui, prefs: &mut PeerPrefs) {
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
        // A menu, not a combo box: inside a tile's menu it opens as a submenu (egui keeps one
        // popup open at a time, and a combo box's popup would close the tile's menu).
        ui.menu_button("Visemes", |ui| {
            for c in VISEME_CHOICES {
                ui.selectable_value(&mut prefs.visemes, c.to_owned(), visemes_label(c));
            }
        });
        ui.weak(visemes_label(&prefs.visemes));
        ui.menu_button("Head", |ui| {
            ui.selectable_value(&mut prefs.head, String::new(), "Automatic")
                .on_hover_text("Chosen by the name, unlike the other peers' heads");
            for v in &VARIANTS {
                ui.selectable_value(&mut prefs.head, v.name.to_owned(), v.name);
            }
        });
        ui.weak(if prefs.head.is_empty() {
            "automatic head"
        } else {
            prefs.head.as_str()
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

/// Space between tiles, in points.
const TILE_GAP: f32 = 8.0;
/// Height of a tile's header: the peer's name and its compact controls.
const TILE_HEADER: f32 = 22.0;

/// Columns and rows for `n` tiles in `avail` points, chosen to make the heads largest: a
/// head's scale is set by the smaller side of the square it must fit (the face is framed by
/// height and roughly as wide as high); fewer columns win a tie.
pub fn tile_grid(n: usize, avail: egui::Vec2) -> (usize, usize) {
    let head_side = |cols: usize| {
        let rows = n.div_ceil(cols);
        let w = (avail.x - TILE_GAP * (cols - 1) as f32) / cols as f32;
        let h = (avail.y - TILE_GAP * (rows - 1) as f32) / rows as f32 - TILE_HEADER;
        w.min(h)
    };
    let cols = (1..=n.max(1))
        .max_by(|&a, &b| head_side(a).total_cmp(&head_side(b)).then(b.cmp(&a)))
        .unwrap_or(1);
    (cols, n.max(1).div_ceil(cols))
}

/// The rectangles of `n` tiles laid out in `area`, row by row, all inside it and apart.
pub fn tile_rects(n: usize, area: egui::Rect) -> Vec<egui::Rect> {
    let (cols, rows) = tile_grid(n, area.size());
    let cell = egui::vec2(
        ((area.width() - TILE_GAP * (cols - 1) as f32) / cols as f32).max(1.0),
        ((area.height() - TILE_GAP * (rows - 1) as f32) / rows as f32).max(1.0),
    );
    (0..n)
        .map(|i| {
            let (col, row) = (i % cols, i / cols);
            let min = area.min
                + egui::vec2(col as f32, row as f32) * (cell + egui::Vec2::splat(TILE_GAP));
            egui::Rect::from_min_size(min, cell).intersect(area)
        })
        .collect()
}

/// The head tiles in a grid sized from the space there is and the number of peers: each tile
/// is a header (name, talking dot, mute, and a menu with the peer's other controls) over the
/// head, which takes the rest, so every face is whole on screen.
pub fn tiles_ui(ui: &mut egui::Ui, peers: &mut [ShownPeer], mut heads: Option<&mut HeadTiles>) {
    if peers.is_empty() {
        ui.centered_and_justified(|ui| {
            ui.label("Waiting for someone to talk… (call a peer or join a room above)");
        });
        return;
    }
    join_order(peers);
    let area = ui.available_rect_before_wrap();
    let rects = tile_rects(peers.len(), area);
    let colours = peer_colours(peers.iter().map(|p| p.view.name.as_str()));
    let looks = peer_heads(
        peers
            .iter()
            .map(|p| (p.view.name.as_str(), p.prefs.head.as_str())),
    );
    for (((shown, cell), colour), look) in peers.iter_mut().zip(rects).zip(colours).zip(looks) {
        let mut tile_ui = ui.new_child(
            egui::UiBuilder::new()
                .id_salt(("tile", shown.view.peer))
                .max_rect(cell)
                .layout(egui::Layout::top_down(egui::Align::Min)),
        );
        tile_ui.set_clip_rect(cell.intersect(ui.clip_rect()));
        tile_header_ui(&mut tile_ui, shown);
        let head = egui::Rect::from_min_max(
            egui::pos2(cell.min.x, (cell.min.y + TILE_HEADER).min(cell.max.y)),
            cell.max,
        );
        head_ui(
            &mut tile_ui,
            head,
            shown,
            (colour, look),
            heads.as_deref_mut(),
        );
    }
    ui.allocate_rect(area, egui::Sense::hover());
}

/// A tile's header row: the name (cut short to fit), a dot while talking, and at the right the
/// mute box and a menu with the rest of the peer's controls. On a narrow tile (many peers) the
/// box and the menu lose their words, keeping them as their accessible names and hover texts,
/// so that the name has the room.
fn tile_header_ui(ui: &mut egui::Ui, shown: &mut ShownPeer) {
    let p = &shown.view;
    let row = egui::Rect::from_min_size(
        ui.max_rect().min,
        egui::vec2(ui.max_rect().width(), TILE_HEADER),
    );
    let compact = row.width() < header_width_with_words(ui, &p.name);
    ui.scope_builder(
        egui::UiBuilder::new()
            .max_rect(row)
            .layout(egui::Layout::right_to_left(egui::Align::Center)),
        |ui| {
            if compact {
                ui.spacing_mut().item_spacing.x = 3.0;
                ui.spacing_mut().button_padding.x = 2.0;
            }
            // Open until a click elsewhere, so several choices can be made in one go.
            let stay_open = egui::containers::menu::MenuConfig::new()
                .close_behavior(egui::PopupCloseBehavior::CloseOnClickOutside);
            let menu =
                egui::containers::menu::MenuButton::new(if compact { "…" } else { "More" })
                    .config(stay_open)
                    .ui(ui, |ui| {
                        ui.set_max_width(260.0);
                        ui.label(egui::RichText::new(&p.name).strong());
                        peer_controls_ui(ui, &mut shown.prefs);
                    })
                    .0
                    .on_hover_text(format!("{}'s controls", p.name));
            if compact {
                let mute = ui
                    .add(egui::Checkbox::without_text(&mut shown.prefs.muted))
                    .on_hover_text(format!("Mute {}", p.name));
                let muted = shown.prefs.muted;
                mute.widget_info(|| {
                    egui::WidgetInfo::selected(egui::accesskit::Role::CheckBox, true, muted, "Mute")
                });
                menu.widget_info(|| {
                    egui::WidgetInfo::labeled(egui::accesskit::Role::Button, true, "More")
                });
            } else {
                ui.checkbox(&mut shown.prefs.muted, "Mute");
            }
            // A narrow tile keeps the name whole: the meter thinner, the time on hover.
            let meter = level_meter_ui(ui, p, compact);
            match p.in_call_since {
                Some(since) => {
                    let in_call = call_time(since.elapsed());
                    if compact {
                        meter.on_hover_text(format!("{} in the call for {in_call}", p.name));
                    } else {
                        ui.weak(in_call)
                            .on_hover_text(format!("{} has been in the call this long", p.name));
                    }
                }
                None if compact => {
                    meter.on_hover_text(format!("{} is calling you", p.name));
                }
                None => {
                    ui.weak("ringing")
                        .on_hover_text(format!("{} is calling you: not answered yet", p.name));
                }
            }
            ui.with_layout(egui::Layout::left_to_right(egui::Align::Center), |ui| {
                talking_dot(ui, p.talking, 10.0);
                ui.add(egui::Label::new(egui::RichText::new(&p.name).strong()).truncate());
            });
        },
    );
}

/// The width a tile's header needs to show the whole name, the talking dot and the mute box
/// and the menu with their words.
fn header_width_with_words(ui: &egui::Ui, name: &str) -> f32 {
    let width = |text: egui::WidgetText| {
        text.into_galley(
            ui,
            Some(egui::TextWrapMode::Extend),
            f32::INFINITY,
            egui::TextStyle::Button,
        )
        .size()
        .x
    };
    let s = ui.spacing();
    width(egui::RichText::new(name).strong().into())
        + width("Mute".into())
        + width("More".into())
        + width("00:00".into())
        + LEVEL_METER_WIDTH
        + 10.0
        + s.icon_width
        + s.icon_spacing
        + 2.0 * s.button_padding.x
        + 6.0 * s.item_spacing.x
}

/// The width of a tile's level meter.
const LEVEL_METER_WIDTH: f32 = 28.0;

/// A small bar of the peer's voice level (upright and thin on a narrow tile), named for
/// screen readers.
fn level_meter_ui(ui: &mut egui::Ui, p: &PeerView, upright: bool) -> egui::Response {
    let fill = ((p.level_db - LEVEL_FLOOR_DB) / -LEVEL_FLOOR_DB).clamp(0.0, 1.0);
    let size = if upright {
        egui::vec2(5.0, 14.0)
    } else {
        egui::vec2(LEVEL_METER_WIDTH, 8.0)
    };
    let (rect, response) = ui.allocate_exact_size(size, egui::Sense::hover());
    let painter = ui.painter();
    painter.rect_filled(rect, 1.0, egui::Color32::from_gray(50));
    let lit = if upright {
        egui::Rect::from_min_max(
            egui::pos2(rect.min.x, rect.max.y - rect.height() * fill),
            rect.max,
        )
    } else {
        egui::Rect::from_min_size(rect.min, egui::vec2(rect.width() * fill, rect.height()))
    };
    painter.rect_filled(lit, 1.0, egui::Color32::LIGHT_GREEN);
    let name = format!("{}'s level", p.name);
    response.widget_info(|| {
        egui::WidgetInfo::labeled(egui::accesskit::Role::Meter, true, name.clone())
    });
    response
}

/// A `size`-point light, green while the peer talks.
fn talking_dot(ui: &mut egui::Ui, talking: bool, size: f32) {
    let colour = if talking {
        egui::Color32::LIGHT_GREEN
    } else {
        egui::Color32::DARK_GRAY
    };
    let (dot, _) = ui.allocate_exact_size(egui::vec2(size, size), egui::Sense::hover());
    ui.painter()
        .circle_filled(dot.center(), size / 2.0 - 1.0, colour);
}

/// The peer's head in `rect`: rendered when there is a renderer, a plain panel otherwise;
/// named for screen readers (and tests) as "NAME's face".
fn head_ui(
    ui: &mut egui::Ui,
    rect: egui::Rect,
    shown: &ShownPeer,
    (colour, variant): (egui::Color32, HeadVariant),
    heads: Option<&mut HeadTiles>,
) {
    let p = &shown.view;
    let response = ui.allocate_rect(rect, egui::Sense::hover());
    response.widget_info(|| {
        egui::WidgetInfo::labeled(
            egui::accesskit::Role::Image,
            true,
            format!("{}'s face", p.name),
        )
    });
    let (w, mut pose) = match (shown.prefs.animate, shown.face) {
        (true, Some(face)) if shown.prefs.life => (VisemeWeights(face.weights), face.pose),
        (true, Some(face)) => (VisemeWeights(face.weights), FacePose::REST),
        _ => (VisemeWeights::neutral(), FacePose::REST),
    };
    // The lipreading close-up keeps the mouth steady in the frame.
    if shown.prefs.lipreading {
        pose = pose.without_head_motion();
    }
    match heads {
        Some(heads) if rect.height() >= 1.0 => {
            let tile = HeadTile {
                id: u64::from(p.peer.number()),
                framing: if shown.prefs.lipreading {
                    Framing::Mouth
                } else {
                    Framing::Face
                },
                weights: w,
                pose,
                background: linear(colour),
                variant,
            };
            heads.show(ui, rect, tile);
        }
        Some(_) => {}
        None => {
            ui.painter().rect_filled(rect, 6.0, colour);
        }
    }
}

/// An sRGB colour as the linear RGB a head's target clears to.
fn linear(colour: egui::Color32) -> [f64; 3] {
    let [r, g, b, _] = egui::Rgba::from(colour).to_array();
    [f64::from(r), f64::from(g), f64::from(b)]
}
