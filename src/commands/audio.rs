//! `lipcall devices`: what the audio layer sees, without the app.

use std::time::Duration;

use anyhow::Result;

use crate::audio::{
    self, Capture, DeviceChoice, DeviceInfo, OutputStatus, Playback, PlaybackConfig,
};

/// `lipcall devices`'s flags.
#[derive(Debug, Clone, clap::Args)]
pub struct DevicesArgs {
    /// Output device id (from the list), or "default".
    #[arg(long)]
    pub output: Option<String>,
    /// Input device id (from the list), or "default".
    #[arg(long)]
    pub input: Option<String>,
}

fn print_list(title: &str, list: Result<Vec<DeviceInfo>, audio::AudioError>) {
    println!("{title}:");
    match list {
        Ok(list) if list.is_empty() => println!("  (none)"),
        Ok(list) => {
            for d in list {
                println!(
                    "  {}{}  [{}]  {}",
                    if d.is_default { "* " } else { "  " },
                    d.name,
                    d.id,
                    d.format.as_deref().unwrap_or("cannot open")
                );
            }
        }
        Err(e) => println!("  {e}"),
    }
}

/// Lists devices, then opens the default (or chosen) ones briefly. Having no audio is not a
/// failure: the app runs receive-only or silent, and this says which.
pub fn devices(output: Option<&str>, input: Option<&str>) -> Result<()> {
    print_list("output devices", audio::output_devices());
    print_list("input devices", audio::input_devices());
    let config = PlaybackConfig {
        device: DeviceChoice::from_option(output),
        ..PlaybackConfig::default()
    };
    let playback = Playback::start(config)?;
    std::thread::sleep(Duration::from_millis(200));
    match playback.status() {
        OutputStatus::Playing {
            device,
            rate,
            channels,
        } => {
            let s = playback.stats();
            println!(
                "output: {device}, {rate} Hz, {channels} ch, latency {:.1} ms, {} frames played",
                s.latency.as_secs_f64() * 1000.0,
                s.frames_played
            );
        }
        OutputStatus::Silent { reason } => println!("output: {reason}"),
    }
    match Capture::start(&DeviceChoice::from_option(input)) {
        Ok(c) => {
            std::thread::sleep(Duration::from_millis(200));
            let (rate, ch) = c.format();
            let level = c.controls().level();
            println!(
                "input: {}, {rate} Hz, {ch} ch, level {:.1} dBFS peak",
                c.device_name(),
                level.peak_dbfs
            );
        }
        Err(e) => println!("input: {e}"),
    }
    Ok(())
}
