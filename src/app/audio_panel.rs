//! The audio bar: the mic level meter, mute and push-to-talk, what plays where, and the
//! microphone's state in words in a slot of fixed size, so that pressing M or Space changes
//! its text and moves nothing.

use std::time::{Duration, Instant};

use eframe::egui;

use super::settings::Settings;
use crate::audio::MicControls;

/// The microphone's state in a slot of fixed size, read out as a label.
fn mic_slot_ui(ui: &mut egui::Ui, keys: &MicKeys, mic: Option<&MicControls>) {
    let (text, colour) = keys.state(mic);
    let mut text = egui::RichText::new(text).strong();
    if let Some(colour) = colour {
        text = text.color(colour);
    }
    let height = ui.spacing().interact_size.y;
    ui.add_sized([MIC_SLOT_WIDTH, height], egui::Label::new(text).truncate());
}

/// The width of the microphone's state: its longest text fits.
const MIC_SLOT_WIDTH: f32 = 230.0;
/// How long a key's note stays.
const NOTE_STAYS: Duration = Duration::from_secs(3);

/// The keyboard's hold on the microphone: M toggles mute, Space talks in push-to-talk mode
/// (neither while a text field has the keyboard), and what a key did when it could do nothing.
#[derive(Debug, Default)]
pub struct MicKeys {
    talking: bool,
    note: Option<(String, Instant)>,
}

impl MicKeys {
    pub fn handle(&mut self, ctx: &egui::Context, mic: Option<&MicControls>) {
        let typing = ctx.egui_wants_keyboard_input();
        let (m, space) = ctx.input(|i| (i.key_pressed(egui::Key::M), i.key_down(egui::Key::Space)));
        let (m, space) = (m && !typing, space && !typing);
        let now = Instant::now();
        match mic {
            Some(mic) => {
                if m {
                    mic.set_muted(!mic.muted());
                    self.note = None;
                }
                mic.set_talk_pressed(space);
                if space && !mic.push_to_talk() {
                    self.note = Some(("Space talks in push-to-talk mode only".into(), now));
                }
            }
            None if m || space => {
                self.note = Some(("No microphone: nothing to mute or send".into(), now));
            }
            None => {}
        }
        self.talking = space;
        self.note
            .take_if(|(_, at)| now.duration_since(*at) > NOTE_STAYS);
    }

    /// The microphone's state as the slot says it, and its colour.
    pub fn state(&self, mic: Option<&MicControls>) -> (String, Option<egui::Color32>) {
        let red = egui::Color32::from_rgb(240, 110, 100);
        let green = egui::Color32::LIGHT_GREEN;
        if let Some((note, _)) = &self.note {
            return (note.clone(), Some(egui::Color32::YELLOW));
        }
        let Some(mic) = mic else {
            return ("No microphone".into(), None);
        };
        if mic.muted() {
            ("Muted: press M to unmute".into(), Some(red))
        } else if mic.push_to_talk() && self.talking {
            ("Talking (Space held)".into(), Some(green))
        } else if mic.push_to_talk() {
            ("Hold Space to talk".into(), None)
        } else {
            ("Microphone on: M mutes".into(), Some(green))
        }
    }
}

/// The microphone's peak level, 60 dB up to full scale, named "Microphone level" for screen
/// readers (the audio bar's and the settings window's).
pub fn mic_meter_ui(ui: &mut egui::Ui, mic: &MicControls) -> egui::Response {
    let level = mic.level();
    let fill = ((level.peak_dbfs + 60.0) / 60.0).clamp(0.0, 1.0);
    let response = ui.add(
        egui::ProgressBar::new(fill)
            .desired_width(120.0)
            .text(format!("{:.0} dBFS", level.peak_dbfs.max(-99.0))),
    );
    response.widget_info(|| {
        let mut info =
            egui::WidgetInfo::labeled(egui::accesskit::Role::Meter, true, "Microphone level");
        info.value = Some(f64::from(fill));
        info
    });
    response
}

/// The mic level meter, mute, push-to-talk, the microphone's state and the output's (the
/// devices are chosen in the settings).
pub fn audio_ui(
    ui: &mut egui::Ui,
    keys: &MicKeys,
    settings: &mut Settings,
    mic: Option<&MicControls>,
    output_status: &str,
    input_status: &str,
) {
    ui.horizontal_wrapped(|ui| {
        match mic {
            Some(mic) => {
                mic_meter_ui(ui, mic);
                let mut muted = mic.muted();
                if ui.checkbox(&mut muted, "Mute (M)").changed() {
                    mic.set_muted(muted);
                }
                if ui
                    .checkbox(&mut settings.push_to_talk, "Push-to-talk (hold Space)")
                    .changed()
                {
                    mic.set_push_to_talk(settings.push_to_talk);
                }
            }
            None => {
                ui.label(input_status);
            }
        }
        mic_slot_ui(ui, keys, mic);
        ui.separator();
        ui.label(output_status);
    });
}
