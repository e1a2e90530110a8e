//! The Mumble server's side of the peer list: the server and its certificate's fingerprint
//! (trusted on first use), the channels as a tree with who is in each (a mark on those who
//! muted themselves), ours highlighted; a click on another channel moves us there.

use eframe::egui;

use super::mumble_call::MumbleView;

/// Indent of one level of the channel tree.
const INDENT: f32 = 12.0;

/// Shows the server; returns the channel clicked, to move to.
pub fn channels_ui(ui: &mut egui::Ui, view: &MumbleView) -> Option<u32> {
    let mut chosen = None;
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
                chosen = Some(row.id);
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
    chosen
}

#[cfg(test)]
mod tests {
    use egui_kittest::Harness;
    use egui_kittest::kittest::Queryable;

    use super::*;
    use crate::app::mumble_call::ChannelRow;
    use crate::net::mumble::events::Member;

    fn member(session: u32, name: &str, channel: u32, self_mute: bool, us: bool) -> Member {
        Member {
            session,
            name: name.into(),
            channel,
            self_mute,
            us,
        }
    }

    #[test]
    fn the_tree_shows_who_is_where_and_a_click_picks_another_channel() {
        let view = MumbleView {
            server: "127.0.0.1:64738".into(),
            fingerprint: vec!["AB"; 32].join(":"),
            first_visit: true,
            channels: vec![
                ChannelRow {
                    id: 0,
                    name: "Root".into(),
                    depth: 0,
                    members: vec![member(3, "Carol", 0, true, true)],
                    ours: true,
                },
                ChannelRow {
                    id: 4,
                    name: "Cellar".into(),
                    depth: 1,
                    members: vec![member(5, "Bob", 4, false, false)],
                    ours: false,
                },
            ],
            self_muted: true,
            udp: true,
        };
        let mut h = Harness::new_ui_state(
            move |ui: &mut egui::Ui, chosen: &mut Vec<u32>| {
                chosen.extend(channels_ui(ui, &view));
            },
            Vec::new(),
        );
        h.run();
        h.get_by_label("Carol (you)");
        h.get_by_label("Bob");
        h.get_by_label("muted");
        h.get_by_label("voice by UDP");
        h.get_by_label("you are muted (the others see it)");
        h.get_by_label("Root").click();
        h.run();
        assert!(h.state().is_empty(), "our own channel is no move");
        h.get_by_label("Cellar").click();
        h.run();
        assert_eq!(h.state().as_slice(), [4]);
    }
}
