//! The settings window: who you are, what you send, your devices, the port others call you
//! at, and each kind of server's own fields (a room's passphrase, which is also a Janus room's
//! PIN and a Mumble server's password; Janus's API secret and token; the NAT servers; the SIP
//! account). Kept out of the call bar, so that the bar's widgets stay the same whatever is typed.

use eframe::egui;

use super::audio_panel::mic_meter_ui;
use super::call_panel::{CallForm, codec_label};
use super::engine::{Command, Engine, lock};
use super::settings::{NatSettings, Settings};
use super::sip_panel::{SipForm, account_ui};
use crate::audio::{DeviceChoice, DeviceInfo};
use crate::codec::any::Codec;
use crate::codec::opus::codec::Bandwidth;

/// What the settings window edits besides the settings themselves.
pub struct SettingsParts<'a> {
    pub form: &'a mut CallForm,
    pub sip_form: &'a mut SipForm,
    pub inputs: &'a [DeviceInfo],
    pub outputs: &'a [DeviceInfo],
    pub engine: &'a Engine,
}

/// The window, while `open`.
pub fn settings_window(
    ctx: &egui::Context,
    open: &mut bool,
    settings: &mut Settings,
    parts: SettingsParts<'_>,
) {
    egui::Window::new("Settings")
        .open(open)
        .default_width(440.0)
        .vscroll(true)
        .show(ctx, |ui| settings_ui(ui, settings, parts));
}

/// The window's contents, section by section.
pub fn settings_ui(ui: &mut egui::Ui, settings: &mut Settings, parts: SettingsParts<'_>) {
    let SettingsParts {
        form,
        sip_form,
        inputs,
        outputs,
        engine,
    } = parts;
    ui.heading("You");
    egui::Grid::new("you").num_columns(2).show(ui, |ui| {
        let label = ui.label("Name");
        ui.add(egui::TextEdit::singleline(&mut settings.name).desired_width(160.0))
            .labelled_by(label.id)
            .on_hover_text("What others see beside your head");
        ui.end_row();
        let label = ui.label("Listening port");
        let mut port = settings.listen_port.unwrap_or(super::listen::DEFAULT_PORT);
        if ui
            .add(egui::DragValue::new(&mut port).range(1..=65535))
            .labelled_by(label.id)
            .on_hover_text("The UDP port direct calls reach you on (from the next start)")
            .changed()
        {
            settings.listen_port = Some(port);
        }
        ui.end_row();
    });
    ui.separator();
    ui.heading("Sound");
    egui::Grid::new("sound").num_columns(2).show(ui, |ui| {
        if device_picker_ui(ui, "Microphone", &mut settings.input_device, inputs) {
            engine.send(Command::SetInput(choice(&settings.input_device)));
        }
        ui.end_row();
        // The level of the microphone open now, to check the one chosen hears you.
        ui.label("Level");
        let (mic, input_status) = {
            let shared = lock(&engine.shared);
            (shared.mic.clone(), shared.input_status.clone())
        };
        match &mic {
            Some(mic) => {
                mic_meter_ui(ui, mic)
                    .on_hover_text("The microphone's level now: speak to see it move");
            }
            None => {
                ui.weak(input_status);
            }
        }
        ui.end_row();
        if device_picker_ui(ui, "Speaker", &mut settings.output_device, outputs) {
            engine.send(Command::SetOutput(choice(&settings.output_device)));
        }
        ui.end_row();
        ui.label("");
        if ui
            .button("Test speaker")
            .on_hover_text("Plays the ringtone for 2 s on the speaker chosen")
            .clicked()
        {
            engine.send(Command::TestSpeaker);
        }
        ui.end_row();
        ui.label("Send");
        ui.horizontal(|ui| {
            codec_picker_ui(ui, &mut settings.codec);
            ui.add_enabled_ui(settings.codec == Codec::Opus, |ui| {
                bandwidth_picker_ui(ui, &mut settings.bandwidth);
                frame_picker_ui(ui, &mut settings.frame_ms);
            });
        });
        ui.end_row();
    });
    ui.separator();
    ui.heading("Rooms and servers");
    egui::Grid::new("servers").num_columns(2).show(ui, |ui| {
        let label = ui.label("Passphrase");
        ui.add(
            egui::TextEdit::singleline(&mut form.passphrase)
                .password(true)
                .hint_text("(none)")
                .desired_width(160.0),
        )
        .labelled_by(label.id)
        .on_hover_text(
            "A lipcall room's key (end to end), a Janus room's PIN, or a Mumble server's \
             password; not saved",
        );
        ui.end_row();
        let label = ui.label("Janus API secret");
        ui.add(
            egui::TextEdit::singleline(&mut settings.janus.api_secret)
                .password(true)
                .hint_text("(none)")
                .desired_width(160.0),
        )
        .labelled_by(label.id);
        ui.end_row();
        let label = ui.label("Janus token");
        ui.add(
            egui::TextEdit::singleline(&mut settings.janus.token)
                .password(true)
                .hint_text("(none)")
                .desired_width(160.0),
        )
        .labelled_by(label.id);
        ui.end_row();
    });
    ui.separator();
    ui.heading("Behind a NAT");
    nat_ui(ui, &mut settings.nat);
    ui.separator();
    ui.heading("Phone (SIP)");
    account_ui(ui, sip_form, settings, engine);
}

fn choice(id: &str) -> DeviceChoice {
    DeviceChoice::from_option(Some(id).filter(|s| !s.is_empty()))
}

/// A device combo box and its label; true when the choice changed.
fn device_picker_ui(
    ui: &mut egui::Ui,
    label: &str,
    chosen: &mut String,
    devices: &[DeviceInfo],
) -> bool {
    let shown = if chosen.is_empty() {
        "default".to_owned()
    } else {
        devices
            .iter()
            .find(|d| &d.id == chosen)
            .map_or_else(|| chosen.clone(), |d| d.name.clone())
    };
    let mut changed = false;
    let label = ui.label(label);
    egui::ComboBox::from_id_salt(label.id)
        .selected_text(shown)
        .width(220.0)
        .show_ui(ui, |ui| {
            changed |= ui
                .selectable_value(chosen, String::new(), "default")
                .changed();
            for d in devices {
                changed |= ui.selectable_value(chosen, d.id.clone(), &d.name).changed();
            }
        })
        .response
        .labelled_by(label.id);
    changed
}

/// The codec we send in the next call (a call in progress keeps its own).
fn codec_picker_ui(ui: &mut egui::Ui, codec: &mut Codec) {
    egui::ComboBox::from_id_salt("codec")
        .selected_text(codec_label(*codec))
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
        .width(90.0)
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

/// Opus's frame length in the next call.
fn frame_picker_ui(ui: &mut egui::Ui, frame_ms: &mut u8) {
    egui::ComboBox::from_id_salt("frame_ms")
        .selected_text(format!("{frame_ms} ms frames"))
        .width(90.0)
        .show_ui(ui, |ui| {
            for ms in crate::codec::opus::codec::FRAME_MS {
                ui.selectable_value(frame_ms, ms, format!("{ms} ms frames"));
            }
        })
        .response
        .on_hover_text(
            "How much audio each Opus packet holds: 10 ms frames reach the peer 10 ms sooner \
             but send twice the packets (16 kb/s more of headers over IPv4); 20 ms is what \
             every peer takes.",
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

/// The STUN and TURN servers a Janus room's media asks (the STUN server serves the phone too).
fn nat_ui(ui: &mut egui::Ui, nat: &mut NatSettings) {
    egui::Grid::new("nat").num_columns(2).show(ui, |ui| {
        let label = ui.label("STUN server");
        ui.add(egui::TextEdit::singleline(&mut nat.stun).hint_text("host:3478"))
            .labelled_by(label.id);
        ui.end_row();
        let label = ui.label("TURN server");
        ui.add(egui::TextEdit::singleline(&mut nat.turn).hint_text("host:3478"))
            .labelled_by(label.id);
        ui.end_row();
        let label = ui.label("TURN user");
        ui.text_edit_singleline(&mut nat.turn_user)
            .labelled_by(label.id);
        ui.end_row();
        let label = ui.label("TURN password");
        ui.add(egui::TextEdit::singleline(&mut nat.turn_password).password(true))
            .labelled_by(label.id);
        ui.end_row();
    });
    ui.checkbox(
        &mut nat.turn_only,
        "Relay only (hide this machine's addresses)",
    );
}
