//! How `lipcall receive` ends and what it leaves: stopped with SIGINT or SIGTERM mid-call it
//! still writes a whole WAV of what it played and its CSVs (it used to keep everything in
//! memory and write nothing); a caller that goes silent without BYE has left after
//! `--peer-timeout`; an output it cannot write fails before the call starts.

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use common::net::{spawn, start_receiver};
use common::{lipcall, repo_file};
use lipcall::net::session::{Session, SessionConfig};
use lipcall::vocab::FRAME_SIZE;

fn csv_rows(path: &Path) -> (String, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).expect("the CSV was written");
    let mut lines = text.lines();
    let header = lines.next().expect("a header").to_string();
    let rows = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    (header, rows)
}

fn stopped_mid_call_leaves_whole_files(signal_name: &str) {
    let dir = tempfile::tempdir().unwrap();
    let wav = dir.path().join("out.wav");
    let features = dir.path().join("features.csv");
    let weights = dir.path().join("weights.csv");
    let receiver = start_receiver(&[
        "--wav",
        wav.to_str().unwrap(),
        "--features",
        features.to_str().unwrap(),
        "--weights",
        weights.to_str().unwrap(),
    ]);
    let demo = repo_file("assets/speech/demo.wav");
    let mut sender = spawn(
        lipcall()
            .arg("send")
            .arg(&demo)
            .args(["--to", &receiver.addr()]),
    );
    // Mid-sentence: the demo lasts longer than this.
    std::thread::sleep(Duration::from_millis(2500));
    receiver.signal(signal_name);
    let (_, stderr) = receiver.finish(Duration::from_secs(10), "lipcall receive");
    let _ = sender.kill();
    let _ = sender.wait();
    let said: Vec<&str> = stderr.lines().collect();
    assert!(
        said.iter().any(|l| l.contains("stopped by a signal")),
        "{said:?}"
    );
    assert!(said.iter().any(|l| l.starts_with("peer ssrc=")), "{said:?}");

    let mut reader = hound::WavReader::open(&wav).expect("a valid WAV");
    let spec = reader.spec();
    assert_eq!(
        (spec.sample_rate, spec.channels, spec.bits_per_sample),
        (8000, 1, 16)
    );
    let samples: Vec<i16> = reader
        .samples::<i16>()
        .map(|s| s.expect("every sample the header counts is there"))
        .collect();
    assert_eq!(samples.len() % FRAME_SIZE, 0);
    let frames = samples.len() / FRAME_SIZE;
    assert!(
        (50..=125).contains(&frames),
        "{frames} frames played in 2.5 s"
    );
    assert!(samples.iter().any(|&s| s.abs() > 1000), "speech was played");

    // One peer, playing through to the end: its last row is the WAV's last frame.
    let (header, rows) = csv_rows(&features);
    assert!(header.starts_with("frame,time_s,mode,lsp1"), "{header}");
    assert!(
        rows.len() + 5 >= frames && rows.len() <= frames,
        "{} rows",
        rows.len()
    );
    assert_eq!(rows.last().unwrap()[0], (frames - 1).to_string());
    assert!(rows.iter().all(|r| r.len() == 14));
    let (header, rows) = csv_rows(&weights);
    let columns = header.split(',').count();
    assert!(columns > 3, "{header}");
    assert_eq!(rows.last().unwrap()[0], (frames - 1).to_string());
    assert!(
        rows.iter().all(|r| r.len() == columns),
        "every row has its weights"
    );
}

#[test]
fn sigint_mid_call_leaves_a_whole_wav_and_csvs() {
    stopped_mid_call_leaves_whole_files("INT");
}

#[test]
fn sigterm_mid_call_leaves_a_whole_wav_and_csvs() {
    stopped_mid_call_leaves_whole_files("TERM");
}

#[test]
fn a_caller_silent_without_bye_has_left_after_the_peer_timeout() {
    let dir = tempfile::tempdir().unwrap();
    let wav = dir.path().join("out.wav");
    let receiver = start_receiver(&["--peer-timeout", "1", "--wav", wav.to_str().unwrap()]);
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
    config.destinations = vec![receiver.socket_addr()];
    // No RTCP: no BYE when it goes.
    config.send_rtcp = false;
    let session = Session::start(config).unwrap();
    common::net::talk(&session, 50);
    drop(session);
    let gone = Instant::now();
    // Without the timeout it waited for a BYE that never comes.
    receiver.finish(Duration::from_secs(15), "lipcall receive");
    assert!(gone.elapsed() >= Duration::from_millis(900));
    let (rate, samples) = common::read_wav_i16(&wav);
    assert_eq!(rate, 8000);
    assert!(
        samples.len() >= 45 * FRAME_SIZE,
        "{} samples",
        samples.len()
    );
}

#[test]
fn an_output_that_cannot_be_written_fails_before_the_call() {
    let dir = tempfile::tempdir().unwrap();
    for flag in ["--wav", "--features", "--weights"] {
        let path = dir.path().join("no/such/dir/out");
        let started = Instant::now();
        let out = lipcall()
            .args(["receive", "--listen", "127.0.0.1:0", flag])
            .arg(&path)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{flag}: {stderr}");
        assert!(stderr.contains("cannot write"), "{flag}: {stderr}");
        assert!(!stderr.contains("listening on"), "{flag}: {stderr}");
        assert!(started.elapsed() < Duration::from_secs(10));
    }
}
