//! Ogg Opus interop with opus-tools (opusenc, opusdec, opusinfo): what lipcall writes plays in
//! opusdec, what opusenc writes decodes in lipcall as opusdec decodes it, and broken files are
//! clean errors.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::*;
use lipcall::codec::opus::stream;

fn opusdec(input: &Path, output: &Path, rate: u32) {
    run(Command::new("opusdec")
        .args(["--quiet", "--no-dither", "--rate", &rate.to_string()])
        .arg(input)
        .arg(output));
}

fn opusenc(input: &Path, output: &Path, kbps: &str) {
    run(Command::new("opusenc")
        .args(["--quiet", "--bitrate", kbps])
        .arg(input)
        .arg(output));
}

/// Two TIMIT utterances (dr1 and dr3) at their own 16 kHz, and the demo speech.
fn speech_16k(dir: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    for (speaker, utterance) in [("dr1-fvmh0", "sa1"), ("dr3-madc0", "sa2")] {
        let src = timit_dir().join(speaker).join(format!("{utterance}.wav"));
        let out = dir.join(format!("{speaker}-{utterance}.wav"));
        run(Command::new("sox")
            .arg(&src)
            .args(["-D", "-b", "16", "-c", "1"])
            .arg(&out));
        files.push(out);
    }
    let demo = dir.join("demo16k.wav");
    run(Command::new("sox")
        .arg(repo_file("assets/speech/demo.wav"))
        .args(["-D", "-r", "16000", "-b", "16", "-c", "1"])
        .arg(&demo));
    files.push(demo);
    files
}

#[test]
fn lipcall_opus_plays_in_opusdec_with_the_input_length() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let input = demo_8k(d);
    let (_, original) = read_wav_i16(&input);
    for kbps in ["12", "16", "24"] {
        let opus = d.join(format!("ours-{kbps}.opus"));
        run(lipcall()
            .arg("encode")
            .arg(&input)
            .arg(&opus)
            .args(["--bitrate", kbps]));
        let info = run(Command::new("opusinfo").arg(&opus));
        let info = String::from_utf8_lossy(&info.stdout);
        assert!(info.contains("Pre-skip: 312"), "{info}");
        assert!(info.contains("Original sample rate: 8000 Hz"), "{info}");
        let wav = d.join(format!("opusdec-{kbps}.wav"));
        opusdec(&opus, &wav, 8000);
        let (rate, decoded) = read_wav_i16(&wav);
        assert_eq!(rate, 8000);
        // opusdec trims by the granule arithmetic: the exact input length.
        assert_eq!(decoded.len(), original.len(), "{kbps} kb/s: length");
        let snr = snr_db(&original, &decoded);
        eprintln!("{kbps} kb/s: opusdec's decode {snr:.2} dB against the input");
        assert!(snr > 4.0, "{kbps} kb/s: SNR {snr:.2} dB");
    }
}

#[test]
fn opusenc_files_decode_as_opusdec_decodes_them() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for wav in speech_16k(d) {
        let name = wav.file_stem().unwrap().to_string_lossy().into_owned();
        let opus = d.join(format!("{name}.opus"));
        opusenc(&wav, &opus, "16");
        let bytes = std::fs::read(&opus).unwrap();

        // At 48 kHz both run libopus with no resampler: sample for sample.
        let ours48 = stream::decode_at(&bytes, 48_000).unwrap();
        let theirs48_wav = d.join(format!("{name}-48k.wav"));
        opusdec(&opus, &theirs48_wav, 48_000);
        let (_, theirs48) = read_wav_i16(&theirs48_wav);
        assert_eq!(ours48.pcm.len(), theirs48.len(), "{name}: length at 48 kHz");
        let max_diff = ours48
            .pcm
            .iter()
            .zip(&theirs48)
            .map(|(&a, &b)| (i32::from(a) - i32::from(b)).abs())
            .max()
            .unwrap();
        let snr48 = snr_db(&theirs48, &ours48.pcm);
        eprintln!("{name}: 48 kHz max difference {max_diff}, SNR {snr48:.1} dB");

        // At 8 kHz lipcall's libopus decodes straight to 8 kHz; opusdec decodes at 48 kHz and
        // resamples with the Speex resampler.
        let ours_wav = d.join(format!("{name}-ours.wav"));
        run(lipcall().arg("decode").arg(&opus).arg(&ours_wav));
        let (rate, ours) = read_wav_i16(&ours_wav);
        assert_eq!(rate, 8000);
        let theirs_wav = d.join(format!("{name}-opusdec.wav"));
        opusdec(&opus, &theirs_wav, 8000);
        let (_, theirs) = read_wav_i16(&theirs_wav);
        assert!(
            ours.len().abs_diff(theirs.len()) <= 1,
            "{name}: {} vs {} samples",
            ours.len(),
            theirs.len()
        );
        let snr8 = snr_db(&theirs, &ours);
        eprintln!("{name}: 8 kHz SNR against opusdec {snr8:.1} dB");
    }
}
