//! The Mumble server's side of the peer list: the server and its certificate's fingerprint
//! (trusted on first use), the channels as a tree with who is in each (a mark on those who
//! muted themselves), ours highlighted; a click on another channel moves us there.

use eframe::egui;

use super::engine::{Command, Engine};
use super::mumble_call::MumbleView;

/// Indent of one level of the channel tree.
const INDENT: f32 = 12.0;

pub(super) fn channels_ui(ui: &mut egui::Ui, view: &MumbleView, engine: &Engine) {
    ui.heading("Mumble");
    ui.label(format!("server {}", view.server));
    let trust = if view.first_visit {
        "first visit: trusted from now on"
    } else {
        "the one trusted before"
    };
    let short: String = view.fingerprint.chars().take(23).collect();
    ui.weak(format!("certificate {short}… ({trust})"))
        .on_hover_text(format!(
            "SHA-256 {}\nA server showing another certificate later is refused.",
            view.fingerprint
        ));
    ui.weak(if view.udp {
        "voice by UDP"
    } else {
        "voice through the TLS tunnel"
    });
    if view.self_muted {
        ui.colored_label(
            egui::Color32::from_rgb(230, 160, 60),
            "you are muted (the others see it)",
        );
    }
    for row in &view.channels {
        let depth = INDENT * row.depth as f32;
        ui.horizontal(|ui| {
            ui.add_space(depth);
            let button = ui
                .add(egui::Button::selectable(row.ours, &row.name))
                .on_hover_text(if row.ours {
                    "the channel we are in"
                } else {
                    "move to this channel"
                });
            if button.clicked() && !row.ours {
                engine.send(Command::Channel(row.id));
            }
        });
        for m in &row.members {
            ui.horizontal(|ui| {
                ui.add_space(depth + INDENT);
                let name = if m.us {
                    format!("{} (you)", m.name)
                } else {
                    m.name.clone()
                };
                ui.label(name);
                if m.self_mute {
                    ui.weak("muted");
                }
            });
        }
    }
    ui.separator();
}
