//! The phone's row under the call bar: the SIP account (URI, registrar, local port, password;
//! the call bar's STUN server serves the phone too) and how its
//! registration stands, and the DTMF keypad while a SIP call takes keys (a call that rings has
//! the window's banner, `ringing.rs`). Calls are dialled in the call bar's address field (a `sip:`
//! URI or a number).

use eframe::egui;

use super::engine::{Command, Engine};
use super::settings::Settings;
use super::sip_call::{PhoneCommand, PhoneNetwork, PhoneStatus};

/// The keypad's keys, row by row.
const KEYPAD: [[&str; 3]; 4] = [
    ["1", "2", "3"],
    ["4", "5", "6"],
    ["7", "8", "9"],
    ["*", "0", "#"],
];

/// The account form's state.
#[derive(Debug, Clone, Default)]
pub struct SipForm {
    /// The account was asked for: the settings window opens at it.
    pub editing: bool,
    /// Why the account given cannot be used.
    pub error: Option<String>,
}

/// Tells the engine to use the settings' account (none where it is empty), its local port
/// and the NAT settings' STUN server.
pub fn use_account(settings: &Settings, engine: &Engine) -> Result<(), String> {
    let account = settings.sip.account().map_err(|e| e.to_string())?;
    let stun = settings.nat.stun.trim();
    let ca = settings.sip.ca.trim();
    let ca = if ca.is_empty() {
        None
    } else {
        Some(std::fs::read(ca).map_err(|e| format!("CA {ca}: {e}"))?)
    };
    let network = PhoneNetwork {
        stun: (!stun.is_empty()).then(|| stun.to_owned()),
        sip_port: (settings.sip.local_port != 0).then_some(settings.sip.local_port),
        ca,
        frame_ms: settings.frame_ms,
    };
    engine.send(Command::Phone(PhoneCommand::Network(network)));
    engine.send(Command::Phone(PhoneCommand::Account(account)));
    Ok(())
}

pub fn sip_ui(ui: &mut egui::Ui, form: &mut SipForm, phone: &PhoneStatus, engine: &Engine) {
    ui.horizontal_wrapped(|ui| {
        ui.label("Phone (SIP)");
        match &phone.account {
            Some(account) => {
                ui.label(account);
                ui.weak(&phone.registration);
            }
            None => {
                ui.weak("no account: sip: addresses can still be called directly");
            }
        }
        if ui
            .button("Account…")
            .on_hover_text("The SIP account, in the settings")
            .clicked()
        {
            form.editing = true;
        }
        if let Some(note) = &phone.note {
            ui.weak(note);
        }
    });
    if phone.keypad {
        keypad_ui(ui, phone, engine);
    }
}

/// The account's fields and Register, in the settings window.
pub fn account_ui(ui: &mut egui::Ui, form: &mut SipForm, settings: &mut Settings, engine: &Engine) {
    egui::Grid::new("sip account")
        .num_columns(2)
        .show(ui, |ui| {
            let label = ui.label("Account");
            ui.add(
                egui::TextEdit::singleline(&mut settings.sip.account)
                    .hint_text("sip:user@provider")
                    .desired_width(170.0),
            )
            .labelled_by(label.id);
            ui.end_row();
            let label = ui.label("Registrar");
            ui.add(
                egui::TextEdit::singleline(&mut settings.sip.registrar)
                    .hint_text("(the account's domain)")
                    .desired_width(170.0),
            )
            .labelled_by(label.id);
            ui.end_row();
            let label = ui.label("Local port");
            ui.add(egui::DragValue::new(&mut settings.sip.local_port).range(0..=65535))
                .labelled_by(label.id)
                .on_hover_text("The UDP port SIP listens on (0: any free one)");
            ui.end_row();
            let label = ui.label("CA");
            ui.add(
                egui::TextEdit::singleline(&mut settings.sip.ca)
                    .hint_text("(system roots)")
                    .desired_width(170.0),
            )
            .labelled_by(label.id)
            .on_hover_text("A PEM file of a TLS registrar's own certificate authority");
            ui.end_row();
            let label = ui.label("Password");
            ui.add(
                egui::TextEdit::singleline(&mut settings.sip.password)
                    .password(true)
                    .desired_width(170.0),
            )
            .labelled_by(label.id);
            ui.end_row();
        });
    ui.horizontal_wrapped(|ui| {
        if ui
            .button("Register")
            .on_hover_text(
                "Registers with the account and rings here with its calls; kept in the \
                 settings file, which only you can read. An empty account stops it.",
            )
            .clicked()
        {
            form.error = use_account(settings, engine).err();
        }
        if let Some(e) = &form.error {
            ui.colored_label(egui::Color32::LIGHT_RED, e);
        }
    });
}

fn keypad_ui(ui: &mut egui::Ui, phone: &PhoneStatus, engine: &Engine) {
    ui.horizontal(|ui| {
        ui.label("Keypad");
        egui::Grid::new("keypad").show(ui, |ui| {
            for row in KEYPAD {
                for key in row {
                    if ui.button(key).clicked() {
                        engine.send(Command::Phone(PhoneCommand::Keys(key.to_owned())));
                    }
                }
                ui.end_row();
            }
        });
        if !phone.keys_sent.is_empty() {
            ui.weak(format!("sent {}", phone.keys_sent));
        }
    });
}
