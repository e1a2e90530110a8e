use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use lipcall::commands::{self, animate, audio, codec, evaluate, grid, janus, lipsync, relay, sip};

/// Voice chat with lip-synced 3D heads, driven by the Speex decoder's own LSPs.
#[derive(Parser)]
#[command(name = "lipcall", version)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    app: AppFlags,
}

/// Without a subcommand: the desktop app.
#[derive(clap::Args)]
struct AppFlags {
    /// App: listen for calls on IP:PORT (otherwise only on a loopback port for the demo peer).
    #[arg(long, value_name = "IP:PORT")]
    listen: Option<String>,
    /// App: no demo peer.
    #[arg(long)]
    no_demo: bool,
    /// App: close the window after this many seconds.
    #[arg(long, value_name = "SECONDS", allow_hyphen_values = true, value_parser = commands::parse_seconds)]
    quit_after: Option<f64>,
    /// App: write per-peer status lines (animation frames, ...) to FILE twice a second.
    #[arg(long, value_name = "FILE")]
    status: Option<PathBuf>,
    /// App: open no audio device (silent playback, receive-only).
    #[arg(long)]
    no_audio: bool,
    /// App: settings file (default: $XDG_CONFIG_HOME/lipcall/settings.json).
    #[arg(long, value_name = "FILE")]
    settings: Option<PathBuf>,
    /// App: call HOST:PORT at start (with the settings' codec).
    #[arg(long, value_name = "HOST:PORT")]
    call: Option<String>,
    /// App: audio kept queued for the output beyond one device period, in ms (default: the
    /// settings', 5): less answers sooner, more survives a busier machine.
    #[arg(long, value_name = "MS", value_parser = clap::value_parser!(u32).range(0..=200))]
    output_margin_ms: Option<u32>,
    /// App: open the settings window at start.
    #[arg(long)]
    open_settings: bool,
}

#[derive(Subcommand)]
enum Command {
    /// Encode a WAV file (any rate, mono or stereo) to Ogg Speex narrowband or Ogg Opus.
    Encode(codec::EncodeArgs),
    /// Decode an Ogg Speex or Ogg Opus file to WAV (Opus at 48 kHz), optionally writing the
    /// per-frame LSP + energy features (Speex).
    Decode(codec::DecodeArgs),
    /// Viseme weights (and rendered frames) for a WAV or Speex file, as a receiver would show them.
    Animate(animate::AnimateArgs),
    /// List audio devices and try the default (or chosen) ones; no audio is not an error.
    Devices(audio::DevicesArgs),
    /// Send a WAV, Ogg Speex or Ogg Opus file as RTP over UDP, paced in real time.
    Send(janus::SendCommand),
    /// Receive a call: jitter buffer, decode, features; write the audio as played.
    Receive(janus::ReceiveCommand),
    /// A phone call over SIP: call an address or answer a call, playing a file as our voice.
    Sip(sip::SipCommand),
    /// Run a relay: forwards each room member's packets to the others, without decoding them.
    Relay(relay::RelayArgs),
    /// Train the viseme network on a TIMIT-style corpus through the real Speex codec.
    Train(lipsync::TrainArgs),
    /// Score a model and the jaw baseline on held-out speakers (Eq. 1, accuracy, openness r,
    /// /p b m/ closures, false closures).
    Evaluate(evaluate::EvaluateArgs),
    /// The paper's Table I (decomposition error for 2..6 visemes), or decompose real marker tracks.
    Decompose(lipsync::DecomposeArgs),
    /// GRID data step: per-20-ms lip targets from the tracked video, and s1's audio-visual lag.
    Grid(grid::GridArgs),
}

/// Exits with clap's usage error (status 2) for flags that do not fit together.
fn usage_error(message: &str) -> ! {
    use clap::CommandFactory;
    Cli::command()
        .error(clap::error::ErrorKind::ArgumentConflict, message)
        .exit()
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    commands::install_logging();
    let Some(command) = cli.command else {
        let a = cli.app;
        return finish(lipcall::app::run(lipcall::app::AppOptions {
            listen: a.listen,
            no_demo: a.no_demo,
            quit_after: a.quit_after,
            status: a.status,
            no_audio: a.no_audio,
            settings: a.settings,
            call: a.call,
            output_margin_ms: a.output_margin_ms,
            open_settings: a.open_settings,
        }));
    };
    let result = match command {
        Command::Encode(a) => {
            let settings = a.settings().unwrap_or_else(|why| usage_error(why));
            codec::encode(&a.input, &a.output, settings)
        }
        Command::Decode(a) => codec::decode(&a),
        Command::Animate(a) => animate::animate(&a),
        Command::Devices(a) => audio::devices(a.output.as_deref(), a.input.as_deref()),
        Command::Send(a) => janus::send_command(&a),
        Command::Receive(a) => janus::receive_command(&a),
        Command::Sip(a) => sip::run(&a),
        Command::Relay(a) => relay::relay(&a.listen, a.seconds),
        Command::Train(a) => lipsync::train(&a),
        Command::Evaluate(a) => evaluate::evaluate(&a),
        Command::Decompose(a) => lipsync::decompose(&a),
        Command::Grid(a) => grid::grid(&a),
    };
    finish(result)
}

fn finish(result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("lipcall: {}", commands::error_line(&e));
            ExitCode::FAILURE
        }
    }
}
