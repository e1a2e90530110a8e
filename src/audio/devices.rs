//! Input and output devices: listing them for the pickers and opening the chosen one.
//!
//! cpal reports a "default" device even on a machine without a sound card; such a device fails
//! when its configuration is asked for or its stream is built. Both failures come back as
//! [`AudioError::NoOutput`] / [`AudioError::NoInput`], never a panic.

use cpal::traits::{DeviceTrait, HostTrait};

use super::error::AudioError;

/// Which device to open.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum DeviceChoice {
    /// The host's default device.
    #[default]
    Default,
    /// A device by the id [`DeviceInfo::id`] gave (stable across runs, fit for a settings file).
    Id(String),
}

impl DeviceChoice {
    /// `None` or "default" means the default device; anything else is an id.
    pub fn from_option(id: Option<&str>) -> Self {
        match id {
            None | Some("default") => Self::Default,
            Some(id) => Self::Id(id.to_string()),
        }
    }
}

/// One entry of a device picker.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceInfo {
    /// Stable id, to pass back in [`DeviceChoice::Id`].
    pub id: String,
    /// Human-readable name.
    pub name: String,
    pub is_default: bool,
    /// The device's default stream format ("44100 Hz, 2 ch, i16"), `None` when it cannot be
    /// opened at all.
    pub format: Option<String>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Direction {
    Input,
    Output,
}

fn describe(config: &cpal::SupportedStreamConfig) -> String {
    format!(
        "{} Hz, {} ch, {}",
        config.sample_rate(),
        config.channels(),
        config.sample_format()
    )
}

fn default_config(
    device: &cpal::Device,
    dir: Direction,
) -> Result<cpal::SupportedStreamConfig, cpal::Error> {
    match dir {
        Direction::Input => device.default_input_config(),
        Direction::Output => device.default_output_config(),
    }
}

fn device_id(device: &cpal::Device) -> Option<String> {
    device.id().ok().map(|id| id.to_string())
}

fn device_name(device: &cpal::Device) -> String {
    device
        .description()
        .map(|d| d.name().to_string())
        .unwrap_or_else(|_| device.to_string())
}

/// The device buffer to ask for, in frames: `period` where the device says it can (its default
/// is often several times that, all of it heard, or captured, as delay), else its default
/// (`None`).
pub(crate) fn period(
    supported: &cpal::SupportedBufferSize,
    rate: u32,
    period: std::time::Duration,
) -> Option<u32> {
    let wanted = (period.as_secs_f64() * f64::from(rate)).round() as u32;
    match *supported {
        cpal::SupportedBufferSize::Range { min, max } if min <= max => Some(wanted.clamp(min, max)),
        _ => None,
    }
}

/// The platform's default host (ALSA on Linux; its pulse plugin reaches PulseAudio/PipeWire).
pub(crate) fn host() -> cpal::Host {
    cpal::default_host()
}

fn list(dir: Direction) -> Result<Vec<DeviceInfo>, AudioError> {
    let host = host();
    let default = match dir {
        Direction::Input => host.default_input_device(),
        Direction::Output => host.default_output_device(),
    }
    .and_then(|d| device_id(&d));
    let devices = match dir {
        Direction::Input => host.input_devices().map(|d| d.collect::<Vec<_>>()),
        Direction::Output => host.output_devices().map(|d| d.collect::<Vec<_>>()),
    }
    .map_err(|e| AudioError::Host(e.to_string()))?;
    let mut out: Vec<DeviceInfo> = devices
        .iter()
        .filter_map(|d| {
            let id = device_id(d)?;
            Some(DeviceInfo {
                is_default: default.as_deref() == Some(id.as_str()),
                name: device_name(d),
                format: default_config(d, dir).ok().map(|c| describe(&c)),
                id,
            })
        })
        .collect();
    // Defaults first, then openable devices, then by name: what a picker wants on top.
    out.sort_by(|a, b| {
        (!a.is_default, a.format.is_none(), &a.name).cmp(&(
            !b.is_default,
            b.format.is_none(),
            &b.name,
        ))
    });
    Ok(out)
}

/// Input devices, the default first.
pub fn input_devices() -> Result<Vec<DeviceInfo>, AudioError> {
    list(Direction::Input)
}

/// Output devices, the default first.
pub fn output_devices() -> Result<Vec<DeviceInfo>, AudioError> {
    list(Direction::Output)
}

/// A device with the stream format it will run at.
pub(crate) struct Opened {
    pub device: cpal::Device,
    pub config: cpal::SupportedStreamConfig,
    pub name: String,
}

pub(crate) fn no_device(dir: Direction, reason: impl Into<String>) -> AudioError {
    let reason = reason.into();
    match dir {
        Direction::Input => AudioError::NoInput { reason },
        Direction::Output => AudioError::NoOutput { reason },
    }
}

/// Finds the chosen device and its native (default) format.
pub(crate) fn open(choice: &DeviceChoice, dir: Direction) -> Result<Opened, AudioError> {
    let device = match choice {
        DeviceChoice::Default => {
            let host = host();
            match dir {
                Direction::Input => host.default_input_device(),
                Direction::Output => host.default_output_device(),
            }
            .ok_or_else(|| no_device(dir, "the system has none"))?
        }
        DeviceChoice::Id(id) => {
            let not_found = || AudioError::DeviceNotFound { id: id.clone() };
            let parsed: cpal::DeviceId = id.parse().map_err(|_| not_found())?;
            cpal::host_from_id(parsed.host())
                .ok()
                .and_then(|h| h.device_by_id(&parsed))
                .ok_or_else(not_found)?
        }
    };
    let config = default_config(&device, dir).map_err(|e| no_device(dir, e.to_string()))?;
    Ok(Opened {
        name: device_name(&device),
        device,
        config,
    })
}
