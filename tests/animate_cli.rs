//! `lipcall animate`: WEIGHTS.csv from WAV, Speex and Opus input, other viseme sets, the jaw
//! baseline, rendered frames, and bad input.

mod common;

use std::path::Path;
use std::process::Command;

use common::*;

fn read_weights(path: &Path) -> (Vec<String>, Vec<Vec<f32>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    let rows = lines
        .map(|l| l.split(',').skip(2).map(|v| v.parse().unwrap()).collect())
        .collect();
    (header, rows)
}

fn assert_convex(rows: &[Vec<f32>]) {
    for (n, row) in rows.iter().enumerate() {
        let sum: f32 = row.iter().sum();
        assert!((sum - 1.0).abs() < 2e-3, "row {n} sums to {sum}");
        assert!(row.iter().all(|&w| w >= 0.0), "row {n}: {row:?}");
    }
}

#[test]
fn weights_from_wav_and_from_its_speex_file_agree() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let wav = demo_8k(d);
    let spx = d.join("demo.spx");
    run(lipcall().arg("encode").arg(&wav).arg(&spx));
    let from_wav = d.join("wav.csv");
    let from_spx = d.join("spx.csv");
    run(lipcall()
        .arg("animate")
        .arg(&wav)
        .arg("--weights")
        .arg(&from_wav));
    run(lipcall()
        .arg("animate")
        .arg(&spx)
        .arg("--weights")
        .arg(&from_spx));
    let (header, rows) = read_weights(&from_wav);
    assert_eq!(header[..2], ["frame", "time_s"]);
    let (_, samples) = read_wav_i16(&wav);
    assert!(
        rows.len().abs_diff(samples.len() / 160) <= 1,
        "{} rows",
        rows.len()
    );
    assert_convex(&rows);
    // The mouth both closes and opens over real speech.
    let aa = header.iter().position(|h| h == "aa").unwrap() - 2;
    let pp = header.iter().position(|h| h == "PP").unwrap() - 2;
    assert!(rows.iter().any(|r| r[aa] > 0.5) && rows.iter().any(|r| r[pp] > 0.9));
    assert_eq!(
        std::fs::read_to_string(&from_wav).unwrap(),
        std::fs::read_to_string(&from_spx).unwrap()
    );
}

#[test]
fn weights_from_an_opusenc_file_follow_the_speech() {
    // opusenc codes 16 kHz speech as wideband SILK: the features are its NLSFs, mapped.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let wav = d.join("demo16.wav");
    run(Command::new("sox")
        .arg(repo_file("assets/speech/demo.wav"))
        .args(["-D", "-r", "16000"])
        .arg(&wav));
    let opus = d.join("demo.opus");
    run(Command::new("opusenc")
        .args(["--quiet", "--bitrate", "16"])
        .arg(&wav)
        .arg(&opus));
    let csv = d.join("opus.csv");
    run(lipcall()
        .arg("animate")
        .arg(&opus)
        .arg("--weights")
        .arg(&csv));
    let (header, rows) = read_weights(&csv);
    let (_, samples) = read_wav_i16(&wav);
    assert!(
        rows.len().abs_diff(samples.len() / 320) <= 1,
        "{} rows for {} samples at 16 kHz",
        rows.len(),
        samples.len()
    );
    assert_convex(&rows);
    let aa = header.iter().position(|h| h == "aa").unwrap() - 2;
    let pp = header.iter().position(|h| h == "PP").unwrap() - 2;
    assert!(rows.iter().any(|r| r[aa] > 0.5) && rows.iter().any(|r| r[pp] > 0.9));
}

#[test]
fn the_closure_bias_moves_how_often_the_lips_shut() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let wav = demo_8k(d);
    let closed_frames = |bias: &str| {
        let out = d.join(format!("closures{bias}.csv"));
        run(lipcall()
            .arg("animate")
            .arg(&wav)
            .args(["--closures", bias, "--weights"])
            .arg(&out));
        let (header, rows) = read_weights(&out);
        assert_convex(&rows);
        let pp = header.iter().position(|h| h == "PP").unwrap() - 2;
        rows.iter().filter(|r| r[pp] > 0.999).count()
    };
    let (fewer, balanced, more) = (closed_frames("-1"), closed_frames("0"), closed_frames("1"));
    assert!(
        fewer <= balanced && balanced <= more && fewer < more,
        "closed frames: {fewer} (-1), {balanced} (0), {more} (1)"
    );
    let out = lipcall()
        .arg("animate")
        .arg(&wav)
        .args(["--closures", "2"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("from -1 to 1"));
}

#[test]
fn other_viseme_sets_and_the_jaw_baseline() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let wav = demo_8k(d);
    let six = d.join("six.csv");
    run(lipcall()
        .arg("animate")
        .arg(&wav)
        .args(["--visemes", "6", "--weights"])
        .arg(&six));
    let (header, rows) = read_weights(&six);
    assert_eq!(header[2..], ["PP", "aa", "I", "O", "E", "FF"]);
    assert_convex(&rows);
    let jaw = d.join("jaw.csv");
    run(lipcall()
        .arg("animate")
        .arg(&wav)
        .args(["--baseline", "jaw", "--weights"])
        .arg(&jaw));
    let (header, rows) = read_weights(&jaw);
    assert_eq!(header[2..], ["PP", "aa"]);
    assert_convex(&rows);
}

/// 0.6 s of the demo speech at 8 kHz, in `dir`.
fn demo_clip(dir: &std::path::Path) -> std::path::PathBuf {
    let clip = dir.join("clip.wav");
    run(Command::new("sox")
        .arg(repo_file("assets/speech/demo.wav"))
        .args(["-D", "-r", "8000"])
        .arg(&clip)
        .args(["trim", "0.8", "0.6"]));
    clip
}

#[test]
fn frames_are_rendered_with_weights_and_audio() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let clip = demo_clip(d);
    let frames = d.join("frames");
    run(lipcall()
        .arg("animate")
        .arg(&clip)
        .arg("--frames")
        .arg(&frames));
    let pngs = std::fs::read_dir(&frames)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .ends_with(".png")
        })
        .count();
    // One frame every 40 ms of the weights (rows are 20 ms): 0.6 s is 15 or 16 frames.
    let (_, rows) = read_weights(&frames.join("weights.csv"));
    assert_eq!(pngs, rows.len().div_ceil(2), "{} rows", rows.len());
    assert!((15..=16).contains(&pngs), "{pngs} frames");
    let (rate, audio) = read_wav_i16(&frames.join("audio.wav"));
    assert_eq!(rate, 8000);
    assert!(audio.len().abs_diff(4800) < 160);
    let first = std::fs::read(frames.join("frame_000000.png")).unwrap();
    assert!(first.starts_with(b"\x89PNG"));
}

#[test]
fn the_living_face_is_seeded_and_can_be_switched_off() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let clip = demo_clip(d);
    let render = |name: &str, extra: &[&str]| -> Vec<Vec<u8>> {
        let frames = d.join(name);
        run(lipcall()
            .arg("animate")
            .arg(&clip)
            .arg("--frames")
            .arg(&frames)
            .args(extra));
        (0..15)
            .map(|k| std::fs::read(frames.join(format!("frame_{k:06}.png"))).unwrap())
            .collect()
    };
    let first = render("a", &[]);
    // The default seed, given or not: the same frames; another seed moves the head otherwise.
    assert_eq!(first, render("b", &["--seed", "1"]));
    assert_ne!(first, render("c", &["--seed", "2"]));
    // Talking moves the head: without the living face the frames differ.
    assert_ne!(first, render("d", &["--no-life"]));
    let out = lipcall()
        .arg("animate")
        .arg(&clip)
        .args(["--seed", "-3", "--weights"])
        .arg(d.join("w.csv"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn bad_input_gives_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let wav = demo_8k(d);
    let bad_model = d.join("bad.lipmodel");
    std::fs::write(&bad_model, "lipcall-model 2\nvisemes PP aa\nhidden 3\n").unwrap();
    let bad_head = d.join("head.glb");
    std::fs::write(&bad_head, b"glTF\x02\x00\x00\x00garbage").unwrap();
    let tiny = d.join("tiny.wav");
    run(Command::new("sox")
        .args(["-n", "-r", "8000", "-b", "16"])
        .arg(&tiny)
        .args(["trim", "0", "0.01"]));
    let out = d.join("w.csv");
    for args in [
        vec![
            wav.as_os_str(),
            "--model".as_ref(),
            bad_model.as_os_str(),
            "--weights".as_ref(),
            out.as_os_str(),
        ],
        vec![
            wav.as_os_str(),
            "--head".as_ref(),
            bad_head.as_os_str(),
            "--frames".as_ref(),
            d.join("f").as_os_str(),
        ],
        vec![tiny.as_os_str(), "--weights".as_ref(), out.as_os_str()],
        vec![
            wav.as_os_str(),
            "--visemes".as_ref(),
            "PP,xx".as_ref(),
            "--weights".as_ref(),
            out.as_os_str(),
        ],
    ] {
        let result = lipcall().arg("animate").args(&args).output().unwrap();
        let stderr = String::from_utf8_lossy(&result.stderr);
        let errors: Vec<&str> = stderr
            .lines()
            .filter(|l| l.starts_with("lipcall:"))
            .collect();
        assert_eq!(result.status.code(), Some(1), "{args:?}: {stderr}");
        assert_eq!(errors.len(), 1, "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
}
