//! A third-party Mumble client on the same murmurd as lipcall: a bot written with PyPI's
//! pymumble (tests/data/mumble_bot.py), which speaks and listens through the TCP tunnel. lipcall
//! hears and animates it, and it hears lipcall.

mod common;

use std::process::Command;
use std::time::Duration;

use common::mumble::{Murmur, lipcall_as, runs_here};
use common::net::{finish, spawn};
use common::segmental_snr;
use common::{demo_8k, read_wav_i16, repo_file, run};

fn pymumble_installed() -> bool {
    Command::new("python3")
        .args(["-c", "import pymumble_py3, opuslib"])
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Viseme weights of a WEIGHTS.csv's first column: (rows, lowest, highest).
fn first_column(path: &std::path::Path) -> (usize, f64, f64) {
    let csv = std::fs::read_to_string(path).unwrap();
    let values: Vec<f64> = csv
        .lines()
        .skip(1)
        .map(|r| r.split(',').nth(2).unwrap().parse().unwrap())
        .collect();
    let (lo, hi) = values
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    (values.len(), lo, hi)
}

#[test]
fn a_pymumble_bot_is_heard_and_animated_and_hears_lipcall() {
    if !runs_here("a_pymumble_bot_is_heard_and_animated_and_hears_lipcall") {
        return;
    }
    if !pymumble_installed() {
        common::unavailable("pymumble (pip install pymumble) with opuslib is not installed");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let murmur = Murmur::start(dir.path(), "");
    let say = dir.path().join("say48k.wav");
    run(Command::new("sox")
        .arg(repo_file("assets/speech/demo.wav"))
        .args(["-D", "-r", "48000", "-b", "16", "-c", "1"])
        .arg(&say));

    let rx = spawn(
        lipcall_as(dir.path(), "rx")
            .args(["receive", "--mumble", &murmur.address(), "--name", "Rx"])
            .args(["--seconds", "24"])
            .arg("--wav")
            .arg(dir.path().join("rx.wav"))
            .arg("--weights")
            .arg(dir.path().join("rx.csv")),
    );
    std::thread::sleep(Duration::from_millis(1500));
    let bot = spawn(
        Command::new("python3")
            .arg(repo_file("tests/data/mumble_bot.py"))
            .args(["127.0.0.1", &murmur.port.to_string(), "Bob"])
            .arg(&say)
            .arg(dir.path().join("bot"))
            .arg("14"),
    );
    // The bot talks first (through the tunnel); lipcall talks while it does and after.
    std::thread::sleep(Duration::from_secs(3));
    let tx = spawn(
        lipcall_as(dir.path(), "ann")
            .arg("send")
            .arg(repo_file("assets/speech/demo.wav"))
            .args(["--mumble", &murmur.address(), "--name", "Ann"]),
    );
    let (_, sent) = finish(tx, Duration::from_secs(40), "lipcall send --mumble");
    let (said, bot_err) = finish(bot, Duration::from_secs(60), "the pymumble bot");
    let (_, received) = finish(rx, Duration::from_secs(60), "lipcall receive --mumble");
    eprintln!("bot: {said}{bot_err}\nsender: {sent}\nreceiver: {received}");

    // lipcall heard the bot and animated it (and Ann), one WEIGHTS.csv per speaker.
    let played = |name: &str| {
        received
            .lines()
            .find(|l| l.starts_with("peer ") && l.contains(&format!("name=\"{name}\"")))
            .and_then(|l| {
                l.split_whitespace()
                    .find_map(|w| w.strip_prefix("played="))
                    .and_then(|v| v.parse::<u64>().ok())
            })
            .unwrap_or_else(|| panic!("{name} not among the peers: {received}"))
    };
    assert!(played("Bob") >= 400, "{received}");
    assert!(played("Ann") >= 400, "{received}");
    let csvs: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("rx") && n.ends_with(".csv"))
        })
        .collect();
    assert_eq!(csvs.len(), 2, "{csvs:?}");
    for csv in &csvs {
        let (rows, lo, hi) = first_column(csv);
        assert!(rows >= 400, "{}: {rows} rows", csv.display());
        assert!(hi - lo > 0.2, "{}: the mouth barely moves", csv.display());
    }

    // The bot heard lipcall: Ann's speech, recognisably.
    let heard = dir.path().join("bot-Ann.wav");
    assert!(heard.exists(), "the bot heard nobody named Ann: {said}");
    let heard8k = dir.path().join("bot-Ann-8k.wav");
    run(Command::new("sox")
        .arg(&heard)
        .args(["-D", "-r", "8000", "-b", "16", "-c", "1"])
        .arg(&heard8k));
    let source = read_wav_i16(&demo_8k(dir.path())).1;
    let got = read_wav_i16(&heard8k).1;
    let snr = segmental_snr(&source, &got, 2000).0;
    eprintln!(
        "the bot heard {:.2} s of Ann's {:.2} s; SNR {snr:.2} dB",
        got.len() as f64 / 8000.0,
        source.len() as f64 / 8000.0
    );
    assert!(
        got.len() as f64 >= source.len() as f64 * 0.9,
        "{} samples",
        got.len()
    );
    assert!(snr > 3.0, "{snr:.2} dB");
}
