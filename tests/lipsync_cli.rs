//! The lip-sync subcommands from the outside: bad input gives a one-line error and exit 1 (2 for
//! bad usage), never a panic. Trainings here are tiny (1 utterance per speaker, a few epochs).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn lipcall(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lipcall"))
        .args(args)
        .output()
        .expect("run lipcall")
}

fn corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/timit-sample")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn assert_clean_failure(out: &Output, needle: &str) {
    let err = stderr(out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains(needle), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
}

#[test]
fn corrupt_and_truncated_model_files_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let shipped = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/models/default.lipmodel"),
    )
    .unwrap();
    let truncated = dir.path().join("truncated.lipmodel");
    std::fs::write(&truncated, &shipped[..shipped.len() / 2]).unwrap();
    let garbage = dir.path().join("garbage.lipmodel");
    std::fs::write(&garbage, b"\x89PNG\r\n\x1a\n").unwrap();
    let bad_viseme = dir.path().join("bad_viseme.lipmodel");
    std::fs::write(&bad_viseme, shipped.replacen("visemes PP", "visemes XX", 1)).unwrap();
    let c = corpus();
    for (file, needle) in [
        (&truncated, "truncated.lipmodel"),
        (&garbage, "not a lipcall viseme model"),
        (&bad_viseme, "unknown viseme \"XX\""),
        (&dir.path().join("missing.lipmodel"), "missing.lipmodel"),
    ] {
        let out = lipcall(&[
            "evaluate",
            "--model",
            file.to_str().unwrap(),
            "--corpus",
            c.to_str().unwrap(),
        ]);
        assert_clean_failure(&out, needle);
    }
}

fn tiny_corpus(dir: &Path, phn: &str, samples: usize) -> PathBuf {
    let root = dir.join("corpus");
    for speaker in ["dr1-a", "dr4-b", "dr5-c"] {
        let d = root.join(speaker);
        std::fs::create_dir_all(&d).unwrap();
        let spec = hound::WavSpec {
            channels: 1,
            sample_rate: 16000,
            bits_per_sample: 16,
            sample_format: hound::SampleFormat::Int,
        };
        let mut w = hound::WavWriter::create(d.join("u1.wav"), spec).unwrap();
        for i in 0..samples {
            w.write_sample(((i as f32 * 0.07).sin() * 3000.0) as i16)
                .unwrap();
        }
        w.finalize().unwrap();
        std::fs::write(d.join("u1.phn"), phn).unwrap();
    }
    root
}

#[test]
fn unknown_phones_and_too_short_audio_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let bad_phone = tiny_corpus(dir.path(), "0 8000 h#\n8000 16000 zz9\n", 16000);
    let out = lipcall(&[
        "evaluate",
        "--corpus",
        bad_phone.to_str().unwrap(),
        "--speakers",
        "test",
    ]);
    assert_clean_failure(&out, "zz9");

    let short_dir = tempfile::tempdir().unwrap();
    let short = tiny_corpus(short_dir.path(), "0 100 h#\n", 100);
    let out = lipcall(&["evaluate", "--corpus", short.to_str().unwrap()]);
    assert_clean_failure(&out, "shorter than one 20 ms frame");

    let out = lipcall(&["evaluate", "--corpus", "/nonexistent/corpus"]);
    assert_clean_failure(&out, "/nonexistent/corpus");
}

#[test]
fn non_finite_training_numbers_are_refused_before_any_work() {
    for (flag, value) in [
        ("--learning-rate", "NaN"),
        ("--closure-weight", "inf"),
        ("--rounding-weight", "1e40"),
        ("--an4-weight", "NaN"),
        ("--warp", "2"),
    ] {
        let out = lipcall(&[
            "train",
            "--corpus",
            corpus().to_str().unwrap(),
            flag,
            value,
            "--quiet",
            "--out",
            "/nonexistent/never-written.lipmodel",
        ]);
        assert_clean_failure(&out, flag);
    }
}

#[test]
fn bad_usage_exits_2() {
    for args in [
        &["train", "--visemes", "PP,PP"][..],
        &["evaluate", "--quality", "11"],
        &["decompose", "--markers", "x.csv"],
        &["train", "--smoothing", "0.95"],
        &["train", "--smoothing", "NaN"],
    ] {
        let out = lipcall(args);
        let code = out.status.code();
        // --visemes is checked after parsing, so it is a failure (1), not usage (2).
        assert!(code == Some(2) || code == Some(1), "{args:?}: {code:?}");
        assert!(!stderr(&out).contains("panicked"));
    }
    let out = lipcall(&["train", "--visemes", "PP,PP", "--quiet"]);
    assert_clean_failure(&out, "twice");
}

#[test]
fn tiny_training_writes_model_curves_and_plot_then_evaluates() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("m.lipmodel");
    let curves = dir.path().join("c.csv");
    let plot = dir.path().join("c.png");
    let c = corpus();
    let out = lipcall(&[
        "train",
        "--corpus",
        c.to_str().unwrap(),
        "--utterances",
        "1",
        "--versions",
        "1",
        "--epochs",
        "3",
        "--hidden",
        "4",
        "--snap",
        "off",
        "--smoothing",
        "0.5",
        "--quiet",
        "--out",
        model.to_str().unwrap(),
        "--curves",
        curves.to_str().unwrap(),
        "--plot",
        plot.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("jaw baseline"), "{text}");
    let file = std::fs::read_to_string(&model).unwrap();
    assert!(file.contains("lipcall-viseme-mlp 3"), "{file}");
    assert!(file.contains("\nsmoothing 0.5\n"), "{file}");
    assert_eq!(std::fs::read_to_string(&curves).unwrap().lines().count(), 4);
    assert!(std::fs::read(&plot).unwrap().starts_with(b"\x89PNG"));
    assert!(stderr(&out).contains("wrote the model to"));

    let out = lipcall(&[
        "evaluate",
        "--model",
        model.to_str().unwrap(),
        "--corpus",
        c.to_str().unwrap(),
        "--speakers",
        "validation",
        "--utterances",
        "1",
        "--quality",
        "3",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    for row in [
        "targets",
        "network",
        "jaw baseline",
        "openness r",
        "false cl.",
    ] {
        assert!(text.contains(row), "{text}");
    }
}

#[test]
fn cross_validated_training_holds_out_each_region_and_evaluation_dumps_frames() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("cv.lipmodel");
    let frames = dir.path().join("frames.csv");
    let c = corpus();
    let out = lipcall(&[
        "train",
        "--cross-validate",
        "--corpus",
        c.to_str().unwrap(),
        "--utterances",
        "1",
        "--versions",
        "1",
        "--epochs",
        "3",
        "--hidden",
        "4",
        "--warp",
        "0.1",
        "--segment-closure-weight",
        "1",
        "--an4-weight",
        "0",
        "--quiet",
        "--out",
        model.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    for region in ["dr1 ", "dr2 ", "dr3 ", "dr4 ", "pooled "] {
        assert!(text.contains(region), "{text}");
    }
    assert!(!text.contains("dr5") && !text.contains("dr6"), "{text}");
    let saved = std::fs::read_to_string(&model).unwrap();
    assert!(
        saved.contains("cross-validated by dialect region"),
        "{saved}"
    );
    assert!(
        !saved.contains("dr5-") && !saved.contains("dr6-"),
        "{saved}"
    );
    let card = std::fs::read_to_string(model.with_extension("card.md")).unwrap();
    assert!(
        card.contains("CC BY-NC-SA") && card.contains("pooled") && !card.contains("AN4"),
        "{card}"
    );

    let out = lipcall(&[
        "evaluate",
        "--model",
        model.to_str().unwrap(),
        "--corpus",
        c.to_str().unwrap(),
        "--utterances",
        "2",
        "--per-frame",
        frames.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let csv = std::fs::read_to_string(&frames).unwrap();
    let mut lines = csv.lines();
    assert!(
        lines
            .next()
            .unwrap()
            .starts_with("speaker,utterance,frame,target_openness,")
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert!(rows.len() > 8 * 50, "{} rows", rows.len());
    assert!(rows.iter().all(|r| r.len() == 16 && r[0].starts_with("dr")));
    // sa2 has the /m/ of "me".
    let bilabial = rows.iter().filter(|r| r[9] == "1").count();
    assert!(bilabial > 0 && bilabial < rows.len() / 4, "{bilabial}");
}

#[test]
fn an4_trains_beside_timit_and_utterances_without_alignments_are_skipped() {
    let audio = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/an4");
    if !audio.is_dir() {
        assert!(
            std::env::var_os("CI").is_none(),
            "no AN4 audio at {}: CI must provide it",
            audio.display()
        );
        eprintln!("skipped: no AN4 audio at {}", audio.display());
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // Labels for two speakers only: every other AN4 utterance has none.
    let labels = dir.path().join("labels");
    let committed = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/alignments/an4");
    for speaker in ["fash", "mjgm"] {
        std::fs::create_dir_all(labels.join(speaker)).unwrap();
        for entry in std::fs::read_dir(committed.join(speaker)).unwrap() {
            let path = entry.unwrap().path();
            std::fs::copy(&path, labels.join(speaker).join(path.file_name().unwrap())).unwrap();
        }
    }
    let model = dir.path().join("m.lipmodel");
    let out = lipcall(&[
        "train",
        "--cross-validate",
        "--corpus",
        corpus().to_str().unwrap(),
        "--utterances",
        "1",
        "--versions",
        "1",
        "--epochs",
        "2",
        "--hidden",
        "4",
        "--an4-weight",
        "0.2",
        "--an4-labels",
        labels.to_str().unwrap(),
        "--quiet",
        "--out",
        model.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let err = stderr(&out);
    assert!(
        err.contains("AN4: 2 utterances of 2 speakers") && err.contains("without alignments"),
        "{err}"
    );
    let card = std::fs::read_to_string(model.with_extension("card.md")).unwrap();
    assert!(
        card.contains("CMU AN4") && card.contains("weighted 0.2"),
        "{card}"
    );
    // An empty labels folder is a clear error, not a silent TIMIT-only model.
    let empty = dir.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let out = lipcall(&[
        "train",
        "--cross-validate",
        "--corpus",
        corpus().to_str().unwrap(),
        "--an4-labels",
        empty.to_str().unwrap(),
        "--quiet",
        "--out",
        model.to_str().unwrap(),
    ]);
    assert_clean_failure(&out, "without alignments");
}

#[test]
fn decompose_prints_table_i_and_decomposes_marker_tracks() {
    let c = corpus();
    let out = lipcall(&[
        "decompose",
        "--corpus",
        c.to_str().unwrap(),
        "--utterances",
        "1",
        "--visemes",
        "3",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("Table I") && text.contains("PP aa I"),
        "{text}"
    );

    let dir = tempfile::tempdir().unwrap();
    let tracks = dir.path().join("tracks.csv");
    std::fs::write(
        &tracks,
        "frame,nose_x,nose_y,lip_x,lip_y,chin_x,chin_y\n\
         10,100,50,100,80,100,120\n11,101,50,101,90,101,140\n12,100,50,100,85,100,130\n",
    )
    .unwrap();
    let keys = dir.path().join("keys.csv");
    std::fs::write(&keys, "viseme,frame\nPP,10\naa,11\n").unwrap();
    let weights = dir.path().join("w.csv");
    let out = lipcall(&[
        "decompose",
        "--markers",
        tracks.to_str().unwrap(),
        "--key-frames",
        keys.to_str().unwrap(),
        "--origin",
        "nose",
        "--weights",
        weights.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let csv = std::fs::read_to_string(&weights).unwrap();
    assert!(csv.starts_with("frame,PP,aa\n10,"), "{csv}");
    assert!(csv.contains("12,0.5"), "{csv}");

    std::fs::write(&keys, "viseme,frame\nPP,10\nXX,11\n").unwrap();
    let out = lipcall(&[
        "decompose",
        "--markers",
        tracks.to_str().unwrap(),
        "--key-frames",
        keys.to_str().unwrap(),
    ]);
    assert_clean_failure(&out, "unknown viseme \"XX\"");
}

/// A GRID-like folder: `clips` s1 clips of 25 video frames (1 s) whose lips follow a phone
/// sequence cycling through /p/ (shut), /aa/ (open) and /iy/ (spread, half open), each phone
/// 80 ms, with their phone files; and one other-speaker clip.
fn tiny_grid(root: &Path, clips: usize) -> PathBuf {
    const CONTOUR: [usize; 20] = [
        61, 40, 37, 0, 267, 270, 291, 321, 314, 17, 84, 91, 78, 82, 13, 312, 308, 317, 14, 87,
    ];
    let mut header = String::from("time_s,tracked");
    for l in [1, 33, 263].into_iter().chain(CONTOUR) {
        header.push_str(&format!(",x_{l},y_{l},z_{l}"));
    }
    let phones = ["p", "aa", "iy"];
    // Opening and spread (in pixels) of a phone; eyes 60 px apart.
    let shape = |p: &str| match p {
        "p" => (0.0, 0.0),
        "aa" => (9.0, 0.0),
        _ => (4.0, 6.0),
    };
    let track = |phone_at: &dyn Fn(f64) -> &'static str| -> String {
        let mut text = header.clone();
        for f in 0..25 {
            let (open, spread) = shape(phone_at((f as f64 + 0.5) / 25.0));
            let mut row = format!(
                "\n{},1,160,150,0,130,120,0,190,120,0",
                (f as f64 + 0.5) / 25.0
            );
            // Corners move out by the spread; the lower lip drops by the opening.
            let points: [(f64, f64); 20] = [
                (-20.0 - spread, 190.0),
                (-12.0, 184.0),
                (-6.0, 184.0),
                (0.0, 184.0),
                (6.0, 184.0),
                (12.0, 184.0),
                (20.0 + spread, 190.0),
                (12.0, 196.0 + open),
                (6.0, 196.0 + open),
                (0.0, 196.0 + open),
                (-6.0, 196.0 + open),
                (-12.0, 196.0 + open),
                (-14.0 - spread, 190.0),
                (-6.0, 190.0),
                (0.0, 190.0),
                (6.0, 190.0),
                (14.0 + spread, 190.0),
                (6.0, 190.0 + open),
                (0.0, 190.0 + open),
                (-6.0, 190.0 + open),
            ];
            for (x, y) in points {
                row.push_str(&format!(",{:.1},{y:.1},0", 160.0 + x));
            }
            text.push_str(&row);
        }
        text + "\n"
    };
    for (set, n) in [("s1", clips), ("other-speakers", 1)] {
        std::fs::create_dir_all(root.join(set).join("tracks")).unwrap();
        for c in 0..n {
            let offset = c % 3;
            let phone_at = move |t: f64| phones[((t / 0.08) as usize + offset) % 3];
            let name = format!("c{c:03}");
            std::fs::write(
                root.join(set).join("tracks").join(format!("{name}.csv")),
                track(&phone_at),
            )
            .unwrap();
            if set == "s1" {
                let mut phn = String::new();
                for i in 0..12 {
                    let start = i * 1280;
                    phn.push_str(&format!(
                        "{start} {} {}\n",
                        start + 1280,
                        phone_at(i as f64 * 0.08 + 0.04)
                    ));
                }
                let dir = root.join("phones");
                std::fs::create_dir_all(&dir).unwrap();
                std::fs::write(dir.join(format!("{name}.phn")), phn).unwrap();
            }
        }
    }
    root.join("phones")
}

#[test]
fn decompose_grid_prints_table_i_on_tracked_lips() {
    let dir = tempfile::tempdir().unwrap();
    let phones = tiny_grid(dir.path(), 11);
    let grid = dir.path().to_str().unwrap();
    let out = lipcall(&[
        "decompose",
        "--grid",
        grid,
        "--phones",
        phones.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    println!("{text}");
    assert!(text.contains("9 training clips"), "{text}");
    assert!(
        text.contains("s1's 2 held-out clips") && text.contains("1 other-speaker"),
        "{text}"
    );
    // Key shapes: aa opens 9 px of 60 (0.15 eye widths), PP is shut.
    let key = |name: &str| -> Vec<f32> {
        let line = text
            .lines()
            .find(|l| l.starts_with(&format!("{name} ")))
            .unwrap();
        line.split_whitespace()
            .filter_map(|w| w.parse().ok())
            .collect()
    };
    assert!(
        (key("aa")[1] - 0.15).abs() < 0.01 && key("PP")[1].abs() < 0.01,
        "{text}"
    );
    // Every frame is one of the three shapes: with all three the error is near 0, with two
    // it is not.
    let row = |names: &str| -> f32 {
        let line = text
            .lines()
            .find(|l| l.contains(names) && l.contains('%'))
            .unwrap();
        line.split_whitespace()
            .find_map(|w| {
                w.trim_end_matches('%')
                    .parse::<f32>()
                    .ok()
                    .filter(|_| w.ends_with('%'))
            })
            .unwrap()
    };
    assert!(row("PP aa I ") < 1.0, "{text}");
    assert!(row("PP aa  ") > 5.0, "{text}");
    // No phone files: a clear failure that says how to make them.
    let out = lipcall(&[
        "decompose",
        "--grid",
        grid,
        "--phones",
        "/nonexistent/phones",
    ]);
    assert_clean_failure(&out, "align_grid.py");
    let out = lipcall(&[
        "decompose",
        "--grid",
        grid,
        "--markers",
        "x.csv",
        "--key-frames",
        "k.csv",
    ]);
    assert_eq!(out.status.code(), Some(2));
}

/// `evaluate --grid` without `--speakers` scores the lips alone: tuning on lips never glimpses
/// the TIMIT test speakers by accident. Named speakers are still scored beside the lips.
#[test]
fn evaluate_with_grid_scores_timit_speakers_only_when_named() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no-grid");
    let missing = missing.to_str().unwrap();
    let out = lipcall(&["evaluate", "--grid", missing]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(text.contains("model: built-in"), "{text}");
    assert!(!text.contains("held-out speakers"), "{text}");
    assert!(stderr(&out).contains("no-grid"), "{}", stderr(&out));

    let csv = dir.path().join("frames.csv");
    let out = lipcall(&[
        "evaluate",
        "--grid",
        missing,
        "--per-frame",
        csv.to_str().unwrap(),
    ]);
    assert_clean_failure(&out, "--speakers");
    assert!(out.stdout.is_empty() && !csv.exists());

    let out = lipcall(&[
        "evaluate",
        "--grid",
        missing,
        "--speakers",
        "dr4",
        "--utterances",
        "1",
        "--corpus",
        corpus().to_str().unwrap(),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("held-out speakers: dr4-"), "{text}");
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
}

/// `tools/lip_readout.py` (docs/model.md, "Third round"): its least-squares shape values find
/// known values again and score r = 1 on lips made through them, and wrong values score less.
#[test]
fn lip_readout_tool_recovers_known_shape_values() {
    let tool = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/lip_readout.py");
    let out = Command::new("python3")
        .arg(tool)
        .arg("--self-test")
        .output()
        .expect("run python3");
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(String::from_utf8_lossy(&out.stdout).contains("self-test passed"));
}
