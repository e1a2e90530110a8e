//! The audio bar: microphone and speaker pickers, the mic level meter, mute and push-to-talk.

use eframe::egui;

use super::engine::{Command, Engine};
use super::settings::Settings;
use crate::audio::{DeviceChoice, DeviceInfo};

/// Device pickers, the mic level meter, mute and push-to-talk.
#[allow(clippy::too_many_arguments)]
pub(super) fn audio_ui(
    ui: &mut egui::Ui,
    settings: &mut Settings,
    mic: Option<&crate::audio::MicControls>,
    output_status: &str,
    input_status: &str,
    inputs: &[DeviceInfo],
    outputs: &[DeviceInfo],
    engine: &Engine,
) {
    ui.horizontal_wrapped(|ui| {
        if device_picker_ui(ui, "Microphone", &mut settings.input_device, inputs) {
            engine.send(Command::SetInput(DeviceChoice::from_option(
                Some(settings.input_device.as_str()).filter(|s| !s.is_empty()),
            )));
        }
        if device_picker_ui(ui, "Speaker", &mut settings.output_device, outputs) {
            engine.send(Command::SetOutput(DeviceChoice::from_option(
                Some(settings.output_device.as_str()).filter(|s| !s.is_empty()),
            )));
        }
        match mic {
            Some(mic) => {
                let level = mic.level();
                let fill = ((level.peak_dbfs + 60.0) / 60.0).clamp(0.0, 1.0);
                ui.add(
                    egui::ProgressBar::new(fill)
                        .desired_width(120.0)
                        .text(format!("{:.0} dBFS", level.peak_dbfs.max(-99.0))),
                );
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
                ui.label(if mic.transmitting() { "sending" } else { "" });
            }
            None => {
                ui.label(input_status);
            }
        }
        ui.separator();
        ui.label(output_status);
    });
}

/// A device combo box; true when the choice changed.
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
    ui.label(label);
    egui::ComboBox::from_id_salt(label)
        .selected_text(shown)
        .width(160.0)
        .show_ui(ui, |ui| {
            changed |= ui
                .selectable_value(chosen, String::new(), "default")
                .changed();
            for d in devices {
                changed |= ui.selectable_value(chosen, d.id.clone(), &d.name).changed();
            }
        });
    changed
}
