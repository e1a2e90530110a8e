use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use lipcall::commands;
use lipcall::speex::codec::EncoderConfig;

/// Voice chat with lip-synced 3D heads, driven by the Speex decoder's own LSPs.
#[derive(Parser)]
#[command(name = "lipcall", version, arg_required_else_help = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Encode a WAV file (any rate, mono or stereo) to Ogg Speex narrowband.
    Encode {
        input: PathBuf,
        output: PathBuf,
        /// Speex quality, 0 (lowest) to 10 (highest).
        #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u8).range(0..=10))]
        quality: u8,
        /// Variable bit rate.
        #[arg(long)]
        vbr: bool,
        /// Encoder complexity, 1 to 10.
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u8).range(1..=10))]
        complexity: u8,
        /// Frames (20 ms each) per Ogg packet.
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=8))]
        frames_per_packet: u8,
    },
    /// Decode an Ogg Speex file to WAV, optionally writing the per-frame LSP + energy features.
    Decode {
        input: PathBuf,
        output: PathBuf,
        /// Write FEATURES.csv: frame,time_s,mode,lsp1..lsp10,energy_db.
        #[arg(long, value_name = "FEATURES.csv")]
        features: Option<PathBuf>,
        /// Turn the perceptual enhancer off (speexdec --no-enh).
        #[arg(long)]
        no_enh: bool,
    },
    /// Train the viseme network on a TIMIT-style corpus through the real Speex codec.
    Train(commands::lipsync::TrainArgs),
    /// Score a model and the jaw baseline on held-out speakers (Eq. 1, accuracy, openness r,
    /// /p b m/ closures, false closures).
    Evaluate(commands::lipsync::EvaluateArgs),
    /// The paper's Table I (decomposition error for 2..6 visemes), or decompose real marker tracks.
    Decompose(commands::lipsync::DecomposeArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Encode {
            input,
            output,
            quality,
            vbr,
            complexity,
            frames_per_packet,
        } => commands::codec::encode(
            &input,
            &output,
            EncoderConfig {
                quality,
                vbr,
                complexity,
                frames_per_packet: usize::from(frames_per_packet),
            },
        ),
        Command::Decode {
            input,
            output,
            features,
            no_enh,
        } => commands::codec::decode(&input, &output, features.as_deref(), !no_enh),
        Command::Train(args) => commands::lipsync::train(&args),
        Command::Evaluate(args) => commands::lipsync::evaluate(&args),
        Command::Decompose(args) => commands::lipsync::decompose(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("lipcall: {e:#}");
            ExitCode::FAILURE
        }
    }
}
