//! A sender whose clock runs fast, over real sockets (127.0.0.1) into `lipcall receive`: the
//! receiver sheds the surplus inside the sender's pauses, and every loud frame is in the WAV.

mod common;

use std::time::{Duration, Instant};

use common::net::{Announce, fields, num, spawn_listening};
use common::{lipcall, read_wav_i16};
use lipcall::codec::any::{Codec, EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD};
use lipcall::net::session::{Session, SessionConfig};
use lipcall::vocab::FRAME_SIZE;
use lipcall::vocab::energy_db;

/// Frame `k` of a talker: 1.2 s of a voiced sound, then 0.4 s of faint noise.
fn talker(k: usize) -> ([i16; FRAME_SIZE], bool) {
    common::talker::talker(k, 60, 80)
}

#[test]
fn a_sender_five_percent_fast_loses_no_loud_frame() {
    let dir = tempfile::tempdir().unwrap();
    let wav = dir.path().join("heard.wav");
    let receiver = spawn_listening(
        lipcall()
            .args(["receive", "--listen", "127.0.0.1:0", "--wav"])
            .arg(&wav),
        Announce::Lipcall,
    );
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
    config.destinations = vec![receiver.socket_addr()];
    config.name = Some("Fast".into());
    let session = Session::start(config).unwrap();
    let mut encoder = FrameEncoder::new(Codec::Speex, &EncoderSettings::default()).unwrap();
    let mut payload = [0u8; MAX_FRAME_PAYLOAD];
    // 6 s of the sender's time in 5.7 s: its clock is 5 % fast (a frame every 19.05 ms).
    let period = Duration::from_secs_f64(0.02 / 1.05);
    let frames = 300;
    let start = Instant::now();
    for k in 0..frames {
        if let Some(wait) = (start + period * k as u32).checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        let (n, ticks) = encoder.encode(&talker(k).0, &mut payload).unwrap().unwrap();
        session.send_packet(&payload[..n], ticks).unwrap();
    }
    session.leave();
    let (_, stderr) = receiver.finish(Duration::from_secs(60), "lipcall receive");
    let peer = fields(&stderr, "peer ");
    assert_eq!(num(&peer, "received"), frames as f64, "{stderr}");
    // The drift was seen and corrected by dropping frames: 15 frames' worth came too many.
    assert!(num(&peer, "drift_ppm") > 30_000.0, "{stderr}");
    assert!(num(&peer, "dropped") >= 5.0, "{stderr}");

    // Every loud frame is in the WAV (and the decoder's 5 ms tail of each into the pause's
    // first frame): what was dropped was quiet.
    let loud_sent = (0..frames).filter(|&k| talker(k).1).count();
    let tails = (1..frames)
        .filter(|&k| talker(k - 1).1 && !talker(k).1)
        .count();
    std::fs::copy(&wav, "/tmp/drift_heard.wav").unwrap();
    let (rate, pcm) = read_wav_i16(&wav);
    assert_eq!(rate, 8000);
    let loud_heard = pcm
        .chunks_exact(FRAME_SIZE)
        .filter(|f| energy_db(f) > -35.0)
        .count();
    eprintln!(
        "{loud_heard} loud frames heard for {loud_sent} sent (+{tails} tails); {}",
        stderr
            .lines()
            .find(|l| l.starts_with("peer "))
            .unwrap_or("")
    );
    assert!(loud_heard >= loud_sent + tails, "{loud_heard}: {stderr}");
}
