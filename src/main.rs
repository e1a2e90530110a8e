use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use lipcall::codec::any::Codec;
use lipcall::codec::opus::codec::EncoderConfig as OpusConfig;
use lipcall::codec::speex::codec::EncoderConfig;
use lipcall::commands;
use lipcall::commands::codec::{EncodeSettings, FileCodec};
use lipcall::commands::janus::{JanusArgs, JanusReceiveArgs};
use lipcall::commands::net::{KeyArgs, ReceiveArgs, SendArgs};

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
}

#[derive(Subcommand)]
enum Command {
    /// Encode a WAV file (any rate, mono or stereo) to Ogg Speex narrowband or Ogg Opus.
    Encode {
        input: PathBuf,
        output: PathBuf,
        /// The codec (default: opus for an .opus output, otherwise speex).
        #[arg(long, value_enum)]
        codec: Option<FileCodec>,
        /// Speex quality, 0 (lowest) to 10 (highest); default 8.
        #[arg(long, value_parser = clap::value_parser!(u8).range(0..=10))]
        quality: Option<u8>,
        /// Speex: variable bit rate.
        #[arg(long)]
        vbr: bool,
        /// Encoder complexity: Speex 1 to 10 (default 3), Opus 0 to 10 (default 10).
        #[arg(long, value_parser = clap::value_parser!(u8).range(0..=10))]
        complexity: Option<u8>,
        /// Speex: frames (20 ms each) per Ogg packet; default 1.
        #[arg(long, value_parser = clap::value_parser!(u8).range(1..=8))]
        frames_per_packet: Option<u8>,
        /// Opus bitrate in kb/s, 6 to 510; default 16.
        #[arg(long, value_name = "KBPS", value_parser = parse_kbps)]
        bitrate: Option<u32>,
        /// Opus: expected packet loss in percent; turns on in-band FEC (which libopus codes
        /// from 18 kb/s in narrowband).
        #[arg(long, value_name = "PERCENT", value_parser = clap::value_parser!(u8).range(0..=100))]
        expect_loss: Option<u8>,
        /// Opus: discontinuous transmission (tiny packets in silence).
        #[arg(long)]
        dtx: bool,
    },
    /// Decode an Ogg Speex or Ogg Opus file to WAV (Opus at 8 kHz), optionally writing the
    /// per-frame LSP + energy features (Speex).
    Decode {
        input: PathBuf,
        output: PathBuf,
        /// Write FEATURES.csv: frame,time_s,mode,lsp1..lsp10,energy_db.
        #[arg(long, value_name = "FEATURES.csv")]
        features: Option<PathBuf>,
        /// Speex: turn the perceptual enhancer off (speexdec --no-enh).
        #[arg(long)]
        no_enh: bool,
    },
    /// Viseme weights (and rendered frames) for a WAV or Speex file, as a receiver would show them.
    Animate {
        input: PathBuf,
        /// Write WEIGHTS.csv: frame,time_s,<viseme names>.
        #[arg(long, value_name = "WEIGHTS.csv")]
        weights: Option<PathBuf>,
        /// Render numbered PNG frames of the head (plus weights.csv and audio.wav) into DIR.
        #[arg(long, value_name = "DIR")]
        frames: Option<PathBuf>,
        /// A glTF/GLB head with viseme or ARKit morph targets instead of the bundled one.
        #[arg(long, value_name = "HEAD.glb")]
        head: Option<PathBuf>,
        /// Frames per second of the rendered frames.
        #[arg(long, default_value_t = 25, value_parser = parse_fps)]
        fps: u32,
        /// Frame the mouth close-up (the lipreading view) instead of the whole face.
        #[arg(long)]
        mouth: bool,
        /// Viseme set: a count (2..6 or 15) or names such as PP,aa,I.
        #[arg(long, value_name = "N|NAMES")]
        visemes: Option<String>,
        /// A model file from `lipcall train` instead of the built-in network.
        #[arg(long, value_name = "FILE")]
        model: Option<PathBuf>,
        /// Compare with a baseline instead of the network: `jaw` opens the jaw with the energy.
        #[arg(long, value_parser = ["jaw"])]
        baseline: Option<String>,
        /// Lip closures, from -1 (fewer, only the surest) through 0 (the model's balance) to 1
        /// (close for nearly every /p b m/, and more often where there is none).
        #[arg(long, value_name = "B", default_value_t = 0.0, allow_hyphen_values = true,
              value_parser = lipcall::lipsync::parse_closure_bias)]
        closures: f32,
        /// A still face in the frames: no blinks, no eye or head motion (the mouth still moves).
        #[arg(long)]
        no_life: bool,
        /// Seed of the living face's blinks, glances and head motion (the same seed and audio
        /// give the same frames).
        #[arg(long, value_name = "N", default_value_t = lipcall::lipsync::life::DEFAULT_SEED)]
        seed: u64,
    },
    /// List audio devices and try the default (or chosen) ones; no audio is not an error.
    Devices {
        /// Output device id (from the list), or "default".
        #[arg(long)]
        output: Option<String>,
        /// Input device id (from the list), or "default".
        #[arg(long)]
        input: Option<String>,
    },
    /// Send a WAV, Ogg Speex or Ogg Opus file as RTP over UDP, paced in real time.
    Send {
        /// Audio to send: .wav (any rate, encoded here), or .spx or .opus (sent as they are,
        /// unless --codec asks for another codec).
        input: PathBuf,
        /// Receiver (or relay, with --room) as HOST:PORT.
        #[arg(long, value_name = "HOST:PORT", required_unless_present = "janus")]
        to: Option<String>,
        /// Publish in a room (--room) of this Janus server instead, http://HOST:PORT/janus;
        /// --key is the room's pin. Sent as Opus over WebRTC.
        #[arg(long, value_name = "URL", conflicts_with_all = ["to", "key_hex", "codec", "ssrc"], requires = "room")]
        janus: Option<String>,
        #[command(flatten)]
        key: KeyOpts,
        /// Display name sent to peers (RTCP SDES NAME).
        #[arg(long)]
        name: Option<String>,
        /// Join this room on the relay given by --to.
        #[arg(long)]
        room: Option<String>,
        /// The codec sent: speex, opus, pcmu or pcma (default: a coded file's own; Speex for
        /// a WAV). Opus goes at 20 kb/s with in-band FEC.
        #[arg(long, value_parser = parse_codec)]
        codec: Option<Codec>,
        /// Speex quality for .wav input, 0 to 10.
        #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u8).range(0..=10))]
        quality: u8,
        #[command(flatten)]
        payloads: PayloadOpts,
        /// Send no RTCP (for receivers that take RTP only, such as a bare GStreamer udpsrc).
        #[arg(long)]
        no_rtcp: bool,
        /// Use this SSRC (hex) instead of a random one, for set-ups that need it in advance.
        #[arg(long, value_parser = parse_hex_u32)]
        ssrc: Option<u32>,
    },
    /// Receive a call: jitter buffer, decode, features; write the audio as played.
    Receive {
        /// Address to listen on, HOST:PORT (port 0 picks one). Once bound, one stderr line
        /// says the address: `lipcall: listening on IP:PORT` (a stable format, for scripts).
        #[arg(long, value_name = "HOST:PORT", required_unless_present = "janus")]
        listen: Option<String>,
        /// Join a room (--room) of this Janus server instead, http://HOST:PORT/janus, and
        /// receive every publisher there; --key is the room's pin.
        #[arg(long, value_name = "URL", conflicts_with_all = ["listen", "relay", "key_hex"], requires = "room")]
        janus: Option<String>,
        /// Write the audio as played (all peers mixed), streamed to disk as it plays.
        #[arg(long, value_name = "OUT.wav")]
        wav: Option<PathBuf>,
        /// Write viseme weights from the built-in lip-sync network (one file per peer).
        #[arg(long, value_name = "WEIGHTS.csv")]
        weights: Option<PathBuf>,
        /// Write per-frame LSP + energy features aligned to OUT.wav (one file per peer).
        #[arg(long, value_name = "FEATURES.csv")]
        features: Option<PathBuf>,
        #[command(flatten)]
        key: KeyOpts,
        /// Stop after this many seconds. Without it, the receive ends once everyone who called
        /// has left: said BYE, or sent nothing for --peer-timeout. Before anyone calls it
        /// waits. Ctrl-C (SIGINT) or SIGTERM ends it at any time; the files written so far are
        /// finished and whole either way.
        #[arg(long, allow_hyphen_values = true, value_parser = commands::parse_seconds)]
        seconds: Option<f64>,
        /// A peer that sent nothing (no RTP, no RTCP) for this many seconds has left (in a
        /// Janus room, Janus says when a publisher leaves).
        #[arg(long, value_name = "SECONDS", default_value_t = 30.0, value_parser = commands::parse_seconds)]
        peer_timeout: f64,
        /// With --key: how far (either way) a caller's clock may be from ours. A new encrypted
        /// stream stamped further off is refused as a replay of an earlier call (counted as
        /// stale).
        #[arg(long, value_name = "SECONDS", default_value_t = lipcall::net::srtp::DEFAULT_CLOCK_TOLERANCE, value_parser = clap::value_parser!(u32).range(1..=86_400))]
        clock_tolerance: u32,
        /// Join a room on this relay (with --room).
        #[arg(long, value_name = "HOST:PORT")]
        relay: Option<String>,
        #[arg(long)]
        room: Option<String>,
        /// Display name sent to peers.
        #[arg(long)]
        name: Option<String>,
        #[command(flatten)]
        payloads: PayloadOpts,
    },
    /// Run a relay: forwards each room member's packets to the others, without decoding them.
    Relay {
        /// Address to listen on, HOST:PORT (port 0 picks one). Once bound, one stderr line
        /// says the address: `lipcall: relay listening on IP:PORT` (a stable format).
        #[arg(long, value_name = "HOST:PORT")]
        listen: String,
        /// Stop after this many seconds (otherwise run until killed).
        #[arg(long, allow_hyphen_values = true, value_parser = commands::parse_seconds)]
        seconds: Option<f64>,
    },
    /// Train the viseme network on a TIMIT-style corpus through the real Speex codec.
    Train(commands::lipsync::TrainArgs),
    /// Score a model and the jaw baseline on held-out speakers (Eq. 1, accuracy, openness r,
    /// /p b m/ closures, false closures).
    Evaluate(commands::lipsync::EvaluateArgs),
    /// The paper's Table I (decomposition error for 2..6 visemes), or decompose real marker tracks.
    Decompose(commands::lipsync::DecomposeArgs),
}

/// Exits with clap's usage error (status 2) for flags that do not fit the chosen codec.
fn usage_error(message: &str) -> ! {
    use clap::CommandFactory;
    Cli::command()
        .error(clap::error::ErrorKind::ArgumentConflict, message)
        .exit()
}

/// kb/s as opusenc's --bitrate takes them, to bits per second.
fn parse_kbps(arg: &str) -> Result<u32, String> {
    match arg.parse::<f64>() {
        Ok(k) if (6.0..=510.0).contains(&k) => Ok((k * 1000.0).round() as u32),
        _ => Err("must be a number of kb/s from 6 to 510".into()),
    }
}

fn parse_fps(arg: &str) -> Result<u32, String> {
    match arg {
        "25" => Ok(25),
        "50" => Ok(50),
        _ => Err("must be 25 or 50".into()),
    }
}

#[derive(clap::Args)]
struct KeyOpts {
    /// Room passphrase: encrypts and authenticates media with SRTP. Without it (or
    /// --key-hex) the call is plain RTP.
    #[arg(long, value_name = "PASSPHRASE", value_parser = commands::parse_passphrase)]
    key: Option<String>,
    /// Raw SRTP master key + salt (60 hex digits), e.g. to talk to GStreamer's srtpenc.
    #[arg(long, value_name = "HEX")]
    key_hex: Option<String>,
}

impl From<KeyOpts> for KeyArgs {
    fn from(k: KeyOpts) -> Self {
        KeyArgs {
            passphrase: k.key,
            hex: k.key_hex,
        }
    }
}

#[derive(clap::Args)]
struct PayloadOpts {
    /// Carry a codec on another RTP payload type, e.g. opus=111 (repeatable). Without SDP the
    /// defaults are GStreamer's: speex=110, opus=96; pcmu=0 and pcma=8 are static.
    #[arg(long = "pt", value_name = "CODEC=PT", value_parser = parse_payload_type)]
    assignments: Vec<String>,
}

fn parse_codec(s: &str) -> Result<Codec, String> {
    s.parse()
        .map_err(|e: lipcall::codec::any::PayloadMapError| e.to_string())
}

fn parse_payload_type(s: &str) -> Result<String, String> {
    lipcall::codec::any::PayloadMap::default()
        .with_assignments(&[s])
        .map(|_| s.to_string())
        .map_err(|e| e.to_string())
}

fn parse_hex_u32(s: &str) -> Result<u32, String> {
    u32::from_str_radix(s.trim_start_matches("0x"), 16).map_err(|e| e.to_string())
}

/// Diagnostics (`tracing` events, and the `log` records of wgpu and eframe) go to stderr:
/// warnings and errors, or what RUST_LOG asks for (`debug`, `lipcall=debug,wgpu=warn`).
fn install_logging() {
    use std::io::IsTerminal;
    use tracing_subscriber::filter::{LevelFilter, Targets};
    use tracing_subscriber::prelude::*;
    let warnings = || Targets::new().with_default(LevelFilter::WARN);
    let mut unreadable = None;
    let filter = match std::env::var("RUST_LOG") {
        Ok(spec) if !spec.trim().is_empty() => spec.parse::<Targets>().unwrap_or_else(|e| {
            unreadable = Some(format!("RUST_LOG={spec:?} ignored ({e}): warnings only"));
            warnings()
        }),
        _ => warnings(),
    };
    let layer = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal());
    let installed = tracing_subscriber::registry()
        .with(layer)
        .with(filter)
        .try_init();
    if let (Ok(()), Some(why)) = (installed, unreadable) {
        tracing::warn!("{why}");
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    install_logging();
    let Some(command) = cli.command else {
        let a = cli.app;
        return finish(lipcall::app::run(lipcall::app::AppOptions {
            listen: a.listen,
            no_demo: a.no_demo,
            quit_after: a.quit_after,
            status: a.status,
            no_audio: a.no_audio,
            settings: a.settings,
        }));
    };
    let result = match command {
        Command::Encode {
            input,
            output,
            codec,
            quality,
            vbr,
            complexity,
            frames_per_packet,
            bitrate,
            expect_loss,
            dtx,
        } => {
            let codec = codec.unwrap_or_else(|| FileCodec::for_path(&output));
            let settings = match codec {
                FileCodec::Speex => {
                    if bitrate.is_some() || expect_loss.is_some() || dtx {
                        usage_error(
                            "--bitrate, --expect-loss and --dtx are Opus settings \
                             (use --codec opus or an .opus output)",
                        );
                    }
                    if complexity == Some(0) {
                        usage_error("Speex complexity is 1 to 10");
                    }
                    let d = EncoderConfig::default();
                    EncodeSettings::Speex(EncoderConfig {
                        quality: quality.unwrap_or(d.quality),
                        vbr,
                        complexity: complexity.unwrap_or(d.complexity),
                        frames_per_packet: frames_per_packet
                            .map_or(d.frames_per_packet, usize::from),
                    })
                }
                FileCodec::Opus => {
                    if quality.is_some() || vbr || frames_per_packet.is_some() {
                        usage_error(
                            "--quality, --vbr and --frames-per-packet are Speex settings; \
                             Opus takes --bitrate",
                        );
                    }
                    let d = OpusConfig::default();
                    EncodeSettings::Opus(OpusConfig {
                        bitrate: bitrate.unwrap_or(d.bitrate),
                        complexity: complexity.unwrap_or(d.complexity),
                        fec: expect_loss.is_some_and(|l| l > 0),
                        loss_percent: expect_loss.unwrap_or(0),
                        dtx,
                        ..d
                    })
                }
            };
            commands::codec::encode(&input, &output, settings)
        }
        Command::Decode {
            input,
            output,
            features,
            no_enh,
        } => commands::codec::decode(&input, &output, features.as_deref(), !no_enh),
        Command::Animate {
            input,
            weights,
            frames,
            head,
            fps,
            mouth,
            visemes,
            model,
            baseline,
            closures,
            no_life,
            seed,
        } => commands::animate::animate(&commands::animate::AnimateArgs {
            input,
            weights,
            frames,
            head,
            fps,
            mouth_close_up: mouth,
            visemes,
            model,
            baseline_jaw: baseline.is_some(),
            closure_bias: closures,
            life: !no_life,
            seed,
        }),
        Command::Devices { output, input } => {
            commands::audio::devices(output.as_deref(), input.as_deref())
        }
        Command::Send {
            janus: Some(url),
            input,
            key,
            name,
            room,
            ..
        } => commands::janus::send(
            &input,
            &JanusArgs {
                url,
                room: room.unwrap_or_default(),
                name,
                pin: key.key,
            },
        ),
        Command::Send {
            janus: None,
            input,
            to,
            key,
            name,
            room,
            codec,
            quality,
            payloads,
            no_rtcp,
            ssrc,
        } => commands::net::send(&SendArgs {
            input,
            to: to.unwrap_or_default(),
            key: key.into(),
            name,
            room,
            quality,
            no_rtcp,
            ssrc,
            codec,
            payload_types: payloads.assignments,
        }),
        Command::Receive {
            janus: Some(url),
            wav,
            weights,
            features,
            key,
            seconds,
            room,
            name,
            ..
        } => commands::janus::receive(&JanusReceiveArgs {
            janus: JanusArgs {
                url,
                room: room.unwrap_or_default(),
                name,
                pin: key.key,
            },
            wav,
            weights,
            features,
            seconds,
        }),
        Command::Receive {
            janus: None,
            listen,
            wav,
            weights,
            features,
            key,
            seconds,
            peer_timeout,
            clock_tolerance,
            relay,
            room,
            name,
            payloads,
        } => commands::net::receive(&ReceiveArgs {
            listen: listen.unwrap_or_default(),
            wav,
            weights,
            features,
            key: key.into(),
            seconds,
            peer_timeout: Some(peer_timeout),
            clock_tolerance: Some(clock_tolerance),
            relay,
            room,
            name,
            payload_types: payloads.assignments,
        }),
        Command::Relay { listen, seconds } => commands::net::relay(&listen, seconds),
        Command::Train(args) => commands::lipsync::train(&args),
        Command::Evaluate(args) => commands::lipsync::evaluate(&args),
        Command::Decompose(args) => commands::lipsync::decompose(&args),
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
