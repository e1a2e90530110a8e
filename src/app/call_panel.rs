//! The call bar: call a peer, join a room on a relay or a Janus server or a Mumble server's
//! channel, leave, open the settings; below it, whether the call is encrypted and its phase.

use eframe::egui;

use super::engine::{self, CallPhase, CallSpec, Command, Engine};
use super::settings::Settings;
use super::sip_call::is_sip_address;
use crate::call::janus::is_janus_url;
use crate::call::mumble::is_mumble_url;
use crate::codec::any::Codec;
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
    /// The settings window is open.
    pub settings_open: bool,
}

/// The width of the address field and of the Connect button: fixed, so that nothing in the
/// bar moves with what is typed.
const ADDRESS_WIDTH: f32 = 260.0;
const CONNECT_WIDTH: f32 = 80.0;

/// What Connect does with the address typed (and the room).
pub fn connect_plan(address: &str, room: &str) -> String {
    let (address, room) = (address.trim(), room.trim());
    if address.is_empty() {
        "Type an address to call or a server to join".into()
    } else if is_mumble_url(address) {
        format!("Join the Mumble server {address}")
    } else if is_janus_url(address) {
        format!("Join the Janus room {room:?} at {address}")
    } else if is_sip_address(address) {
        format!("Phone {address}")
    } else if room.is_empty() {
        format!("Call {address} directly")
    } else {
        format!("Join the room {room:?} on the relay {address}")
    }
}

/// The call bar: the same widgets whatever is typed (an address, a room, Connect, Leave,
/// Settings) on one row, and the call's state on the row below.
pub fn call_ui(
    ui: &mut egui::Ui,
    form: &mut CallForm,
    settings: &mut Settings,
    call: &engine::CallStatus,
    engine: &Engine,
) {
    ui.horizontal(|ui| {
        ui.strong("lipcall");
        ui.separator();
        let address_label = ui.label("Address");
        let address = ui
            .add(
                egui::TextEdit::singleline(&mut form.address)
                    .hint_text("host:port, sip:, number, Janus or mumble:// URL")
                    .desired_width(ADDRESS_WIDTH),
            )
            .labelled_by(address_label.id);
        // Enter in the address field connects, as the button does.
        let entered = address.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter));
        let room = ui.label("Room");
        ui.add(
            egui::TextEdit::singleline(&mut form.room)
                .hint_text("(none)")
                .desired_width(110.0),
        )
        .labelled_by(room.id)
        .on_hover_text("A room on a relay or a Janus server; none for a direct call");
        let typed = !form.address.trim().is_empty();
        let height = ui.spacing().interact_size.y;
        let connect = ui
            .add_enabled_ui(typed, |ui| {
                ui.add_sized([CONNECT_WIDTH, height], egui::Button::new("Connect"))
            })
            .inner
            .on_hover_text(connect_plan(&form.address, &form.room))
            .on_disabled_hover_text(connect_plan(&form.address, &form.room))
            .clicked();
        if (connect || entered) && typed {
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
                frame_ms: settings.frame_ms,
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
        if ui
            .selectable_label(form.settings_open, "Settings")
            .on_hover_text(
                "Name, devices, codec, listening port, passphrase, Janus and NAT servers, \
                 SIP account",
            )
            .clicked()
        {
            form.settings_open = !form.settings_open;
        }
    });
    ui.horizontal_wrapped(|ui| status_ui(ui, call));
}

/// The call's encryption, phase and problems.
fn status_ui(ui: &mut egui::Ui, call: &engine::CallStatus) {
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
            warn,
            format!(
                "{} packets of unknown payload types dropped",
                call.unknown_payload
            ),
        );
    }
    // A failed call's reason is its phase's, shown once.
    let said =
        matches!(&call.phase, CallPhase::Failed { reason } if Some(reason) == call.error.as_ref());
    if let Some(e) = call.error.as_ref().filter(|_| !said) {
        ui.colored_label(egui::Color32::LIGHT_RED, e);
    }
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
