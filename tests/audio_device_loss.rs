//! An output that disappears mid-call (the sound server drops our stream): the playback says
//! so and goes on silently, peers and clock included; the app's engine opens the device again
//! and plays on. Needs the PulseAudio null sink; without a server (and outside CI) there is
//! nothing to lose and the test only says so.

mod common;

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use lipcall::audio::{OutputStatus, Playback, PlaybackConfig};

fn pactl(args: &[&str]) -> Option<String> {
    let out = Command::new("pactl")
        .args(args)
        .stderr(Stdio::null())
        .output()
        .ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).into_owned())
}

/// One case at a time: each drops every stream of this process.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// No PulseAudio server: a failure under CI, else said and skipped.
fn no_server() -> bool {
    let missing = !common::pulse_running();
    if missing {
        common::unavailable("a PulseAudio server (bash .ci/pulse-null-sink.sh): nothing to lose");
    }
    missing
}

/// Drops this process's playback streams, as a sound server that restarts does.
fn kill_our_streams() {
    let inputs = our_sink_inputs();
    assert!(!inputs.is_empty(), "our stream is not listed");
    for i in &inputs {
        // pactl has no kill-sink-input; pacmd has.
        let ok = Command::new("pacmd")
            .args(["kill-sink-input", i])
            .stdout(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok, "pacmd kill-sink-input {i}");
    }
}

/// Indices of the sink inputs (playback streams) this process owns.
fn our_sink_inputs() -> Vec<String> {
    let pid = format!("application.process.id = \"{}\"", std::process::id());
    let list = pactl(&["list", "sink-inputs"]).unwrap_or_default();
    let mut out = Vec::new();
    let mut current: Option<String> = None;
    for line in list.lines() {
        if let Some(idx) = line.strip_prefix("Sink Input #") {
            current = Some(idx.trim().to_string());
        } else if line.trim() == pid
            && let Some(idx) = current.take()
        {
            out.push(idx);
        }
    }
    out
}

#[test]
fn losing_the_output_goes_silent_and_keeps_time() {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    if no_server() {
        return;
    }
    let mut pb = Playback::start(PlaybackConfig::default()).unwrap();
    assert!(
        matches!(pb.status(), OutputStatus::Playing { .. }),
        "{:?}",
        pb.status()
    );
    let mut feed = pb.add_peer().unwrap();
    let id = feed.id();
    // One second at the mixer's rate (the device's).
    let second = vec![1000i16; feed.rate() as usize];
    feed.push(&second);
    // An idle null sink may take a while to start consuming a new stream.
    let deadline = Instant::now() + Duration::from_secs(4);
    while pb.stats().frames_played < 4800 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
        assert!(pb.poll().is_none(), "a slow start is not a loss");
    }
    let before = pb.stats().frames_played;
    assert!(before >= 4800, "the device is playing: {before} frames");
    assert!(pb.poll().is_none());
    kill_our_streams();
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut switched = None;
    while Instant::now() < deadline {
        if let Some(s) = pb.poll() {
            switched = Some(s.clone());
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let Some(OutputStatus::Silent { reason }) = switched else {
        panic!("no switch to silent: {:?}, {:?}", pb.status(), pb.stats());
    };
    eprintln!("after loss: {reason}");
    // The virtual clock takes over: the peer's audio goes on being "heard". Half a second more
    // of it, so the clock cannot run past the end of the queue however late the switch came.
    feed.push(&second[..second.len() / 2]);
    std::thread::sleep(Duration::from_millis(300));
    let a = pb.heard_position(id, Instant::now());
    std::thread::sleep(Duration::from_millis(200));
    let b = pb.heard_position(id, Instant::now());
    assert!(matches!((a, b), (Some(a), Some(b)) if b > a), "{a:?} {b:?}");
}

#[test]
fn the_app_opens_a_lost_output_again_and_plays_on() {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    if no_server() {
        return;
    }
    let engine = common::app::engine_with_audio("Ann", None);
    let limit = Duration::from_secs(30);
    let playing = |s: &lipcall::app::engine::Shared| s.output_status.starts_with("Playing on");
    common::app::wait_for(&engine, "playing", limit, playing);
    // The stream is listed once the server has it.
    let deadline = Instant::now() + limit;
    while our_sink_inputs().is_empty() {
        assert!(Instant::now() < deadline, "our stream is never listed");
        std::thread::sleep(Duration::from_millis(50));
    }
    kill_our_streams();
    common::app::wait_for(&engine, "the loss said", limit, |s| {
        s.output_status.contains("disappeared")
    });
    common::app::wait_for(&engine, "playing again", limit, playing);
    let deadline = Instant::now() + limit;
    while our_sink_inputs().is_empty() {
        assert!(Instant::now() < deadline, "no stream of ours again");
        std::thread::sleep(Duration::from_millis(50));
    }
}
