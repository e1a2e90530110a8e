//! Rooms through the relay: three peers hear each other; another room and a wrong key hear
//! nothing; a garbage flood at the relay leaves the room undisturbed; forged joins and leaves
//! (sent from the socket whose address they forge, as the relay would see them) change no
//! membership, and junk joins do not keep a caller out. Loopback only, with bounded loops.

mod common;

use std::collections::HashMap;
use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use lipcall::codec::speex::codec::{Encoder, EncoderConfig, MAX_PACKET_BYTES};
use lipcall::net::control::{self, Control, ControlKind, Cookie, Refusal, RoomId};
use lipcall::net::peer::FrameKind;
use lipcall::net::relay::{Relay, RelayConfig};
use lipcall::net::session::{Session, SessionConfig};
use lipcall::net::srtp::MasterKey;
use lipcall::net::transport::PeerFrame;
use lipcall::vocab::FRAME_SIZE;

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

/// Pulls after the last frame sent: a second, for the delay a stall of this busy thread
/// (the flood beside it) adds, which a tone that never pauses gives the buffer no pause to
/// shed.
const TAIL: u32 = 50;

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
    for k in 0..FRAMES + TAIL {
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
                    *h.decoded.entry(f.peer.number()).or_default() += 1;
                    h.pcm
                        .entry(f.peer.number())
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
            // Five peers from one address (loopback).
            max_members_per_source: 8,
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

fn udp() -> UdpSocket {
    let s = UdpSocket::bind("127.0.0.1:0").unwrap();
    s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    s
}

fn send(socket: &UdpSocket, relay: SocketAddr, kind: ControlKind, room: &str, cookie: Cookie) {
    let request = Control::new(kind, RoomId::from_name(room), cookie);
    socket.send_to(&request.encode(), relay).unwrap();
}

fn recv(socket: &UdpSocket) -> Vec<u8> {
    let mut buf = [0u8; 1600];
    let (n, _) = socket
        .recv_from(&mut buf)
        .expect("a datagram from the relay");
    buf[..n].to_vec()
}

/// A member on a plain socket: join, echo the cookie; the cookie is its token.
fn member(relay: SocketAddr, room: &str) -> (UdpSocket, Cookie) {
    let socket = udp();
    send(&socket, relay, ControlKind::Join, room, Cookie::NONE);
    let challenge = Control::decode(&recv(&socket)).unwrap();
    assert_eq!(challenge.kind, ControlKind::Challenge);
    send(&socket, relay, ControlKind::Confirm, room, challenge.cookie);
    let joined = Control::decode(&recv(&socket)).unwrap();
    assert_eq!(joined.kind, ControlKind::Joined);
    (socket, challenge.cookie)
}

fn rtp(seq: u16) -> [u8; 14] {
    let [hi, lo] = seq.to_be_bytes();
    [0x80, 110, hi, lo, 0, 0, 0, 0, 0, 0, 0, 9, 1, 2]
}

/// Everything already queued on a socket.
fn drain(socket: &UdpSocket) -> Vec<Vec<u8>> {
    socket.set_nonblocking(true).unwrap();
    let mut got = Vec::new();
    let mut buf = [0u8; 1600];
    while let Ok((n, _)) = socket.recv_from(&mut buf) {
        got.push(buf[..n].to_vec());
    }
    socket.set_nonblocking(false).unwrap();
    got
}

fn wait_for_stats(relay: &Relay, done: impl Fn(&lipcall::net::relay::RelayStats) -> bool) {
    let deadline = Instant::now() + Duration::from_secs(5);
    while !done(&relay.stats()) {
        assert!(Instant::now() < deadline, "{:?}", relay.stats());
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn a_forged_join_does_not_make_an_uninvolved_address_receive_the_room() {
    let relay = Relay::start("127.0.0.1:0".parse().unwrap(), RelayConfig::default()).unwrap();
    let addr = relay.local_addr();
    let (alice, _) = member(addr, "kitchen");
    let (bob, _) = member(addr, "kitchen");
    // The victim never asked for anything: these are what an attacker forging its address
    // sends (a join, a confirm with a guessed cookie), as they reach the relay.
    let victim = udp();
    send(&victim, addr, ControlKind::Join, "kitchen", Cookie::NONE);
    send(
        &victim,
        addr,
        ControlKind::Confirm,
        "kitchen",
        Cookie([7; 16]),
    );
    wait_for_stats(&relay, |s| s.bad_cookie == 1);
    for seq in 0..20 {
        alice.send_to(&rtp(seq), addr).unwrap();
    }
    // Bob has all 20 copies: the relay has handled every packet.
    for _ in 0..20 {
        assert_eq!(recv(&bob).len(), 14);
    }
    let reflected = drain(&victim);
    let kinds: Vec<ControlKind> = reflected
        .iter()
        .map(|d| Control::decode(d).expect("only control answers").kind)
        .collect();
    assert_eq!(kinds, [ControlKind::Challenge, ControlKind::Challenge]);
    assert!(reflected.iter().all(|d| d.len() == control::LEN));
    assert_eq!(relay.stats().members, 2);
}

#[test]
fn a_forged_leave_does_not_cut_a_member_off() {
    let relay = Relay::start("127.0.0.1:0".parse().unwrap(), RelayConfig::default()).unwrap();
    let addr = relay.local_addr();
    let (alice, alice_cookie) = member(addr, "kitchen");
    let (bob, bob_cookie) = member(addr, "kitchen");
    let (carol, _) = member(addr, "kitchen");
    // Leaves in Bob's name (sent from his address, as the relay sees a forged one): without a
    // cookie, with a made-up one, with Alice's.
    for cookie in [Cookie::NONE, Cookie([7; 16]), alice_cookie] {
        send(&bob, addr, ControlKind::Leave, "kitchen", cookie);
    }
    wait_for_stats(&relay, |s| s.bad_cookie == 3);
    alice.send_to(&rtp(1), addr).unwrap();
    assert_eq!(recv(&bob), rtp(1));
    assert_eq!(recv(&carol), rtp(1));
    assert_eq!(relay.stats().members, 3);
    // His own leave, with his cookie, does remove him.
    send(&bob, addr, ControlKind::Leave, "kitchen", bob_cookie);
    wait_for_stats(&relay, |s| s.leaves == 1);
    alice.send_to(&rtp(2), addr).unwrap();
    assert_eq!(recv(&carol), rtp(2));
    assert!(drain(&bob).is_empty());
}

#[test]
fn junk_joins_do_not_keep_a_caller_out() {
    let relay = Relay::start("127.0.0.1:0".parse().unwrap(), RelayConfig::default()).unwrap();
    let addr = relay.local_addr();
    // 256 sockets that never read: joins into the caller's room and into others, confirms
    // with made-up cookies, and joins of the outdated protocol. In batches the relay takes
    // in before the next (none is lost to a full socket buffer).
    let junk: Vec<UdpSocket> = (0..256).map(|_| udp()).collect();
    let mut v1_join = [0u8; 22];
    v1_join[..5].copy_from_slice(b"LPCR\x01");
    v1_join[5] = 1;
    let mut sent = 0;
    for round in 0..8u8 {
        for batch in junk.chunks(32) {
            for (k, s) in batch.iter().enumerate() {
                let room = if k % 2 == 0 {
                    "kitchen".to_string()
                } else {
                    format!("junk {k}")
                };
                send(s, addr, ControlKind::Join, &room, Cookie::NONE);
                send(s, addr, ControlKind::Confirm, &room, Cookie([round; 16]));
                s.send_to(&v1_join, addr).unwrap();
                sent += 3;
            }
            wait_for_stats(&relay, |s| s.datagrams >= sent);
        }
    }
    let stats = relay.stats();
    assert_eq!(
        (
            stats.challenges,
            stats.bad_cookie,
            stats.outdated,
            stats.members
        ),
        (4096, 2048, 2048, 0),
        "{stats:?}"
    );
    let alice = peer(addr, "kitchen", "pw", "Alice");
    let bob = peer(addr, "kitchen", "pw", "Bob");
    assert!(alice.stats().relay_joined && bob.stats().relay_joined);
    wait_for_stats(&relay, |s| s.members == 2);
}

#[test]
fn a_refused_join_says_why() {
    let relay = Relay::start(
        "127.0.0.1:0".parse().unwrap(),
        RelayConfig {
            max_members: 1,
            ..Default::default()
        },
    )
    .unwrap();
    let addr = relay.local_addr();
    let _alice = peer(addr, "kitchen", "pw", "Alice");
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
    config.destinations = vec![addr];
    config.room = Some("kitchen".into());
    let bob = Session::start(config).unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    while bob.stats().relay_refusal.is_none() {
        assert!(Instant::now() < deadline, "{:?}", bob.stats());
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(bob.stats().relay_refusal, Some(Refusal::RoomFull));
    assert!(!bob.stats().relay_joined);
}

#[test]
fn a_session_rejoins_a_restarted_relay_on_its_next_keepalive() {
    let relay = Relay::start("127.0.0.1:0".parse().unwrap(), RelayConfig::default()).unwrap();
    let addr = relay.local_addr();
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
    config.destinations = vec![addr];
    config.room = Some("kitchen".into());
    config.keepalive_interval = Duration::from_millis(100);
    let session = Session::start(config).unwrap();
    wait_for_stats(&relay, |s| s.members == 1);
    drop(relay);
    // A new process: a new secret, so the session's token is unknown there.
    let relay = Relay::start(addr, RelayConfig::default()).unwrap();
    wait_for_stats(&relay, |s| s.members == 1 && s.bad_cookie >= 1);
    assert!(
        session.stats().relay_challenges >= 2,
        "{:?}",
        session.stats()
    );
}
