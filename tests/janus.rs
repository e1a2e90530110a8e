//! Rooms on a real Janus (Debian's `janus`, started here with the repository's config folder,
//! assets/janus, on a free loopback port): two lipcall processes in one VideoRoom. Each test
//! runs in a network namespace of its own (tests/common/netns.rs), the media on its address.

mod common;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use common::janus::{IN_ROOM, free_tcp_port, janus_installed, receive_in_room, start_janus};
use common::net::{Announce, finish, spawn, spawn_listening};
use common::{demo_8k, lipcall, read_wav_i16, repo_file, segmental_snr};

#[test]
fn two_lipcalls_in_a_janus_room_hear_each_other_and_the_receiver_animates() {
    if !common::janus::runs_here(
        "two_lipcalls_in_a_janus_room_hear_each_other_and_the_receiver_animates",
    ) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let janus = start_janus(dir.path());
    let speech = repo_file("assets/speech/demo.wav");
    let source = read_wav_i16(&demo_8k(dir.path())).1;
    let room = "lipcall-test";
    let pin = "correct horse";

    let wav = dir.path().join("janus.wav");
    let weights = dir.path().join("janus-weights.csv");
    // The receiver creates the room and joins before the sender comes.
    let receiver = receive_in_room(&janus, room, pin, "13", &wav, &weights);
    let sender = spawn(
        lipcall()
            .arg("send")
            .arg(&speech)
            .args(["--janus", &janus.url, "--room", room])
            .env("LIPCALL_KEY", pin)
            .args(["--name", "Ann"]),
    );
    let (_, sent) = finish(sender, Duration::from_secs(30), "lipcall send --janus");
    let (_, received) = receiver.finish(Duration::from_secs(30), "lipcall receive --janus");
    assert!(
        received.contains("\"Ann\"") && received.contains("is publishing"),
        "{received}"
    );
    assert!(
        received.contains("left"),
        "the sender's leaving is seen: {received}"
    );
    let got = read_wav_i16(&wav).1;

    // The same audio sent directly: lipcall's own Opus round trip over RTP.
    let direct_wav = dir.path().join("direct.wav");
    let direct_rx = spawn_listening(
        lipcall()
            .args(["receive", "--listen", "127.0.0.1:0"])
            .args(["--seconds", "11", "--rate", "8000"])
            .arg("--wav")
            .arg(&direct_wav),
        Announce::Lipcall,
    );
    let direct_tx = spawn(lipcall().arg("send").arg(&speech).args([
        "--to",
        &direct_rx.addr(),
        "--codec",
        "opus",
    ]));
    finish(
        direct_tx,
        Duration::from_secs(30),
        "lipcall send --codec opus",
    );
    direct_rx.finish(Duration::from_secs(30), "lipcall receive");
    let direct = read_wav_i16(&direct_wav).1;

    let (snr_janus, lag_janus) = segmental_snr(&source, &got, 2000);
    let (snr_direct, lag_direct) = segmental_snr(&source, &direct, 2000);
    eprintln!(
        "SNR through Janus {snr_janus:.2} dB (lag {lag_janus}), direct Opus round trip \
         {snr_direct:.2} dB (lag {lag_direct}); received {:.2} s of {:.2} s",
        got.len() as f64 / 8000.0,
        source.len() as f64 / 8000.0
    );
    assert!(
        (snr_janus - snr_direct).abs() <= 1.0,
        "Janus {snr_janus:.2} dB vs direct {snr_direct:.2} dB\nsender: {sent}\nreceiver: {received}"
    );
    assert!(
        snr_direct > 5.0,
        "the reference itself is sound: {snr_direct:.2} dB"
    );
    assert!(
        got.len() as f64 >= source.len() as f64 * 0.97,
        "{} samples",
        got.len()
    );

    let csv = std::fs::read_to_string(&weights).unwrap();
    let mut lines = csv.lines();
    let header = lines.next().unwrap();
    assert!(header.starts_with("frame,time_s,"), "{header}");
    let columns = header.split(',').count();
    let rows: Vec<&str> = lines.collect();
    assert!(
        rows.len() * 160 >= got.len() * 95 / 100,
        "{} rows",
        rows.len()
    );
    assert!(rows.iter().all(|r| r.split(',').count() == columns));
    // The mouth moves: viseme weights vary over the utterance.
    let first: Vec<f64> = rows
        .iter()
        .map(|r| r.split(',').nth(2).unwrap().parse().unwrap())
        .collect();
    let (lo, hi) = first
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    assert!(hi - lo > 0.2, "weights barely move: {lo}..{hi}");
}

#[test]
fn a_wrong_pin_and_an_unreachable_janus_fail_at_once_with_janus_s_reason() {
    if common::netns::ran_in_own_namespace(
        "a_wrong_pin_and_an_unreachable_janus_fail_at_once_with_janus_s_reason",
    ) {
        return;
    }
    // Nothing listens on a port that was free a moment ago.
    let port = free_tcp_port();
    let started = Instant::now();
    let out = lipcall()
        .args([
            "receive",
            "--janus",
            &format!("http://127.0.0.1:{port}/janus"),
        ])
        .args(["--room", "r", "--seconds", "2"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("cannot reach Janus at"), "{stderr}");
    assert!(started.elapsed() < Duration::from_secs(5));

    if !janus_installed() {
        common::unavailable("the pin check: no `janus` binary (Debian package janus)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let janus = start_janus(dir.path());
    let owner = spawn_listening(
        lipcall()
            .args(["receive", "--janus", &janus.url, "--room", "pinned"])
            .args(["--seconds", "3"])
            .env("LIPCALL_KEY", "right"),
        IN_ROOM,
    );
    for key in [Some("wrong"), None] {
        let started = Instant::now();
        let mut cmd = lipcall();
        cmd.args(["receive", "--janus", &janus.url, "--room", "pinned"])
            .args(["--seconds", "2"]);
        if let Some(key) = key {
            cmd.env("LIPCALL_KEY", key);
        }
        let out = cmd.output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{stderr}");
        assert!(stderr.contains("Janus VideoRoom error 4"), "{stderr}");
        assert!(stderr.contains("pin"), "{stderr}");
        assert!(started.elapsed() < Duration::from_secs(5));
    }
    owner.finish(Duration::from_secs(20), "the room's first member");
}

#[test]
fn a_restarted_janus_is_said_and_rejoined_and_the_call_goes_on() {
    if !common::janus::runs_here("a_restarted_janus_is_said_and_rejoined_and_the_call_goes_on") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut janus = start_janus(dir.path());
    let room = "restarts";
    let receiver = spawn_listening(
        lipcall()
            .args(["receive", "--janus", &janus.url, "--room", room])
            .args(["--seconds", "15"]),
        IN_ROOM,
    );
    let sender = spawn(
        lipcall()
            .arg("send")
            .arg(repo_file("assets/speech/demo.wav"))
            .args(["--janus", &janus.url, "--room", room, "--name", "Ann"]),
    );
    std::thread::sleep(Duration::from_secs(4));
    janus.restart();
    let (_, sent) = finish(sender, Duration::from_secs(30), "lipcall send --janus");
    let (_, received) = receiver.finish(Duration::from_secs(30), "lipcall receive --janus");
    for (who, stderr) in [("sender", &sent), ("receiver", &received)] {
        assert!(stderr.contains("lost the Janus room"), "{who}: {stderr}");
        assert!(stderr.contains("back in the Janus room"), "{who}: {stderr}");
    }
    // The receiver hears the sender again in the new session: about the last 3 s of 8.8.
    let peer = received
        .lines()
        .find(|l| l.starts_with("peer "))
        .unwrap_or_else(|| panic!("no peer line: {received}"));
    let count: u32 = peer
        .split_whitespace()
        .find_map(|kv| kv.strip_prefix("received="))
        .and_then(|v| v.parse().ok())
        .unwrap();
    assert!(count >= 75, "{count} packets after the restart: {received}");
}

#[test]
fn each_publisher_is_a_peer_and_the_receive_ends_when_all_have_left() {
    if !common::janus::runs_here("each_publisher_is_a_peer_and_the_receive_ends_when_all_have_left")
    {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let janus = start_janus(dir.path());
    let room = "two-voices";
    let weights = dir.path().join("w.csv");
    // No --seconds: the receive ends once both publishers have left.
    let receiver = spawn_listening(
        lipcall()
            .args(["receive", "--janus", &janus.url, "--room", room])
            .arg("--weights")
            .arg(&weights),
        IN_ROOM,
    );
    let send = |name: &str| {
        spawn(
            lipcall()
                .arg("send")
                .arg(repo_file("assets/speech/demo.wav"))
                .args(["--janus", &janus.url, "--room", room, "--name", name]),
        )
    };
    let ann = send("Ann");
    std::thread::sleep(Duration::from_millis(700));
    let cy = send("Cy");
    finish(ann, Duration::from_secs(30), "Ann's send");
    finish(cy, Duration::from_secs(30), "Cy's send");
    let (_, received) = receiver.finish(Duration::from_secs(20), "lipcall receive --janus");
    for name in ["Ann", "Cy"] {
        assert!(
            received.contains(&format!("\"{name}\" (")) && received.contains("is publishing"),
            "{name}: {received}"
        );
    }
    assert_eq!(received.matches(") left").count(), 2, "{received}");
    let peers: Vec<&str> = received
        .lines()
        .filter(|l| l.starts_with("peer "))
        .collect();
    assert_eq!(peers.len(), 2, "{received}");
    // One weights file per publisher: the first as asked, the other beside it by SSRC.
    let files: Vec<PathBuf> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with('w') && n.ends_with(".csv"))
        })
        .collect();
    assert_eq!(files.len(), 2, "{files:?}");
    for file in files {
        let rows = std::fs::read_to_string(&file).unwrap().lines().count() - 1;
        assert!(rows >= 400, "{}: {rows} rows", file.display());
    }
}
