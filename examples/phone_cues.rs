//! Phone-derived mouth cues of a TIMIT-style utterance, one row per 20 ms frame, for comparing
//! renders with the truth (tools/face_track.py):
//! `cargo run --release --example phone_cues -- SPEECH.wav SPEECH.phn > cues.csv`
use std::path::PathBuf;

use anyhow::Context;
use lipcall::lipsync::mouth;
use lipcall::train::corpus::{read_phones, targets_from_phones, wav_length};
use lipcall::vocab::VisemeSet;

fn main() -> anyhow::Result<()> {
    let args: Vec<PathBuf> = std::env::args().skip(1).map(PathBuf::from).collect();
    let [wav, phn] = args.as_slice() else {
        anyhow::bail!("usage: phone_cues SPEECH.wav SPEECH.phn");
    };
    let (rate, samples) = wav_length(wav)?;
    let phones = read_phones(phn)?;
    let targets = targets_from_phones(&phones, rate, samples)
        .map_err(|(line, e)| anyhow::anyhow!("{}:{line}: {e}", phn.display()))
        .context("phone-derived targets")?;
    let set = VisemeSet::full();
    println!("frame,time_s,openness,width,rounding");
    for (n, w) in targets.weights.iter().enumerate() {
        let [open, width, round] = mouth::cues(&set, w);
        println!("{n},{:.3},{open:.4},{width:.4},{round:.4}", n as f64 * 0.02);
    }
    Ok(())
}
