//! The app's engine heard through a PulseAudio null sink: a peer sending fullband Opus (48 kHz)
//! is played with its band above 4 kHz, which the 8 kHz mixer of before cut away; a Speex
//! (narrowband) peer, the control, has none there.
//!
//! Each case runs the engine in a child process of this test binary (its `#[ignore]`d
//! `engine_plays_a_sender` with `LIPCALL_HD_SENDER` set) whose output goes to a null sink of
//! its own (`PULSE_SINK`), so that what the monitor records is the engine's alone.

mod common;

use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::pulse::NullSink;
use common::{band_db, pulse_running, run};
use lipcall::app::engine::{CallPhase, Command as EngineCommand, lock};
use lipcall::codec::any::Codec;
use lipcall::codec::opus::codec::Bandwidth;
use lipcall::commands::net::{KeyArgs, SendArgs, send};

const RATE: u32 = 48_000;

/// Four seconds of speech at 48 kHz with a hiss from 5 kHz up (the demo speech is recorded at
/// 16 kHz: nothing above 8 kHz of its own).
fn fullband_source(dir: &Path) -> std::path::PathBuf {
    let speech = dir.join("speech.wav");
    run(Command::new("sox")
        .arg(common::repo_file("assets/speech/demo.wav"))
        .args(["-D", "-b", "16", "-c", "1", "-r", "48000"])
        .arg(&speech)
        .args(["trim", "0", "4"]));
    let hiss = dir.join("hiss.wav");
    run(Command::new("sox")
        .args(["-n", "-D", "-b", "16", "-c", "1", "-r", "48000"])
        .arg(&hiss)
        .args(["synth", "4", "pinknoise", "highpass", "5000", "gain", "-28"]));
    let out = dir.join("source.wav");
    run(Command::new("sox")
        .args(["-m", "-D"])
        .arg(&speech)
        .arg(&hiss)
        .arg(&out));
    out
}

/// The child: an engine (no window, no demo, the default output = `PULSE_SINK`) hears a sender
/// of `LIPCALL_HD_SENDER` = "CODEC FILE" until the file has been played.
#[test]
#[ignore = "run by the_app_plays_each_peer_at_its_own_band in a child process"]
fn engine_plays_a_sender() {
    let Ok(spec) = std::env::var("LIPCALL_HD_SENDER") else {
        return;
    };
    let (codec, file) = spec.split_once(' ').expect("CODEC FILE");
    let codec: Codec = codec.parse().expect("a codec");
    let engine = common::app::engine_with_audio("Ear", Some("127.0.0.1:0"));
    let to = lock(&engine.shared).call.local_addr.expect("listening");
    let status = lock(&engine.shared).output_status.clone();
    eprintln!("output: {status}; mixer at {} Hz", {
        lock(&engine.shared).playback.mix_rate()
    });
    assert!(status.starts_with("Playing on "), "{status}");
    // An idle null sink may take a while to start consuming a new stream.
    std::thread::sleep(Duration::from_secs(1));
    let args = SendArgs {
        input: file.into(),
        to: to.to_string(),
        key: KeyArgs::default(),
        name: Some("Talker".into()),
        room: None,
        quality: 8,
        bandwidth: Bandwidth::Fullband,
        frame_ms: 20,
        no_rtcp: false,
        ssrc: None,
        codec: Some(codec),
        payload_types: Vec::new(),
        seconds: None,
    };
    let sender = std::thread::spawn(move || send(&args));
    // The peer as last seen before it said goodbye (and was forgotten).
    let mut seen = None;
    while !sender.is_finished() {
        // A direct caller rings (and the ringtone plays) until answered: answered at once, so
        // what the sink hears is the peer.
        let ringing = match &lock(&engine.shared).call.phase {
            CallPhase::Ringing { caller, .. } => *caller,
            _ => None,
        };
        if let Some(caller) = ringing {
            engine.send(EngineCommand::AnswerCaller(caller));
        }
        if let Some(p) = lock(&engine.shared).peers.views().into_iter().next() {
            seen = Some(p);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    sender.join().unwrap().expect("sent");
    std::thread::sleep(Duration::from_millis(500));
    let peer = seen.expect("the sender was heard");
    assert_eq!(peer.codec, Some(codec));
    assert!(peer.frames_received > 150, "{}", peer.frames_received);
}

/// Records `sink`'s monitor at 48 kHz while a child engine plays `codec` from `file`.
fn play_through_the_engine(sink: &str, codec: &str, file: &Path) -> Vec<i16> {
    let mut parec = Command::new("parec")
        .args(["-d", &format!("{sink}.monitor"), "--raw", "--format=s16le"])
        .args(["--channels=1", "--rate=48000"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("parec (pulseaudio-utils) runs");
    let mut out = parec.stdout.take().unwrap();
    // The child starts once the recording runs (the monitor streams the sink's silence): a
    // recording that started late, on a busy machine, missed the first second of the speech.
    let (started, running) = std::sync::mpsc::channel();
    let reader = std::thread::spawn(move || {
        let mut bytes = vec![0u8; 9600];
        let _ = out.read_exact(&mut bytes);
        let _ = started.send(());
        let _ = out.read_to_end(&mut bytes);
        bytes
    });
    running
        .recv_timeout(Duration::from_secs(20))
        .expect("parec records the sink's monitor");
    let child = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "engine_plays_a_sender",
            "--ignored",
            "--nocapture",
        ])
        .env("PULSE_SINK", sink)
        .env("LIPCALL_HD_SENDER", format!("{codec} {}", file.display()))
        .output()
        .expect("the test binary runs");
    let _ = parec.kill();
    let _ = parec.wait();
    let bytes = reader.join().unwrap();
    let log = String::from_utf8_lossy(&child.stderr);
    eprintln!(
        "{codec}: {}",
        log.lines()
            .filter(|l| l.contains("output:"))
            .collect::<String>()
    );
    assert!(
        child.status.success(),
        "{codec}: the engine's run failed:\n{log}"
    );
    bytes
        .chunks_exact(2)
        .map(|b| i16::from_le_bytes([b[0], b[1]]))
        .collect()
}

#[test]
fn the_app_plays_each_peer_at_its_own_band() {
    if !pulse_running() {
        common::unavailable("no PulseAudio server (start .ci/pulse-null-sink.sh): not run");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let source = fullband_source(dir.path());
    let (_, source_pcm) = common::read_wav_i16(&source);
    // The energy above 4 kHz and above 6 kHz (where a narrowband peer's 8 kHz audio has left
    // nothing, even through the filter's skirt), in dB below the whole band's.
    let shares = |pcm: &[i16]| {
        let whole = band_db(pcm, RATE, 20.0);
        (
            band_db(pcm, RATE, 4000.0) - whole,
            band_db(pcm, RATE, 6000.0) - whole,
        )
    };
    let source_share = shares(&source_pcm);
    let sink = NullSink::load("hd", RATE);
    let started = Instant::now();
    let mut heard_shares = Vec::new();
    for codec in ["opus", "speex"] {
        let heard = play_through_the_engine(&sink.name, codec, &source);
        let whole = band_db(&heard, RATE, 20.0);
        let share = shares(&heard);
        eprintln!(
            "{codec}: {:.1} s recorded, whole band {whole:.1} dB; above 4 kHz {:.1} dB, above \
             6 kHz {:.1} dB (the source {:.1} and {:.1})",
            heard.len() as f64 / f64::from(RATE),
            share.0,
            share.1,
            source_share.0,
            source_share.1
        );
        assert!(
            heard.len() > source_pcm.len(),
            "{codec}: {:.1} s recorded, shorter than the speech",
            heard.len() as f64 / f64::from(RATE)
        );
        // Something was played: the speech, well above the null sink's digital silence.
        assert!(
            whole > band_db(&source_pcm, RATE, 20.0) - 12.0,
            "{codec}: {whole:.1} dB"
        );
        heard_shares.push(share);
    }
    eprintln!("both runs in {:.1} s", started.elapsed().as_secs_f64());
    let (opus, speex) = (heard_shares[0], heard_shares[1]);
    // Fullband Opus keeps the band above 4 kHz as the source has it (Opus at 32 kb/s codes the
    // hiss coarsely: within 3 dB); narrowband Speex, as every peer was heard before, has none.
    assert!(
        (opus.0 - source_share.0).abs() < 3.0 && (opus.1 - source_share.1).abs() < 3.0,
        "opus {opus:?} vs source {source_share:?} dB"
    );
    assert!(speex.1 < source_share.1 - 25.0, "speex {speex:?} dB");
}
