//! Capture from a real device: the PulseAudio null sink's monitor (the default source there)
//! hears a tone the playback engine plays. Without a server (outside CI): the no-input path.

mod common;

use common::pulse_running;

use std::time::{Duration, Instant};

use lipcall::audio::{Capture, DeviceChoice, Gate, OutputStatus, Playback, PlaybackConfig};
use lipcall::vocab::FRAME_SIZE;

#[test]
fn loopback_through_the_monitor_gives_8k_frames_meter_and_gates() {
    if !pulse_running() {
        assert!(
            std::env::var_os("CI").is_none(),
            "CI must provide PulseAudio"
        );
        match Capture::start(&DeviceChoice::Default) {
            Ok(c) => eprintln!("an input exists without PulseAudio: {c:?}"),
            Err(e) => assert!(e.to_string().contains("receive-only"), "{e}"),
        }
        return;
    }
    let mut pb = Playback::start(PlaybackConfig {
        peer_queue: Duration::from_secs(4),
        ..PlaybackConfig::default()
    })
    .unwrap();
    assert!(matches!(pb.status(), OutputStatus::Playing { .. }));
    let mut mic = Capture::start(&DeviceChoice::Default).expect("the monitor source opens");
    let controls = mic.controls();

    // 3 s of 500 Hz at half scale (-6 dBFS), at the mixer's rate.
    let mut feed = pb.add_peer().unwrap();
    let rate = feed.rate() as f32;
    let tone: Vec<i16> = (0..3 * feed.rate())
        .map(|i| {
            let ph = 2.0 * std::f32::consts::PI * 500.0 * i as f32 / rate;
            (16384.0 * ph.sin()) as i16
        })
        .collect();
    feed.push(&tone);

    let mut frame = [0i16; FRAME_SIZE];
    let mut loud_frames = 0;
    let mut peak_db = f32::MIN;
    let deadline = Instant::now() + Duration::from_secs(3);
    while Instant::now() < deadline && loud_frames < 25 {
        while let Some(gate) = mic.read_frame(&mut frame).unwrap() {
            assert_eq!(gate, Gate::Open);
            let peak = frame.iter().map(|s| s.unsigned_abs()).max().unwrap_or(0);
            if (14_000..19_000).contains(&peak) {
                loud_frames += 1;
            }
        }
        peak_db = peak_db.max(controls.level().peak_dbfs);
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(loud_frames >= 25, "tone frames heard: {loud_frames}");
    assert!((-8.0..-4.0).contains(&peak_db), "meter {peak_db} dBFS");

    // Muted: frames keep coming (time goes on) but closed and silent.
    controls.set_muted(true);
    std::thread::sleep(Duration::from_millis(100));
    let mut closed = 0;
    while let Some(gate) = mic.read_frame(&mut frame).unwrap() {
        if gate == Gate::Closed {
            assert!(frame.iter().all(|&s| s == 0));
            closed += 1;
        }
    }
    assert!(closed > 0);
    assert!(!mic.lost());
}
