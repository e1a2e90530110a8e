//! Bad input on the command line: a clear one-line error and exit 1 (2 for bad usage), no panic.

mod common;

use std::path::Path;
use std::process::Command;

use common::*;

fn fails_cleanly(args: &[&Path], expected: &str) {
    let out = lipcall().args(args).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "one line: {stderr}");
    assert!(
        stderr.to_lowercase().contains(&expected.to_lowercase()),
        "{args:?}: expected {expected:?} in {stderr}"
    );
}

#[test]
fn unreadable_inputs_give_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let text = d.join("notes.wav");
    std::fs::write(&text, "this is not audio\n").unwrap();
    let empty = d.join("empty.spx");
    std::fs::write(&empty, b"").unwrap();
    let out_wav = d.join("out.wav");
    let out_spx = d.join("out.spx");
    let p = Path::new;

    fails_cleanly(&[p("encode"), &text, &out_spx], "not a readable WAV");
    fails_cleanly(&[p("encode"), &empty, &out_spx], "not a readable WAV");
    fails_cleanly(
        &[p("encode"), &d.join("missing.wav"), &out_spx],
        "No such file",
    );
    fails_cleanly(&[p("decode"), &empty, &out_wav], "empty");
    fails_cleanly(&[p("decode"), &text, &out_wav], "not an Ogg file");

    // Ogg Vorbis made by sox.
    let vorbis = d.join("tone.ogg");
    run(Command::new("sox")
        .args(["-n", "-r", "8000", "-c", "1"])
        .arg(&vorbis)
        .args(["synth", "0.5", "sine", "440"]));
    fails_cleanly(&[p("decode"), &vorbis, &out_wav], "Vorbis");

    // A real Speex file cut short.
    let wav = demo_8k(d);
    let spx = d.join("demo.spx");
    run(lipcall().arg("encode").arg(&wav).arg(&spx));
    let bytes = std::fs::read(&spx).unwrap();
    let truncated = d.join("truncated.spx");
    std::fs::write(&truncated, &bytes[..bytes.len() * 2 / 3]).unwrap();
    fails_cleanly(&[p("decode"), &truncated, &out_wav], "truncated");
}

#[test]
fn bad_usage_exits_2() {
    for args in [
        vec!["encode"],
        vec!["encode", "a.wav", "b.spx", "--quality", "11"],
        vec!["frobnicate"],
    ] {
        let out = lipcall().args(&args).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{args:?}");
    }
}

#[test]
fn a_48k_stereo_wav_is_resampled_not_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let stereo = d.join("stereo48k.wav");
    run(Command::new("sox")
        .arg(repo_file("assets/speech/demo.wav"))
        .args(["-D", "-r", "48000", "-c", "2", "-b", "16"])
        .arg(&stereo));
    let (_, original) = read_wav_i16(&stereo);
    let seconds = original.len() as f64 / 2.0 / 48_000.0;
    let spx = d.join("out.spx");
    let wav = d.join("out.wav");
    run(lipcall().arg("encode").arg(&stereo).arg(&spx));
    run(lipcall().arg("decode").arg(&spx).arg(&wav));
    let (rate, decoded) = read_wav_i16(&wav);
    assert_eq!(rate, 8000);
    let expected = (seconds * 8000.0).round() as usize;
    assert!(
        decoded.len().abs_diff(expected) < 160,
        "{} vs {expected}",
        decoded.len()
    );
    // And it still sounds like the speech: compare with the mono 8 kHz path.
    let mono = demo_8k(d);
    let (_, reference) = read_wav_i16(&mono);
    let snr = snr_db(&reference, &decoded);
    assert!(snr > 3.0, "SNR against the mono reference {snr:.2} dB");
}

#[test]
fn the_app_refuses_a_bad_listen_address_before_opening_a_window() {
    let p = Path::new;
    fails_cleanly(
        &[p("--listen"), p("not-an-address"), p("--no-audio")],
        "--listen",
    );
}
