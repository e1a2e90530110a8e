//! Mouth-to-ear latency of a call on loopback, measured with an onset sent through two sessions
//! in real time, and broken into its parts.

use std::time::{Duration, Instant};

use lipcall::codec::speex::codec::{
    Decoder, Encoder, EncoderConfig, FrameOutcome, MAX_PACKET_BYTES,
};
use lipcall::net::session::{Session, SessionConfig};
use lipcall::net::transport::PeerFrame;
use lipcall::vocab::FRAME_SIZE;

const ONSET_FRAME: usize = 60;
const TICK: Duration = Duration::from_millis(20);

fn signal(frame: usize) -> [i16; FRAME_SIZE] {
    std::array::from_fn(|i| {
        if frame >= ONSET_FRAME {
            let t = (frame * FRAME_SIZE + i) as f32 / 8000.0;
            (10000.0 * (2.0 * std::f32::consts::PI * 400.0 * t).sin()) as i16
        } else {
            0
        }
    })
}

fn onset(pcm: &[i16]) -> Option<usize> {
    pcm.iter().position(|&s| s.abs() > 1500)
}

/// Samples by which encoding + decoding delays the onset.
fn codec_delay() -> usize {
    let mut enc = Encoder::new(EncoderConfig::default()).unwrap();
    let mut dec = Decoder::new(true).unwrap();
    let mut packet = [0u8; MAX_PACKET_BYTES];
    let mut out = Vec::new();
    let mut pcm = [0i16; FRAME_SIZE];
    for f in 0..ONSET_FRAME + 10 {
        let n = enc.encode_frame(&signal(f), &mut packet).unwrap();
        dec.load(&packet[..n]).unwrap();
        assert_eq!(dec.decode_next(&mut pcm).unwrap(), FrameOutcome::Decoded);
        out.extend_from_slice(&pcm);
    }
    onset(&out).unwrap() - ONSET_FRAME * FRAME_SIZE
}

#[test]
fn mouth_to_ear_on_loopback() {
    let receiver = Session::start(SessionConfig::new("127.0.0.1:0".parse().unwrap())).unwrap();
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
    config.destinations = vec![receiver.local_addr().unwrap()];
    let sender = Session::start(config).unwrap();

    let mut encoder = Encoder::new(EncoderConfig::default()).unwrap();
    let mut packet = [0u8; MAX_PACKET_BYTES];
    // Sender and receiver tick on the same schedule, the receiver's phase offset by half a
    // frame as an unsynchronised sound card would be on average.
    let start = Instant::now();
    let mut heard = None;
    let mut frames: Vec<PeerFrame> = Vec::new();
    let mut encode_time = Duration::ZERO;
    let mut pull_time = Duration::ZERO;
    let mut pulls = 0u32;
    for k in 0..ONSET_FRAME as u32 + 40 {
        // Frame k is captured during [k, k+1) * 20 ms and is complete at (k+1) * 20 ms.
        let captured = start + TICK * (k + 1);
        if let Some(wait) = captured.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        let t = Instant::now();
        let n = encoder
            .encode_frame(&signal(k as usize), &mut packet)
            .unwrap();
        sender.send_frames(&packet[..n], 1).unwrap();
        encode_time += t.elapsed();
        let tick = captured + TICK / 2;
        if let Some(wait) = tick.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        frames.clear();
        let t = Instant::now();
        receiver.pull(tick, &mut frames);
        pull_time += t.elapsed();
        pulls += 1;
        if heard.is_none()
            && let Some(f) = frames.first()
            && let Some(at) = onset(&f.frame.pcm)
        {
            heard = Some(tick + Duration::from_secs_f64(at as f64 / 8000.0));
        }
    }
    let heard = heard.expect("the onset was never played");
    let spoken = start + TICK * ONSET_FRAME as u32;
    let total = heard.duration_since(spoken).as_secs_f64() * 1000.0;
    let peer = &receiver.peers()[0];
    let codec = codec_delay() as f64 / 8.0;
    let jitter = peer.receiver.jitter.current_delay_ms;
    eprintln!(
        "mouth-to-ear {total:.1} ms = framing 20.0 + codec look-ahead/synthesis {codec:.1} + \
         encode+send {:.2} + jitter buffer {jitter:.1} (target {:.1}) + decode+features {:.2} + \
         output tick phase and rest {:.1}",
        encode_time.as_secs_f64() * 1000.0 / pulls as f64,
        peer.receiver.jitter.target_delay_ms,
        pull_time.as_secs_f64() * 1000.0 / pulls as f64,
        total - 20.0 - codec - jitter
    );
    eprintln!("{:?}", peer.receiver);
    assert!(total > 20.0 + codec, "{total}");
    assert!(total < 150.0, "{total}");
}
