//! The banner of a call that rings: "NAME is calling" large across the window, pulsing, with
//! *Answer* and *Decline*, and the window asking for the user's attention (the task bar
//! flashes) until the ringing ends. A SIP call and a direct caller ring alike: the buttons go
//! to the phone or to the engine's consent (a direct caller hears our microphone only once
//! answered). The ringtone and the desktop notification are the engine's (`engine/ring.rs`),
//! so they ring with the window hidden too.

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
        let ringing = match &call.phase {
            CallPhase::Ringing { from, caller } => Some((from.clone(), *caller)),
            _ => None,
        };
        let from = ringing.as_ref().map(|(from, _)| from.clone());
        if from != self.attended {
            let attention = match &from {
                Some(_) => egui::UserAttentionType::Critical,
                None => egui::UserAttentionType::Reset,
            };
            ctx.send_viewport_cmd(egui::ViewportCommand::RequestUserAttention(attention));
            self.attended = from;
        }
        let Some((from, caller)) = ringing else {
            return;
        };
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
                ui.label(
                    egui::RichText::new(format!("{from} is calling"))
                        .size(30.0)
                        .strong()
                        .color(egui::Color32::WHITE),
                );
                ui.add_space(24.0);
                if big_button(ui, "Answer", egui::Color32::from_rgb(30, 150, 60)) {
                    engine.send(match caller {
                        Some(addr) => Command::AnswerCaller(addr),
                        None => Command::Phone(PhoneCommand::Answer),
                    });
                }
                if big_button(ui, "Decline", egui::Color32::from_rgb(190, 40, 40)) {
                    engine.send(match caller {
                        Some(addr) => Command::DeclineCaller(addr),
                        None => Command::Phone(PhoneCommand::Decline),
                    });
                }
                if caller.is_some() {
                    ui.label(
                        egui::RichText::new("you hear them; they hear you once you answer")
                            .color(egui::Color32::WHITE),
                    );
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
