//! The app's microphone is read in the frame length it sends: Opus in 10 ms frames leaves
//! each packet as its 10 ms are captured, not in pairs every 20 ms (which a listener takes for
//! 10 ms of jitter and a 10 ms later first half).
//!
//! Each case runs the engine in a child process of this test binary (its `#[ignore]`d
//! `engine_calls_with_its_microphone` with `LIPCALL_MIC_CALL` set) whose microphone is the
//! monitor of a null sink of its own (`PULSE_SOURCE`). It calls a plain UDP socket here, which
//! stamps each RTP packet's arrival. Per packet, the arrival less its RTP timestamp's time is
//! its lateness; the first and the second 10 ms of each 20 ms differ in it by about 10 ms when
//! both leave together, by about nothing when each leaves on time. Medians over hundreds of
//! packets, so a loaded machine's bursts do not decide.
//!
//! Over SIP, the app offers the settings' frame length and sends the one SDP agreed: twice the
//! packets to a `lipcall sip answer --frame-ms 10` as to one that says `a=ptime:20`.

mod common;

use std::net::UdpSocket;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::pulse::NullSink;
use common::pulse_running;
use lipcall::app::engine::{CallPhase, CallSpec, Command as EngineCommand, Engine, lock};
use lipcall::codec::any::Codec;

/// How long the child calls for.
const CALL: Duration = Duration::from_secs(6);

/// The child: an engine (no window, no demo, the default source = `PULSE_SOURCE`) calls
/// `LIPCALL_MIC_CALL` = "ADDRESS FRAME_MS" in Opus for [`CALL`].
#[test]
#[ignore = "run by the tests below in a child process"]
fn engine_calls_with_its_microphone() {
    let Ok(spec) = std::env::var("LIPCALL_MIC_CALL") else {
        return;
    };
    let (address, frame_ms) = spec.split_once(' ').expect("ADDRESS FRAME_MS");
    let engine = calling_in_opus(address, frame_ms.parse().expect("a frame length"));
    std::thread::sleep(CALL);
    let status = lock(&engine.shared).input_status.clone();
    eprintln!("input: {status}");
    engine.send(EngineCommand::Leave);
}

/// An engine with a real microphone (the default source) that calls `address` in Opus with
/// `frame_ms` frames once the microphone is open.
fn calling_in_opus(address: &str, frame_ms: u8) -> Engine {
    let engine = common::app::engine_with_audio("Mouth", None);
    common::app::wait_for(
        &engine,
        "the microphone opened",
        Duration::from_secs(10),
        |s| s.mic.is_some(),
    );
    engine.send(EngineCommand::Call(Box::new(CallSpec {
        address: address.into(),
        codec: Codec::Opus,
        frame_ms,
        ..CallSpec::default()
    })));
    engine
}

/// One Opus packet heard: when, and its RTP timestamp.
struct Heard {
    at: Instant,
    timestamp: u32,
}

/// Runs the child calling a socket here with `frame_ms` frames; the RTP packets it sent.
fn call_with_frames(frame_ms: u8) -> Vec<Heard> {
    let mic = NullSink::load(&format!("mic{frame_ms}"), 48_000);
    let ear = NullSink::load(&format!("ear{frame_ms}"), 48_000);
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    socket
        .set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let address = socket.local_addr().unwrap();
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "engine_calls_with_its_microphone",
            "--ignored",
            "--nocapture",
        ])
        .env("PULSE_SOURCE", format!("{}.monitor", mic.name))
        .env("PULSE_SINK", &ear.name)
        .env("LIPCALL_MIC_CALL", format!("{address} {frame_ms}"))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the test binary runs");
    let mut heard = Vec::new();
    let mut buf = [0u8; 2048];
    let deadline = Instant::now() + CALL + Duration::from_secs(30);
    while Instant::now() < deadline {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        let Ok(n) = socket.recv(&mut buf) else {
            continue;
        };
        let at = Instant::now();
        // RTP (version 2) of Opus: not RTCP, not the session's own messages.
        if n < 12 || buf[0] >> 6 != 2 || buf[1] & 0x7f != Codec::Opus.default_payload_type() {
            continue;
        }
        heard.push(Heard {
            at,
            timestamp: u32::from_be_bytes([buf[4], buf[5], buf[6], buf[7]]),
        });
    }
    let _ = child.kill();
    let out = child.wait_with_output().expect("the child ends");
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "{frame_ms} ms: the engine's run failed:\n{log}"
    );
    heard
}

/// Per packet: its lateness (arrival less its timestamp's time since the first packet), ms,
/// and which 10 ms of its 20 ms it codes (0 or 1).
fn lateness(heard: &[Heard], ticks: u32) -> Vec<(f64, u32)> {
    let first = &heard[0];
    heard
        .iter()
        .map(|h| {
            let since = h.timestamp.wrapping_sub(first.timestamp);
            let media_ms = f64::from(since) / 48.0;
            let arrived_ms = (h.at - first.at).as_secs_f64() * 1000.0;
            (arrived_ms - media_ms, (since / ticks) % 2)
        })
        .collect()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn check_pulse() -> bool {
    let running = pulse_running();
    if !running {
        common::unavailable("a PulseAudio server (bash .ci/pulse-null-sink.sh)");
    }
    running
}

#[test]
fn ten_ms_frames_leave_as_the_microphone_captures_them() {
    if !check_pulse() {
        return;
    }
    let heard = call_with_frames(10);
    assert!(heard.len() > 200, "{} packets", heard.len());
    let steps: Vec<u32> = heard
        .windows(2)
        .map(|w| w[1].timestamp.wrapping_sub(w[0].timestamp))
        .collect();
    let tens = steps.iter().filter(|&&s| s == 480).count();
    assert!(
        tens * 10 >= steps.len() * 9,
        "{tens} of {} packets 480 ticks (10 ms) after the one before",
        steps.len()
    );
    let late = lateness(&heard, 480);
    let half = |h| median(late.iter().filter(|l| l.1 == h).map(|l| l.0).collect());
    let (first, second) = (half(0), half(1));
    eprintln!(
        "10 ms frames: {} packets, median lateness {first:.1} ms (first halves), {second:.1} ms \
         (second halves)",
        late.len()
    );
    // Sent in pairs, every first half waits 10 ms for its second (9.8 ms measured with the
    // microphone read in 20 ms); each on its own, they differ by what the device's bursts make
    // of it (1 to 5 ms on the null sink's monitor at load 9).
    assert!(
        (first - second).abs() < 7.0,
        "first halves {first:.1} ms late, second halves {second:.1} ms"
    );
}

#[test]
fn twenty_ms_frames_leave_every_20_ms() {
    if !check_pulse() {
        return;
    }
    let heard = call_with_frames(20);
    assert!(heard.len() > 100, "{} packets", heard.len());
    let twenties = heard
        .windows(2)
        .filter(|w| w[1].timestamp.wrapping_sub(w[0].timestamp) == 960)
        .count();
    assert!(
        twenties * 10 >= (heard.len() - 1) * 9,
        "{twenties} of {} packets 960 ticks (20 ms) after the one before",
        heard.len() - 1
    );
    let gaps: Vec<f64> = heard
        .windows(2)
        .map(|w| (w[1].at - w[0].at).as_secs_f64() * 1000.0)
        .collect();
    let gap = median(gaps);
    assert!((12.0..28.0).contains(&gap), "median gap {gap:.1} ms");
}

/// Packets a `lipcall sip answer ANSWER_ARGS` received from the app calling it for 4 s with
/// `frame_ms` frames (its summary's `received`).
fn sip_packets_received(frame_ms: u8, answer_args: &[&str]) -> f64 {
    let dir = tempfile::tempdir().unwrap();
    let port = common::sip::free_port(false);
    let heard = dir.path().join("heard.wav");
    let answer = common::sip::lipcall_answering_with(dir.path(), port, "30", &heard, answer_args);
    let engine = calling_in_opus(&format!("sip:lipcall@127.0.0.1:{port}"), frame_ms);
    common::app::wait_for(&engine, "in the call", Duration::from_secs(20), |s| {
        matches!(s.call.phase, CallPhase::InCall { .. })
    });
    std::thread::sleep(Duration::from_secs(4));
    engine.send(EngineCommand::Leave);
    assert!(
        answer.wait_for("received=", Duration::from_secs(15)),
        "{}",
        answer.text()
    );
    let text = answer.text();
    common::net::num(&common::net::fields(&text, "peer "), "received")
}

#[test]
fn over_sip_the_app_sends_the_frame_length_it_offered_and_the_peer_took() {
    if !check_pulse() {
        return;
    }
    let ten = sip_packets_received(10, &["--frame-ms", "10"]);
    // The answer says a=ptime:20: the app asked for 10 but sends 20.
    let twenty = sip_packets_received(10, &[]);
    eprintln!("packets received: {ten} at 10 ms, {twenty} where the answer took 20");
    // Sending 20 where 10 was agreed (before: the phone always offered 20) gives the same
    // count; 10 ms gave 1.63 times as many at load 9 (the call's first packets go at 20 ms
    // until SDP's answer is in).
    assert!(twenty >= 100.0 && ten >= 1.3 * twenty, "{ten} vs {twenty}");
}
