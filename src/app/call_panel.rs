//! The call bar: call a peer, join a room on a relay or a Janus server or a Mumble server's
//! channel, leave; the codec sent and whether the call is encrypted.

use eframe::egui;

use super::engine::{self, CallPhase, CallSpec, Command, Engine};
use super::settings::{NatSettings, Settings};
use crate::call::janus::is_janus_url;
use crate::call::mumble::is_mumble_url;
use crate::codec::any::Codec;
use crate::codec::opus::codec::Bandwidth;
use crate::net::janus::messages::JanusAuth;

fn non_empty(s: &str) -> Option<String> {
    let s = s.trim();
    (!s.is_empty()).then(|| s.to_string())
}

/// The call form's fields.
#[derive(Debug, Clone, Default)]
pub struct CallForm {
    pub address: String,
    pub room: String,
    pub passphrase: String,
}

/// Join a room on a relay or call a peer directly; leave; the encryption indicator.
pub fn call_ui(
    ui: &mut egui::Ui,
    form: &mut CallForm,
    settings: &mut Settings,
    call: &engine::CallStatus,
    engine: &Engine,
) {
    ui.horizontal_wrapped(|ui| {
        ui.strong("lipcall");
        ui.separator();
        let name = ui.label("Name");
        ui.add(egui::TextEdit::singleline(&mut settings.name).desired_width(90.0))
            .labelled_by(name.id);
        let address_label = ui.label("Address");
        let address = ui.add(
            egui::TextEdit::singleline(&mut form.address)
                .hint_text("host:port, Janus URL, mumble://host/channel, sip: or number")
                .desired_width(150.0),
        );
        let address = address.labelled_by(address_label.id);
        // Enter in the address field connects, as the button does.
        let entered =
            address.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter));
        let mumble = is_mumble_url(&form.address);
        if !mumble {
            ui.label("Room");
            ui.add(
                egui::TextEdit::singleline(&mut form.room)
                    .hint_text("(direct call)")
                    .desired_width(90.0),
            );
        }
        let passphrase = ui.label(if mumble {
            "Server password"
        } else {
            "Passphrase"
        });
        ui.add(
            egui::TextEdit::singleline(&mut form.passphrase)
                .password(true)
                .desired_width(90.0),
        )
        .labelled_by(passphrase.id);
        if is_janus_url(&form.address) {
            nat_menu_ui(ui, &mut settings.nat);
            ui.label("API secret");
            ui.add(
                egui::TextEdit::singleline(&mut settings.janus.api_secret)
                    .password(true)
                    .hint_text("(none)")
                    .desired_width(80.0),
            );
            ui.label("Token");
            ui.add(
                egui::TextEdit::singleline(&mut settings.janus.token)
                    .password(true)
                    .hint_text("(none)")
                    .desired_width(80.0),
            );
        }
        codec_picker_ui(ui, &mut settings.codec);
        if settings.codec == Codec::Opus {
            bandwidth_picker_ui(ui, &mut settings.bandwidth);
        }
        let label = if mumble {
            "Join server"
        } else if form.room.trim().is_empty() {
            "Call"
        } else {
            "Join room"
        };
        let connect = ui
            .add_enabled(!form.address.trim().is_empty(), egui::Button::new(label))
            .clicked();
        if (connect || entered) && !form.address.trim().is_empty() {
            settings.last_address = form.address.clone();
            settings.last_room = form.room.clone();
            engine.send(Command::Call(Box::new(CallSpec {
                address: form.address.clone(),
                room: Some(form.room.clone()),
                passphrase: Some(form.passphrase.clone()),
                name: settings.name.clone(),
                codec: settings.codec,
                janus_auth: JanusAuth {
                    api_secret: non_empty(&settings.janus.api_secret),
                    token: non_empty(&settings.janus.token),
                },
                bandwidth: settings.bandwidth,
                ice: settings.nat.ice(),
                mumble_identity: None,
            })));
        }
        if ui
            .add_enabled(
                call.in_call || call.phase.is_active(),
                egui::Button::new("Leave"),
            )
            .clicked()
        {
            engine.send(Command::Leave);
        }
        ui.separator();
        let warn = egui::Color32::from_rgb(230, 160, 60);
        match call.encryption {
            engine::Encryption::EndToEnd => {
                ui.colored_label(egui::Color32::LIGHT_GREEN, "encrypted end to end (SRTP)")
            }
            engine::Encryption::HopByHop => ui
                .colored_label(warn, "encrypted hop by hop: the server can hear the call")
                .on_hover_text(
                    "Each link is encrypted (WebRTC's DTLS-SRTP to Janus; TLS and OCB2-AES128 \
                     to Mumble), but the server decrypts every stream it forwards; a SIP call's \
                     SRTP keys travel in its SIP messages, which every proxy on the way reads. \
                     Only lipcall's own rooms with a passphrase are end to end.",
                ),
            engine::Encryption::None => ui.colored_label(warn, "NOT encrypted"),
        };
        phase_ui(ui, call);
        if call.unknown_payload > 0 {
            ui.colored_label(
                egui::Color32::from_rgb(230, 160, 60),
                format!(
                    "{} packets of unknown payload types dropped",
                    call.unknown_payload
                ),
            );
        }
        // A failed call's reason is its phase's, shown once.
        let said = matches!(&call.phase, CallPhase::Failed { reason } if Some(reason) == call.error.as_ref());
        if let Some(e) = call.error.as_ref().filter(|_| !said) {
            ui.colored_label(egui::Color32::LIGHT_RED, e);
        }
    });
}

/// The call's phase, in red when it failed, and the link's own account of it beside.
fn phase_ui(ui: &mut egui::Ui, call: &engine::CallStatus) {
    // A ringing call is said once, by the banner above (`ringing.rs`).
    if matches!(call.phase, CallPhase::Ringing { .. }) {
        return;
    }
    let phase = call.phase.describe(std::time::Instant::now());
    let colour = match call.phase {
        CallPhase::Failed { .. } => egui::Color32::LIGHT_RED,
        CallPhase::InCall { .. } => egui::Color32::LIGHT_GREEN,
        _ => ui.visuals().text_color(),
    };
    // Whole on one row: where it does not fit it starts the next row instead of breaking.
    let extend = egui::TextWrapMode::Extend;
    ui.add(egui::Label::new(egui::RichText::new(phase).color(colour).strong()).wrap_mode(extend));
    if !call.state.is_empty() {
        ui.add(egui::Label::new(egui::RichText::new(&call.state).weak()).wrap_mode(extend));
    }
}

/// The codec we send in the next call (a call in progress keeps its own).
fn codec_picker_ui(ui: &mut egui::Ui, codec: &mut Codec) {
    // One widget (its label inside), so that the row never wraps between label and box.
    egui::ComboBox::from_id_salt("codec")
        .selected_text(format!("Send {}", codec_label(*codec)))
        .width(90.0)
        .show_ui(ui, |ui| {
            for c in Codec::ALL {
                ui.selectable_value(codec, c, codec_label(c));
            }
        })
        .response
        .on_hover_text(
            "The codec we send in new calls. Opus is what most VoIP speaks; every peer may \
             send any of Opus, Speex (narrowband or wideband), PCMU, PCMA and G.722, and all are received.",
        );
}

/// The band Opus codes in the next call.
fn bandwidth_picker_ui(ui: &mut egui::Ui, bandwidth: &mut Bandwidth) {
    egui::ComboBox::from_id_salt("bandwidth")
        .selected_text(bandwidth_label(*bandwidth))
        .width(70.0)
        .show_ui(ui, |ui| {
            for b in Bandwidth::ALL {
                ui.selectable_value(bandwidth, b, bandwidth_label(b));
            }
        })
        .response
        .on_hover_text(
            "The band Opus codes: fullband (up to 20 kHz, 32 kb/s) carries the /s f th sh/ \
             that telephone bands cut; narrowband (4 kHz, 20 kb/s) saves bits.",
        );
}

fn bandwidth_label(bandwidth: Bandwidth) -> &'static str {
    match bandwidth {
        Bandwidth::Auto => "Auto band",
        Bandwidth::Narrowband => "4 kHz",
        Bandwidth::Mediumband => "6 kHz",
        Bandwidth::Wideband => "8 kHz",
        Bandwidth::Superwideband => "12 kHz",
        Bandwidth::Fullband => "20 kHz",
    }
}

pub(super) fn codec_label(codec: Codec) -> &'static str {
    match codec {
        Codec::Speex => "Speex",
        Codec::Opus => "Opus",
        Codec::Pcmu => "PCMU",
        Codec::Pcma => "PCMA",
        Codec::G722 => "G.722",
        Codec::SpeexWb => "Speex WB",
    }
}

/// The STUN and TURN servers a Janus room's media asks (kept in the settings).
fn nat_menu_ui(ui: &mut egui::Ui, nat: &mut NatSettings) {
    let label = if nat.turn.trim().is_empty() && nat.stun.trim().is_empty() {
        "NAT: none"
    } else {
        "NAT: set"
    };
    ui.menu_button(label, |ui| {
        ui.label("Behind a NAT (see docs/janus.md)");
        egui::Grid::new("nat").num_columns(2).show(ui, |ui| {
            ui.label("STUN server");
            ui.add(egui::TextEdit::singleline(&mut nat.stun).hint_text("host:3478"));
            ui.end_row();
            ui.label("TURN server");
            ui.add(egui::TextEdit::singleline(&mut nat.turn).hint_text("host:3478"));
            ui.end_row();
            ui.label("TURN user");
            ui.text_edit_singleline(&mut nat.turn_user);
            ui.end_row();
            ui.label("TURN password");
            ui.add(egui::TextEdit::singleline(&mut nat.turn_password).password(true));
            ui.end_row();
        });
        ui.checkbox(
            &mut nat.turn_only,
            "Relay only (hide this machine's addresses)",
        );
    })
    .response
    .on_hover_text("STUN and TURN servers for Janus rooms when this machine is behind a NAT");
}
