//! Encrypted calls replayed: a recording of an earlier `send` call keyed by LIPCALL_KEY replayed into a later
//! `receive` with the same key plays nothing while a fresh caller plays (the master key comes from
//! passphrase and room alone, and such a recording used to play in full); and within one
//! receiver, a caller's packets replayed after its peer expired are refused (the replay window
//! used to go with the peer). Loopback only.

mod common;

use std::collections::HashMap;
use std::net::{SocketAddr, UdpSocket};
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use common::net::{Announce, fields, num, spawn, spawn_listening, talk};
use common::{lipcall, run};
use lipcall::net::peer::FrameKind;
use lipcall::net::session::{Session, SessionConfig};
use lipcall::net::srtp::MasterKey;
use lipcall::net::transport::{PeerFrame, PeerId};

/// Datagrams as they came, each with its time since the first.
type Recording = Vec<(Duration, Vec<u8>)>;

/// Records what arrives at `tap` until `done()` says the sender has finished and nothing more
/// comes for 200 ms.
fn record(tap: &UdpSocket, mut done: impl FnMut() -> bool) -> Recording {
    tap.set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let mut buf = [0u8; 2048];
    let mut start = None;
    let mut out = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        assert!(Instant::now() < deadline, "the call never ended");
        match tap.recv_from(&mut buf) {
            Ok((n, _)) => {
                let t0 = *start.get_or_insert_with(Instant::now);
                out.push((t0.elapsed(), buf[..n].to_vec()));
            }
            Err(_) if done() => return out,
            Err(_) => {}
        }
    }
}

/// Sends a recording to `to` from a socket of its own, each datagram at its recorded time.
fn replay(recording: &Recording, to: SocketAddr) {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let start = Instant::now();
    for (at, datagram) in recording {
        if let Some(wait) = (start + *at).checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        socket.send_to(datagram, to).unwrap();
    }
}

/// The SSRC of a recording's RTP packets (RTCP's second byte is 200..=204).
fn media_ssrc(recording: &Recording) -> u32 {
    let (_, rtp) = recording
        .iter()
        .find(|(_, d)| !(200..=204).contains(&d[1]))
        .expect("media in the recording");
    u32::from_be_bytes([rtp[8], rtp[9], rtp[10], rtp[11]])
}

fn clip(dir: &std::path::Path, seconds: &str) -> std::path::PathBuf {
    let demo = common::demo_8k(dir);
    let clip = dir.join(format!("clip{seconds}.wav"));
    run(Command::new("sox")
        .arg(&demo)
        .arg(&clip)
        .args(["trim", "0", seconds]));
    clip
}

#[test]
fn a_recorded_call_replayed_into_a_later_receiver_plays_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let three_seconds = clip(dir.path(), "3");
    let key = "correct horse";

    // The call as an eavesdropper on the path records it.
    let tap = UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut sender = spawn(
        lipcall()
            .arg("send")
            .arg(&three_seconds)
            .args(["--to", &tap.local_addr().unwrap().to_string()])
            .env("LIPCALL_KEY", key),
    );
    let recording = record(&tap, || sender.try_wait().unwrap().is_some());
    assert!(sender.wait().unwrap().success());
    let media = recording
        .iter()
        .filter(|(_, d)| !(200..=204).contains(&d[1]))
        .count();
    assert_eq!(media, 150, "3 s of 20 ms frames");
    let replayed_ssrc = media_ssrc(&recording);

    // A later receiver, a new process. Every recorded packet is at least the recording's
    // length (3 s) old when it comes again: past a tolerance of 1 s.
    let receiver = spawn_listening(
        lipcall()
            .args([
                "receive",
                "--listen",
                "127.0.0.1:0",
                "--clock-tolerance",
                "1",
            ])
            .env("LIPCALL_KEY", key),
        Announce::Lipcall,
    );
    replay(&recording, receiver.socket_addr());
    // Then a caller who is really there; the receive ends once it has left.
    let fresh_ssrc = replayed_ssrc ^ 1;
    run(lipcall()
        .arg("send")
        .arg(&three_seconds)
        .args([
            "--to",
            &receiver.addr(),
            "--ssrc",
            &format!("{fresh_ssrc:08x}"),
        ])
        .env("LIPCALL_KEY", key));
    let (_, stderr) = receiver.finish(Duration::from_secs(30), "lipcall receive");

    let peers: Vec<HashMap<String, String>> = stderr
        .lines()
        .filter(|l| l.starts_with("peer "))
        .map(|l| {
            l.split_whitespace()
                .filter_map(|kv| kv.split_once('='))
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect()
        })
        .collect();
    let ssrcs: Vec<&str> = peers.iter().map(|p| p["ssrc"].as_str()).collect();
    assert_eq!(ssrcs, [format!("{fresh_ssrc:08x}")], "{stderr}");
    assert!(num(&peers[0], "played") >= 145.0, "{stderr}");
    let session = fields(&stderr, "lipcall: played");
    // Every recorded datagram (media and reports) was refused as stale, none was played.
    assert_eq!(num(&session, "stale"), recording.len() as f64, "{stderr}");
    assert_eq!(num(&session, "auth_failed"), 0.0, "{stderr}");
}

/// Decoded frames per SSRC, pulled every 20 ms until `stop`.
fn play_out(session: &Session, stop: &AtomicBool) -> HashMap<u32, u32> {
    let start = Instant::now();
    let mut decoded = HashMap::new();
    let mut frames: Vec<PeerFrame> = Vec::new();
    let mut tick = 0u32;
    while !stop.load(Ordering::Relaxed) {
        let due = start + Duration::from_millis(20) * tick;
        tick += 1;
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        frames.clear();
        session.pull(due, &mut frames);
        for f in &frames {
            if f.frame.kind == FrameKind::Decoded {
                *decoded.entry(f.peer.number()).or_insert(0) += 1;
            }
        }
    }
    decoded
}

/// Waits (up to 20 s) until `condition` holds.
fn wait_until(what: &str, mut condition: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(20);
    while !condition() {
        assert!(Instant::now() < deadline, "timed out waiting: {what}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn sender(key: &MasterKey, destinations: Vec<SocketAddr>) -> Session {
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
    config.destinations = destinations;
    config.key = Some(key.clone());
    Session::start(config).unwrap()
}

#[test]
fn a_callers_packets_replayed_after_its_peer_expired_are_not_played_again() {
    let key = MasterKey::from_passphrase("correct horse", "");
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
    config.key = Some(key.clone());
    config.peer_timeout = Duration::from_millis(300);
    let receiver = Session::start(config).unwrap();
    let to = receiver.local_addr().unwrap();
    let tap = UdpSocket::bind("127.0.0.1:0").unwrap();
    let stop = AtomicBool::new(false);
    let frames = 50;

    std::thread::scope(|scope| {
        let player = scope.spawn(|| play_out(&receiver, &stop));
        // A caller talks 1 s (to the receiver and to a tap that records it) and hangs up.
        let caller = sender(&key, vec![to, tap.local_addr().unwrap()]);
        let ssrc = caller.ssrc();
        let hung_up = AtomicBool::new(false);
        let recording = std::thread::scope(|inner| {
            let recorder = inner.spawn(|| record(&tap, || hung_up.load(Ordering::Relaxed)));
            talk(&caller, frames);
            // Its BYE is sent before the drop returns.
            drop(caller);
            hung_up.store(true, Ordering::Relaxed);
            recorder.join().unwrap()
        });
        // Its peer expires (after playing out).
        wait_until("the caller's peer expires", || {
            receiver.peers().iter().all(|p| p.id != PeerId::Ssrc(ssrc))
        });
        // Its recording comes again, then a fresh caller talks.
        replay(&recording, to);
        let fresh = sender(&key, vec![to]);
        let fresh_ssrc = fresh.ssrc();
        talk(&fresh, frames);
        drop(fresh);
        // Once its peer has expired too, everything it sent has played.
        wait_until("the fresh caller's peer expires", || {
            receiver
                .peers()
                .iter()
                .all(|p| p.id != PeerId::Ssrc(fresh_ssrc))
        });
        stop.store(true, Ordering::Relaxed);
        let decoded = player.join().unwrap();

        assert_eq!(decoded.get(&fresh_ssrc), Some(&frames), "{decoded:?}");
        // Played once, when it was live; not a frame of the replay.
        assert_eq!(decoded.get(&ssrc), Some(&frames), "{decoded:?}");
        assert!(receiver.peers().iter().all(|p| p.id != PeerId::Ssrc(ssrc)));
        let stats = receiver.stats();
        let media = recording
            .iter()
            .filter(|(_, d)| !(200..=204).contains(&d[1]))
            .count() as u64;
        assert_eq!(media, u64::from(frames));
        // Refused by the replay state the receiver kept, not by the clock.
        assert_eq!(stats.replayed, recording.len() as u64, "{stats:?}");
        assert_eq!(stats.stale, 0, "{stats:?}");
    });
}
