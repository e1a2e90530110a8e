//! A call's edges on real sockets (127.0.0.1), into `lipcall receive`: a sender with talk
//! spurts reports no loss, a redial on the same SSRC after BYE plays, junk RTCP keeps no caller
//! out, and another port can neither end a caller with a spoofed BYE nor take over its SSRC.

mod common;

use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use common::net::{Listening, fields, num, start_receiver};
use lipcall::codec::any::{Codec, EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD};
use lipcall::net::rtp::RtpStream;
use lipcall::net::session::{Session, SessionConfig};
use lipcall::vocab::FRAME_SIZE;

const TICK: Duration = Duration::from_millis(20);

/// Waits for it to stop by itself (every peer said BYE, or its `--seconds` are over); what it
/// printed on stderr.
fn stopped(receiver: Listening) -> String {
    receiver
        .finish(Duration::from_secs(60), "lipcall receive")
        .1
}

fn voice(frame: u32) -> [i16; FRAME_SIZE] {
    std::array::from_fn(|i| {
        let t = (frame as usize * FRAME_SIZE + i) as f32 / 8000.0;
        let s: f32 = (1..12)
            .map(|h| (2.0 * std::f32::consts::PI * 130.0 * h as f32 * t).sin() / h as f32)
            .sum();
        (5000.0 * s * (1.0 + (t * 5.0).sin()) / 2.0) as i16
    })
}

/// Sends Speex in real time to `to` from an in-process session: for each 20 ms frame,
/// `talking(k)` says whether it is sent or skipped (silence: the timestamp moves on, the next
/// packet starts a talk spurt); `during(k)` runs before frame k. Says BYE at the end.
fn send(
    to: SocketAddr,
    ssrc: u32,
    frames: u32,
    talking: impl Fn(u32) -> bool,
    mut during: impl FnMut(u32),
) -> u32 {
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
    config.destinations = vec![to];
    config.ssrc = Some(ssrc);
    config.name = Some("Edge".into());
    let session = Session::start(config).unwrap();
    let mut encoder = FrameEncoder::new(Codec::Speex, &EncoderSettings::default()).unwrap();
    let mut payload = [0u8; MAX_FRAME_PAYLOAD];
    let start = Instant::now();
    let mut sent = 0;
    for k in 0..frames {
        if let Some(wait) = (start + TICK * k).checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        during(k);
        if talking(k) {
            let (n, ticks) = encoder.encode(&voice(k), &mut payload).unwrap().unwrap();
            session.send_packet(&payload[..n], ticks).unwrap();
            sent += 1;
        } else {
            session.skip_frames(1);
        }
    }
    session.leave();
    sent
}

#[test]
fn a_sender_with_talk_spurts_reports_no_loss() {
    // 13 s of speech in spurts, with pauses of 40 ms to 1 s between them.
    let spurts: &[(u32, u32)] = &[
        (40, 2),
        (30, 5),
        (25, 10),
        (50, 14),
        (35, 50),
        (60, 3),
        (45, 20),
        (80, 7),
        (70, 30),
        (90, 1),
    ];
    let talking = |k: u32| {
        let mut at = 0;
        for &(len, gap) in spurts {
            if k < at + len {
                return true;
            }
            at += len + gap;
            if k < at {
                return false;
            }
        }
        false
    };
    let frames: u32 = spurts.iter().map(|s| s.0 + s.1).sum();
    let receiver = start_receiver(&[]);
    let sent = send(receiver.socket_addr(), 0x5107, frames, talking, |_| {});
    let stderr = stopped(receiver);
    let peer = fields(&stderr, "peer ");
    assert_eq!(num(&peer, "received"), f64::from(sent), "{stderr}");
    assert_eq!(num(&peer, "lost"), 0.0, "{stderr}");
    assert_eq!(num(&peer, "late"), 0.0, "{stderr}");
    // Every frame sent was played, and what was concealed is at most a frame or two at the
    // start of a pause (before the next spurt's packet shows it was one).
    assert_eq!(num(&peer, "played"), f64::from(sent), "{stderr}");
    assert!(
        num(&peer, "concealed") <= 2.0 * spurts.len() as f64,
        "{stderr}"
    );
}

#[test]
fn a_redial_on_the_same_ssrc_after_bye_plays() {
    // Two calls one after the other with the same SSRC (`send --ssrc`), each from its own port
    // with its own sequence numbers and timestamps, the first ending with BYE: the second used
    // to be ignored (received=704 played=351).
    let receiver = start_receiver(&["--seconds", "5.5"]);
    let first = send(receiver.socket_addr(), 0x0005_5ec0, 100, |_| true, |_| {});
    let second = send(receiver.socket_addr(), 0x0005_5ec0, 100, |_| true, |_| {});
    let stderr = stopped(receiver);
    assert_eq!(stderr.matches("peer ssrc=").count(), 1, "{stderr}");
    let peer = fields(&stderr, "peer ");
    assert_eq!(
        num(&peer, "received"),
        f64::from(first + second),
        "{stderr}"
    );
    // Every frame is played, but for one the buffer may shed when the second call's start was
    // held up by half a frame or more (a sender starting on a loaded machine; see `HELD_UP` in
    // src/net/jitter/corrector.rs).
    let (played, dropped) = (num(&peer, "played"), num(&peer, "dropped"));
    assert_eq!(played + dropped, f64::from(first + second), "{stderr}");
    assert!(dropped <= 1.0, "{stderr}");
    assert_eq!(num(&peer, "lost"), 0.0, "{stderr}");
    assert_eq!(num(&peer, "late"), 0.0, "{stderr}");
}

#[test]
fn junk_rtcp_does_not_keep_a_caller_out() {
    let receiver = start_receiver(&[]);
    // 32 receiver reports of 8 bytes from 32 SSRCs: they used to fill the peer table, refusing
    // every new caller for 30 s.
    let junk = UdpSocket::bind("127.0.0.1:0").unwrap();
    for i in 0..32u32 {
        let mut rr = vec![0x80, 201, 0, 1];
        rr.extend_from_slice(&(0x0bad_0000 + i).to_be_bytes());
        junk.send_to(&rr, receiver.socket_addr()).unwrap();
    }
    let sent = send(receiver.socket_addr(), 0xca11, 100, |_| true, |_| {});
    let stderr = stopped(receiver);
    let session = fields(&stderr, "lipcall: played");
    assert_eq!(num(&session, "too_many_peers"), 0.0, "{stderr}");
    assert_eq!(stderr.matches("peer ssrc=").count(), 1, "{stderr}");
    let peer = fields(&stderr, "peer ");
    assert_eq!(peer["ssrc"], "0000ca11");
    assert_eq!(num(&peer, "played"), f64::from(sent), "{stderr}");
}

#[test]
fn another_port_can_neither_end_nor_hijack_a_caller() {
    let receiver = start_receiver(&[]);
    let ssrc = 0x00c0_ffee_u32;
    let attacker = UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut spoof = RtpStream::new(ssrc, 12_345, 999_999);
    spoof.set_payload(0, 160);
    let mut buf = Vec::new();
    let to = receiver.socket_addr();
    let sent = send(
        to,
        ssrc,
        150,
        |_| true,
        |k| {
            if k == 40 {
                // One 8-byte BYE with the caller's SSRC.
                let mut bye = vec![0x81, 203, 0, 1];
                bye.extend_from_slice(&ssrc.to_be_bytes());
                attacker.send_to(&bye, to).unwrap();
            }
            if (50..110).contains(&k) {
                // 60 packets with the caller's SSRC (PCMU: any bytes decode).
                spoof.packetize(&[0x55; 160], 1, &mut buf).unwrap();
                attacker.send_to(&buf, to).unwrap();
            }
        },
    );
    let stderr = stopped(receiver);
    let peer = fields(&stderr, "peer ");
    let attacker_port = attacker.local_addr().unwrap().port().to_string();
    assert!(
        !peer["addr"].ends_with(&format!(":{attacker_port}")),
        "{stderr}"
    );
    assert_eq!(peer["codec"], "speex", "{stderr}");
    // The whole call played, none of the attacker's packets among it; the real BYE ended it.
    assert_eq!(num(&peer, "received"), f64::from(sent), "{stderr}");
    assert_eq!(num(&peer, "played"), f64::from(sent), "{stderr}");
    assert_eq!(num(&peer, "lost"), 0.0, "{stderr}");
    assert_eq!(peer["bye"], "true", "{stderr}");
}
