//! The banner of a call that rings: "NAME is calling" large across the window, pulsing, with
//! *Answer* and *Decline*, and the window asking for the user's attention (the task bar
//! flashes) until the ringing ends. A direct caller, connected as soon as heard (a lipcall
//! direct call cannot be refused before it is heard), gets the same banner for a while,
//! saying that it is connected, with *OK* and *Leave*. The ringtone and the desktop
//! notification are the engine's (`engine/ring.rs`), so they ring with the window hidden too.

use std::f32::consts::TAU;
use std::time::Duration;

use eframe::egui;

use super::engine::{self, CallPhase, CallStatus, Command, Engine};
use super::sip_call::PhoneCommand;

/// One pulse of the banner, bright to dim and back.
const PULSE: Duration = Duration::from_millis(1200);
/// How often the pulse is redrawn: enough for a smooth glow, far from a busy loop.
const PULSE_FRAME: Duration = Duration::from_millis(50);

/// What the banner remembers between frames.
#[derive(Debug, Default)]
pub struct RingingBanner {
    /// The caller the window asked attention for.
    attended: Option<String>,
    /// The direct caller whose banner was dismissed.
    dismissed: Option<String>,
}

/// What rings now, as the banner shows it.
enum Ring<'a> {
    /// A SIP call waiting for Answer or Decline.
    Asking(&'a str),
    /// A direct caller, already connected.
    Connected(&'a str),
}

impl RingingBanner {
    /// The banner, above the call bar, while a call rings; asks and stops asking for attention
    /// as the ringing starts and ends. `ui` is the window's root.
    pub fn show(&mut self, ui: &mut egui::Ui, call: &CallStatus, engine: &Engine) {
        let ctx = ui.ctx().clone();
        if std::mem::take(&mut engine::lock(&engine.shared).show_window) {
            ctx.send_viewport_cmd(egui::ViewportCommand::Minimized(false));
            ctx.send_viewport_cmd(egui::ViewportCommand::Focus);
        }
        let ring = match &call.phase {
            CallPhase::Ringing { from } => Some(Ring::Asking(from)),
            CallPhase::InCall { with, .. }
                if call.just_arrived() && self.dismissed.as_deref() != Some(with) =>
            {
                Some(Ring::Connected(with))
            }
            _ => None,
        };
        let caller = ring.as_ref().map(|r| match r {
            Ring::Asking(c) | Ring::Connected(c) => (*c).to_owned(),
        });
        if caller != self.attended {
            let attention = match &ring {
                Some(Ring::Asking(_)) => egui::UserAttentionType::Critical,
                Some(Ring::Connected(_)) => egui::UserAttentionType::Informational,
                None => egui::UserAttentionType::Reset,
            };
            ctx.send_viewport_cmd(egui::ViewportCommand::RequestUserAttention(attention));
            self.attended = caller;
        }
        if !matches!(call.phase, CallPhase::InCall { .. }) {
            self.dismissed = None;
        }
        let Some(ring) = ring else { return };
        let time = ctx.input(|i| i.time) as f32;
        let glow = 0.5 + 0.5 * (TAU * time / PULSE.as_secs_f32()).sin();
        ctx.request_repaint_after(PULSE_FRAME);
        let base = egui::Color32::from_rgb(20, 60, 110);
        let bright = egui::Color32::from_rgb(40, 130, 220);
        let fill = base.lerp_to_gamma(bright, glow);
        let frame = egui::Frame::new()
            .fill(fill)
            .inner_margin(egui::Margin::symmetric(16, 12));
        egui::Panel::top("ringing").frame(frame).show(ui, |ui| {
            ui.horizontal_wrapped(|ui| {
                let (title, note) = match &ring {
                    Ring::Asking(c) => (format!("{c} is calling"), None),
                    Ring::Connected(c) => (
                        format!("{c} called you"),
                        Some("connected: a direct call is in as soon as it is heard"),
                    ),
                };
                ui.label(
                    egui::RichText::new(title)
                        .size(30.0)
                        .strong()
                        .color(egui::Color32::WHITE),
                );
                ui.add_space(24.0);
                match ring {
                    Ring::Asking(_) => {
                        if big_button(ui, "Answer", egui::Color32::from_rgb(30, 150, 60)) {
                            engine.send(Command::Phone(PhoneCommand::Answer));
                        }
                        if big_button(ui, "Decline", egui::Color32::from_rgb(190, 40, 40)) {
                            engine.send(Command::Phone(PhoneCommand::Decline));
                        }
                    }
                    Ring::Connected(c) => {
                        if big_button(ui, "OK", egui::Color32::from_rgb(30, 150, 60)) {
                            self.dismissed = Some(c.to_owned());
                        }
                        if big_button(ui, "Leave", egui::Color32::from_rgb(190, 40, 40)) {
                            engine.send(Command::Leave);
                        }
                    }
                }
                if let Some(note) = note {
                    ui.label(egui::RichText::new(note).color(egui::Color32::WHITE));
                }
            });
        });
    }
}

fn big_button(ui: &mut egui::Ui, text: &str, fill: egui::Color32) -> bool {
    let text = egui::RichText::new(text)
        .size(22.0)
        .strong()
        .color(egui::Color32::WHITE);
    ui.add(
        egui::Button::new(text)
            .fill(fill)
            .min_size(egui::vec2(140.0, 44.0)),
    )
    .clicked()
}
