//! `lipcall send --frame-ms 10`: Opus in 10 ms packets, RTP timestamps 480 apart, decoded by
//! GStreamer as lipcall's own decoder decodes it, and animated by `lipcall receive` one weights
//! row per 20 ms, as its 20 ms send is.

mod common;

use std::net::UdpSocket;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

use common::net::{Announce, align, fields, num, spawn_listening};
use common::{lipcall, read_wav_i16, run};
use lipcall::codec::opus::codec::{Decoder, MAX_PACKET_SAMPLES, packet_samples};

const OPUS_CAPS: &str =
    "application/x-rtp,media=audio,clock-rate=48000,encoding-name=OPUS,payload=96";

/// One test at a time: each runs real-time senders and receivers.
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

fn clip(dir: &Path) -> std::path::PathBuf {
    let out = dir.join("clip.wav");
    run(Command::new("sox")
        .arg(common::demo_8k(dir))
        .arg(&out)
        .args(["trim", "0", "3"]));
    out
}

/// Every RTP packet `lipcall send ARGS` sends to a socket of the test's own, in order.
fn capture_send(clip: &Path, args: &[&str]) -> Vec<(u32, Vec<u8>)> {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    socket
        .set_read_timeout(Some(Duration::from_secs(3)))
        .unwrap();
    let to = socket.local_addr().unwrap().to_string();
    let reader = std::thread::spawn(move || {
        let mut packets = Vec::new();
        let mut buf = [0u8; 2048];
        // The sender's end shows as 3 s of quiet.
        while let Ok(n) = socket.recv(&mut buf) {
            let rtp = lipcall::net::rtp::parse(&buf[..n], Some(96)).unwrap();
            packets.push((rtp.header.timestamp, rtp.payload.to_vec()));
        }
        packets
    });
    run(lipcall()
        .arg("send")
        .arg(clip)
        .args(["--to", &to, "--no-rtcp", "--codec", "opus"])
        .args(args));
    reader.join().unwrap()
}

/// `lipcall send ARGS` into `udpsrc ! rtpopusdepay ! opusdec` at 8 kHz: GStreamer's decode.
fn gstreamer_decode(clip: &Path, args: &[&str]) -> Vec<i16> {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("gst.wav");
    let mut gst = Command::new("gst-launch-1.0");
    gst.args(["-v", "-e", "udpsrc", "port=0"])
        .arg(format!("caps={OPUS_CAPS}"))
        .args(["!", "rtpopusdepay", "!", "opusdec", "!"])
        .args(["audio/x-raw,rate=8000,channels=1", "!", "wavenc", "!"])
        .arg("filesink")
        .arg(format!("location={}", out.display()));
    let gst = spawn_listening(&mut gst, Announce::GstUdpsrc);
    run(lipcall()
        .arg("send")
        .arg(clip)
        .args(["--to", &gst.addr(), "--no-rtcp", "--codec", "opus"])
        .args(args));
    // udpsrc takes what is still in its socket before the EOS that SIGINT sends.
    std::thread::sleep(Duration::from_millis(500));
    gst.interrupt();
    gst.finish(Duration::from_secs(30), "gst-launch udpsrc");
    let (rate, pcm) = read_wav_i16(&out);
    assert_eq!(rate, 8000);
    pcm
}

/// The RTP timestamps step 480 (10 ms of the 48 kHz clock), every packet holds 10 ms, and
/// GStreamer decodes what lipcall's own decoder decodes of the same packets, for as long.
#[test]
fn send_in_10_ms_frames_steps_480_and_gstreamer_decodes_it() {
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let clip = clip(dir.path());
    let packets = capture_send(&clip, &["--frame-ms", "10"]);
    // 3 s: 300 packets of 10 ms (the last one padded).
    assert!((299..=301).contains(&packets.len()), "{}", packets.len());
    for pair in packets.windows(2) {
        assert_eq!(pair[1].0.wrapping_sub(pair[0].0), 480);
    }
    let mut decoder = Decoder::new().unwrap();
    let mut expected = Vec::new();
    let mut out = [0i16; MAX_PACKET_SAMPLES];
    for (_, payload) in &packets {
        assert_eq!(packet_samples(payload, 48_000), Ok(480));
        let n = decoder.decode(payload, &mut out).unwrap();
        expected.extend_from_slice(&out[..n]);
    }
    let got = gstreamer_decode(&clip, &["--frame-ms", "10"]);
    assert!(
        got.len().abs_diff(expected.len()) <= 160,
        "GStreamer decoded {} samples, lipcall {}",
        got.len(),
        expected.len()
    );
    let same = align(&expected, &got, 400);
    eprintln!(
        "10 ms frames: GStreamer against lipcall's decode: median {:.1} dB",
        same.median()
    );
    assert!(same.median() > 60.0, "{same:?}");
    assert!(same.share_above(40.0) >= 0.95, "{same:?}");

    // Without the flag, 20 ms frames as before; codecs other than Opus refuse 10 ms.
    let twenty = capture_send(&clip, &[]);
    assert!((149..=151).contains(&twenty.len()), "{}", twenty.len());
    assert!(
        twenty
            .windows(2)
            .all(|p| p[1].0.wrapping_sub(p[0].0) == 960)
    );
    for (codec, ms) in [("pcmu", "10"), ("speex", "10"), ("opus", "15")] {
        let out = lipcall()
            .arg("send")
            .arg(&clip)
            .args(["--to", "127.0.0.1:9", "--codec", codec, "--frame-ms", ms])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{codec} at {ms} ms: {stderr}");
        assert!(stderr.contains("frame"), "{codec} at {ms} ms: {stderr}");
    }
}

/// A WEIGHTS.csv's rows of weights (rows with none, before the first came, left out).
fn weight_rows(path: &Path) -> Vec<Vec<f32>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').skip(2).map(|v| v.parse().unwrap()).collect())
        .filter(|row: &Vec<f32>| !row.is_empty())
        .collect()
}

struct Animated {
    played_frames: usize,
    weights: Vec<Vec<f32>>,
    all_rows: usize,
    received: f64,
}

/// `lipcall send ARGS` into `lipcall receive --wav --weights`.
fn into_receive(clip: &Path, args: &[&str]) -> Animated {
    let dir = tempfile::tempdir().unwrap();
    let wav = dir.path().join("played.wav");
    let weights = dir.path().join("weights.csv");
    let receiver = spawn_listening(
        lipcall()
            .args(["receive", "--listen", "127.0.0.1:0", "--rate", "8000"])
            .arg("--wav")
            .arg(&wav)
            .arg("--weights")
            .arg(&weights)
            .args(["--seconds", "6"]),
        Announce::Lipcall,
    );
    run(lipcall()
        .arg("send")
        .arg(clip)
        .args(["--to", &receiver.addr(), "--codec", "opus"])
        .args(args));
    let (_, stderr) = receiver.finish(Duration::from_secs(60), "lipcall receive");
    let peer = fields(&stderr, "peer ");
    assert_eq!(num(&peer, "decode_errors"), 0.0, "{stderr}");
    let played = read_wav_i16(&wav).1;
    assert_eq!(played.len() % 160, 0);
    Animated {
        played_frames: played.len() / 160,
        all_rows: std::fs::read_to_string(&weights).unwrap().lines().count() - 1,
        weights: weight_rows(&weights),
        received: num(&peer, "received"),
    }
}

/// The mean absolute difference of two runs' weights, at the best shift of up to 5 rows (the
/// two runs' jitter buffers may start a frame apart), and that shift.
fn weights_apart(a: &[Vec<f32>], b: &[Vec<f32>]) -> (f64, i64) {
    let mut best = (f64::INFINITY, 0);
    for shift in -5i64..=5 {
        let pairs: Vec<(&Vec<f32>, &Vec<f32>)> = (0..a.len() as i64)
            .filter_map(|i| Some((&a[i as usize], b.get(usize::try_from(i + shift).ok()?)?)))
            .collect();
        let (sum, n) = pairs.iter().fold((0.0, 0usize), |(s, n), (x, y)| {
            let d: f64 = x
                .iter()
                .zip(*y)
                .map(|(p, q)| f64::from((p - q).abs()))
                .sum();
            (s + d / x.len() as f64, n + 1)
        });
        let mean = sum / n.max(1) as f64;
        if n > a.len() / 2 && mean < best.0 {
            best = (mean, shift);
        }
    }
    best
}

/// `send --frame-ms 10` into `lipcall receive`: it plays, with a weights row for every 20 ms
/// frame played (two packets a step), and its weights are those of the 20 ms send as nearly as
/// the 20 ms send's own are those of its input 10 ms later (a half-step shift of the framing:
/// the measure of "the same within coding"; docs/audio.md has the numbers).
#[test]
fn send_in_10_ms_frames_animates_a_row_per_20_ms_like_the_20_ms_send() {
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let clip = clip(dir.path());
    let later = dir.path().join("later.wav");
    run(Command::new("sox")
        .arg(&clip)
        .arg(&later)
        .args(["pad", "0.01", "0"]));
    let ten = into_receive(&clip, &["--frame-ms", "10"]);
    let twenty = into_receive(&clip, &[]);
    let shifted = into_receive(&later, &[]);
    assert!(ten.received >= 280.0, "{} packets", ten.received);
    assert!(twenty.received >= 140.0, "{} packets", twenty.received);
    for run in [&ten, &twenty] {
        assert!(run.played_frames >= 145, "{} frames", run.played_frames);
        assert_eq!(run.all_rows, run.played_frames);
        assert!(run.weights.len() + 5 >= run.played_frames);
    }
    let (apart, shift) = weights_apart(&twenty.weights, &ten.weights);
    let (baseline, _) = weights_apart(&twenty.weights, &shifted.weights);
    eprintln!(
        "weights, mean |difference| per weight: 10 ms frames against 20 ms ones {apart:.4} (at a \
         shift of {shift} rows); the 20 ms send against itself 10 ms later {baseline:.4}"
    );
    // Measured: 0.031 against 0.043 (before the row took the later of two 10 ms frames: 0.043).
    assert!(
        apart <= baseline * 1.25 + 0.005,
        "{apart:.4} vs {baseline:.4}"
    );
    assert!(apart < 0.06, "{apart:.4}");
}
