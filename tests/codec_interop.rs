//! Interop with the reference tools speexenc and speexdec (Debian's speex 1.2.1).

mod common;

use std::path::Path;
use std::process::Command;

use common::*;

fn speexenc(input: &Path, output: &Path, args: &[&str]) {
    run(Command::new("speexenc").args(args).arg(input).arg(output));
}

fn speexdec(input: &Path, output: &Path, enhancer: bool) {
    let mut cmd = Command::new("speexdec");
    if !enhancer {
        cmd.arg("--no-enh");
    }
    run(cmd.arg(input).arg(output));
}

fn assert_same_as_speexdec(spx: &Path, dir: &Path, enhancer: bool) {
    let tag = if enhancer { "enh" } else { "noenh" };
    let reference = dir.join(format!("ref-{tag}.wav"));
    let ours = dir.join(format!("ours-{tag}.wav"));
    speexdec(spx, &reference, enhancer);
    let mut cmd = lipcall();
    cmd.arg("decode").arg(spx).arg(&ours);
    if !enhancer {
        cmd.arg("--no-enh");
    }
    run(&mut cmd);
    let (rate_ref, reference) = read_wav_i16(&reference);
    let (rate_ours, ours) = read_wav_i16(&ours);
    assert_eq!(rate_ref, rate_ours);
    assert_eq!(
        reference.len(),
        ours.len(),
        "{} {tag}: length",
        spx.display()
    );
    let worst = reference
        .iter()
        .zip(&ours)
        .map(|(&a, &b)| (i32::from(a) - i32::from(b)).abs())
        .max()
        .unwrap_or(0);
    assert!(
        worst <= 1,
        "{} {tag}: differs by {worst} LSB",
        spx.display()
    );
}

#[test]
fn decode_matches_speexdec_sample_for_sample() {
    let dir = tempfile::tempdir().unwrap();
    let inputs = [
        demo_8k(dir.path()),
        timit_8k(dir.path(), "dr2-marc0", "sx108"),
    ];
    let settings: [&[&str]; 5] = [
        &["--quality", "2"],
        &["--quality", "4"],
        &["--quality", "8"],
        &["--vbr", "--quality", "6"],
        &["--quality", "5", "--nframes", "3"],
    ];
    for (i, input) in inputs.iter().enumerate() {
        for (j, args) in settings.iter().enumerate() {
            let case = dir.path().join(format!("case-{i}-{j}"));
            std::fs::create_dir(&case).unwrap();
            let spx = case.join("in.spx");
            speexenc(input, &spx, args);
            assert_same_as_speexdec(&spx, &case, true);
            assert_same_as_speexdec(&spx, &case, false);
        }
    }
}

#[test]
fn encoded_files_play_in_speexdec_as_well_as_speexencs_own() {
    let dir = tempfile::tempdir().unwrap();
    let input = demo_8k(dir.path());
    let (_, original) = read_wav_i16(&input);
    for quality in ["2", "4", "8"] {
        let ours_spx = dir.path().join(format!("ours-{quality}.spx"));
        let theirs_spx = dir.path().join(format!("theirs-{quality}.spx"));
        run(lipcall()
            .arg("encode")
            .arg(&input)
            .arg(&ours_spx)
            .args(["--quality", quality]));
        speexenc(&input, &theirs_spx, &["--quality", quality]);
        let ours_wav = dir.path().join(format!("ours-{quality}.wav"));
        let theirs_wav = dir.path().join(format!("theirs-{quality}.wav"));
        speexdec(&ours_spx, &ours_wav, true);
        speexdec(&theirs_spx, &theirs_wav, true);
        let (rate, ours) = read_wav_i16(&ours_wav);
        let (_, theirs) = read_wav_i16(&theirs_wav);
        assert_eq!(rate, 8000);
        // speexdec trims the end by the granule arithmetic, the same for both files.
        assert_eq!(ours.len(), theirs.len(), "quality {quality}: length");
        assert!(
            original.len().abs_diff(ours.len()) < 160,
            "quality {quality}: length"
        );
        let snr_ours = snr_db(&original, &ours);
        let snr_theirs = snr_db(&original, &theirs);
        assert!(snr_ours > 3.0, "quality {quality}: SNR {snr_ours:.2} dB");
        assert!(
            (snr_ours - snr_theirs).abs() <= 0.5,
            "quality {quality}: ours {snr_ours:.2} dB, speexenc {snr_theirs:.2} dB"
        );
    }
}

#[test]
fn vbr_and_multi_frame_encodes_play_in_speexdec() {
    let dir = tempfile::tempdir().unwrap();
    let input = demo_8k(dir.path());
    let (_, original) = read_wav_i16(&input);
    for (name, args) in [
        ("vbr", vec!["--vbr", "--quality", "6"]),
        ("nframes", vec!["--frames-per-packet", "4"]),
    ] {
        let spx = dir.path().join(format!("{name}.spx"));
        run(lipcall().arg("encode").arg(&input).arg(&spx).args(&args));
        let wav = dir.path().join(format!("{name}.wav"));
        speexdec(&spx, &wav, false);
        let (_, decoded) = read_wav_i16(&wav);
        assert!(
            original.len().abs_diff(decoded.len()) < 160,
            "{name}: length"
        );
        assert!(snr_db(&original, &decoded) > 3.0, "{name}");
        assert_same_as_speexdec(&spx, dir.path(), true);
    }
}
