//! Rooms through the relay: three peers hear each other; another room and a wrong key hear
//! nothing; a garbage flood at the relay leaves the room undisturbed. Loopback only, with
//! bounded loops.

mod common;

use std::collections::HashMap;
use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use lipcall::codec::speex::FRAME_SIZE;
use lipcall::codec::speex::codec::{Encoder, EncoderConfig, MAX_PACKET_BYTES};
use lipcall::net::peer::FrameKind;
use lipcall::net::relay::{Relay, RelayConfig};
use lipcall::net::session::{PeerFrame, Session, SessionConfig};
use lipcall::net::srtp::MasterKey;

const FRAMES: u32 = 100; // 2 s

fn peer(relay: SocketAddr, room: &str, passphrase: &str, name: &str) -> Session {
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
    config.destinations = vec![relay];
    config.room = Some(room.into());
    config.key = Some(MasterKey::from_passphrase(passphrase, room));
    config.name = Some(name.into());
    config.rtcp_interval = Duration::from_millis(500);
    let session = Session::start(config).unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    while !session.stats().relay_joined {
        assert!(Instant::now() < deadline, "{name} could not join");
        std::thread::sleep(Duration::from_millis(5));
    }
    session
}

/// A tone whose pitch tells who is talking.
fn tone_packets(freq: f32) -> Vec<Vec<u8>> {
    let mut encoder = Encoder::new(EncoderConfig::default()).unwrap();
    let mut packet = [0u8; MAX_PACKET_BYTES];
    (0..FRAMES as usize)
        .map(|f| {
            let frame: [i16; FRAME_SIZE] = std::array::from_fn(|i| {
                let t = (f * FRAME_SIZE + i) as f32 / 8000.0;
                (8000.0 * (2.0 * std::f32::consts::PI * freq * t).sin()) as i16
            });
            let n = encoder.encode_frame(&frame, &mut packet).unwrap();
            packet[..n].to_vec()
        })
        .collect()
}

/// Zero crossings per second over a peer's decoded audio: about twice its pitch.
fn pitch(pcm: &[i16]) -> f64 {
    let crossings = pcm.windows(2).filter(|w| (w[0] < 0) != (w[1] < 0)).count();
    crossings as f64 / (pcm.len() as f64 / 8000.0) / 2.0
}

struct Heard {
    decoded: HashMap<u32, u32>,
    pcm: HashMap<u32, Vec<i16>>,
}

/// Runs the call in real time: every talker sends a frame per tick, everyone pulls.
fn call(talkers: &[(&Session, Vec<Vec<u8>>)], listeners: &[&Session]) -> Vec<Heard> {
    let start = Instant::now();
    let mut heard: Vec<Heard> = listeners
        .iter()
        .map(|_| Heard {
            decoded: HashMap::new(),
            pcm: HashMap::new(),
        })
        .collect();
    let mut frames: Vec<PeerFrame> = Vec::new();
    for k in 0..FRAMES + 30 {
        let due = start + Duration::from_millis(20) * k;
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        if k < FRAMES {
            for (session, packets) in talkers {
                session.send_frames(&packets[k as usize], 1).unwrap();
            }
        }
        for (listener, h) in listeners.iter().zip(heard.iter_mut()) {
            frames.clear();
            listener.pull(due, &mut frames);
            for f in &frames {
                if f.frame.kind == FrameKind::Decoded {
                    *h.decoded.entry(f.ssrc).or_default() += 1;
                    h.pcm
                        .entry(f.ssrc)
                        .or_default()
                        .extend_from_slice(&f.frame.pcm);
                }
            }
        }
    }
    heard
}

fn flood(relay: SocketAddr, stop: Arc<AtomicBool>) -> u64 {
    let sockets: Vec<UdpSocket> = (0..4)
        .map(|_| UdpSocket::bind("127.0.0.1:0").unwrap())
        .collect();
    let mut state = 0x1234_5678_9abc_def0u64;
    let mut sent = 0u64;
    let deadline = Instant::now() + Duration::from_secs(20);
    // Bounded: at most 200k datagrams, 20 s, and it yields often.
    while !stop.load(Ordering::Relaxed) && sent < 200_000 && Instant::now() < deadline {
        for (i, s) in sockets.iter().enumerate() {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let len = (state % 200) as usize;
            let mut data: Vec<u8> = (0..len).map(|j| (state >> (j % 56)) as u8).collect();
            match i {
                // RTP-looking garbage and random joins into random rooms.
                0 if len >= 12 => data[0] = 0x80,
                1 => {
                    data = b"LPCR\x01\x01".to_vec();
                    data.extend_from_slice(&state.to_be_bytes());
                    data.extend_from_slice(&state.to_le_bytes());
                }
                _ => {}
            }
            let _ = s.send_to(&data, relay);
            sent += 1;
        }
        if sent.is_multiple_of(64) {
            std::thread::sleep(Duration::from_micros(200));
        }
    }
    sent
}

#[test]
fn three_peers_hear_each_other_and_nobody_else_does_under_a_flood() {
    let relay = Relay::start(
        "127.0.0.1:0".parse().unwrap(),
        RelayConfig {
            max_rooms: 64,
            ..Default::default()
        },
    )
    .unwrap();
    let addr = relay.local_addr();
    let alice = peer(addr, "kitchen", "pw", "Alice");
    let bob = peer(addr, "kitchen", "pw", "Bob");
    let carol = peer(addr, "kitchen", "pw", "Carol");
    let stranger = peer(addr, "garden", "pw", "Stranger");
    let intruder = peer(addr, "kitchen", "wrong", "Intruder");

    let stop = Arc::new(AtomicBool::new(false));
    let flooder = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || flood(addr, stop))
    };
    let talkers = [
        (&alice, tone_packets(300.0)),
        (&bob, tone_packets(500.0)),
        (&carol, tone_packets(700.0)),
        (&intruder, tone_packets(900.0)),
    ];
    let heard = call(&talkers, &[&alice, &bob, &carol, &stranger, &intruder]);
    stop.store(true, Ordering::Relaxed);
    let flooded = flooder.join().unwrap();
    for s in [&alice, &bob, &carol] {
        s.send_report();
    }
    // Until the reports (with the SDES names checked below) have reached every member.
    let deadline = Instant::now() + Duration::from_secs(5);
    while Instant::now() < deadline
        && [&alice, &bob, &carol]
            .iter()
            .any(|s| s.peers().into_iter().filter(|p| p.name.is_some()).count() < 2)
    {
        std::thread::sleep(Duration::from_millis(10));
    }

    let members = [(&alice, 300.0), (&bob, 500.0), (&carol, 700.0)];
    for (i, (listener, _)) in members.iter().enumerate() {
        for (j, (talker, freq)) in members.iter().enumerate() {
            if i == j {
                continue;
            }
            let got = heard[i].decoded.get(&talker.ssrc()).copied().unwrap_or(0);
            assert!(
                got >= FRAMES * 9 / 10,
                "peer {i} decoded {got} frames of peer {j}"
            );
            let p = pitch(&heard[i].pcm[&talker.ssrc()]);
            assert!(
                (p - freq).abs() < freq * 0.05,
                "peer {i} heard {p} Hz from peer {j}"
            );
        }
        assert!(!heard[i].decoded.contains_key(&intruder.ssrc()));
        assert!(!heard[i].decoded.contains_key(&listener.ssrc()));
        let stats = listener.stats();
        assert!(stats.auth_failed >= u64::from(FRAMES) / 2, "{stats:?}");
        // Names arrive with RTCP.
        let names: Vec<Option<String>> = listener.peers().into_iter().map(|p| p.name).collect();
        assert!(names.iter().flatten().count() >= 2, "{names:?}");
    }
    // Another room hears nothing; a wrong key hears nothing it can decode.
    assert!(heard[3].decoded.is_empty(), "{:?}", heard[3].decoded);
    assert!(stranger.peers().is_empty());
    assert!(heard[4].decoded.is_empty(), "{:?}", heard[4].decoded);
    assert!(intruder.stats().auth_failed >= u64::from(FRAMES));

    let rs = relay.stats();
    eprintln!("flood of {flooded} datagrams; relay {rs:?}");
    assert!(flooded > 1000);
    assert!(
        rs.unknown_source + rs.malformed + rs.refused > flooded / 2,
        "{rs:?}"
    );
    assert!(rs.rooms <= 64 && rs.members <= 64 * 16, "{rs:?}");
}
