//! A SIP call's session as SDP configures it, in simulated time.

use std::time::Instant;

use super::*;
use crate::codec::any::{Codec, PayloadMap};
use crate::net::rtcp::{self, Outgoing, ReportBlock};
use crate::net::rtp::{self, RtpStream};
use crate::net::sip::sdp::{Direction, Sdes};
use crate::net::transport::{Transmit, TransmitKind};

const LOCAL: SocketAddr = SocketAddr::V4(std::net::SocketAddrV4::new(
    std::net::Ipv4Addr::LOCALHOST,
    4000,
));

fn negotiated() -> Negotiated {
    let mut payloads = PayloadMap::default();
    payloads.set(Codec::Pcmu, 0).unwrap();
    Negotiated {
        remote: "127.0.0.1:9000".parse().unwrap(),
        rtcp: "127.0.0.1:9001".parse().unwrap(),
        rtcp_mux: false,
        codec: Codec::Pcmu,
        payload_type: 0,
        events: Some(101),
        direction: Direction::SendRecv,
        payloads,
        audio_types: vec![0],
        srtp: None,
        signalling_peer: Some([10, 0, 0, 1].into()),
        frame_ms: 20,
    }
}

fn core(negotiated: &Negotiated, ours: &SdesKey, local: SocketAddr, now: Instant) -> SessionCore {
    SessionCore::new(session_config(negotiated, ours, local).unwrap(), local, now).unwrap()
}

/// The RTP (not empty: no keepalive) the core queued, and where each went.
fn media(core: &mut SessionCore) -> Vec<Transmit> {
    std::iter::from_fn(|| core.poll_transmit())
        .filter(|t| t.kind == TransmitKind::Rtp && !t.data.is_empty())
        .collect()
}

fn pcmu(ssrc: u32) -> RtpStream {
    let mut stream = RtpStream::new(ssrc, 1, 0);
    stream.set_payload(0, 160);
    stream
}

#[test]
fn an_old_style_hold_sends_nothing_and_keeps_the_source() {
    let now = Instant::now();
    let first = negotiated();
    let mut core = core(&first, &SdesKey([1; 30]), LOCAL, now);
    let mut held = negotiated();
    held.remote = "0.0.0.0:9000".parse().unwrap();
    held.direction = Direction::SendOnly;
    renegotiate(&mut core, &first, &held);
    core.send_packet(&[0xff; 160], 160, now).unwrap();
    assert!(media(&mut core).is_empty());
    renegotiate(&mut core, &held, &negotiated());
    core.send_packet(&[0xff; 160], 160, now).unwrap();
    let sent = media(&mut core);
    assert_eq!(sent.len(), 1);
    assert_eq!(sent[0].to, first.remote);
    assert_eq!(
        rtp::parse(&sent[0].data, None).unwrap().header.payload_type,
        0
    );
}

#[test]
fn media_from_the_signalling_peers_nat_is_received_and_answered_there() {
    let now = Instant::now();
    let mut core = core(&negotiated(), &SdesKey([1; 30]), LOCAL, now);
    let mut sender = pcmu(42);
    let mut buf = Vec::new();
    sender.packetize(&[0xff; 160], 1, &mut buf).unwrap();
    let nat: SocketAddr = "10.0.0.1:40000".parse().unwrap();
    core.handle_datagram(&buf, nat, now);
    assert_eq!(core.stats().rtp, 1);
    assert_eq!(core.latched(), Some(nat));
    core.send_packet(&[0xff; 160], 160, now).unwrap();
    assert_eq!(media(&mut core)[0].to, nat);
    // A type SDP did not agree (PCMA, which lipcall reads), and garbage: counted, never
    // decoded.
    sender.set_payload(8, 160);
    sender.packetize(&[0xd5; 160], 1, &mut buf).unwrap();
    core.handle_datagram(&buf, nat, now);
    core.handle_datagram(&[0x80, 0, 1], nat, now);
    assert_eq!(
        (core.stats().unknown_payload, core.stats().malformed),
        (1, 1)
    );
    assert_eq!(core.peers().len(), 1);
}

#[test]
fn sdes_keyed_ends_hear_each_other_and_drop_the_unkeyed() {
    let now = Instant::now();
    let (a_key, b_key) = (SdesKey([1; 30]), SdesKey([2; 30]));
    let towards = |key: &SdesKey| Negotiated {
        srtp: Some(Sdes {
            tag: 1,
            key: key.clone(),
        }),
        signalling_peer: None,
        ..negotiated()
    };
    let mut a = core(&towards(&b_key), &a_key, LOCAL, now);
    let mut b = core(&towards(&a_key), &b_key, LOCAL, now);
    let from: SocketAddr = "127.0.0.1:9001".parse().unwrap();
    a.send_packet(&[0xff; 160], 160, now).unwrap();
    let sent = media(&mut a).remove(0).data;
    assert_eq!(sent.len(), 12 + 160 + 10, "authenticated");
    b.handle_datagram(&sent, from, now);
    assert_eq!((b.stats().rtp, b.stats().auth_failed), (1, 0));
    // The first authenticated packet fixed the source: A's next one from elsewhere (a
    // replay or a rebinding alike) is dropped before decryption, and ours stay there.
    a.send_packet(&[0xff; 160], 160, now).unwrap();
    let next = media(&mut a).remove(0).data;
    b.handle_datagram(&next, "127.0.0.5:9001".parse().unwrap(), now);
    assert_eq!((b.stats().rtp, b.stats().foreign), (1, 1));
    assert_eq!(b.latched(), Some(from));
    // Plain RTP (or a wrong key) into a keyed call is dropped.
    let mut buf = Vec::new();
    pcmu(5).packetize(&[0xff; 160], 1, &mut buf).unwrap();
    b.handle_datagram(&buf, from, now);
    assert_eq!((b.stats().rtp, b.stats().auth_failed), (1, 1));
    // Reports are SRTCP: A's BYE reaches B; one in the clear is not believed.
    a.leave(now);
    let bye = std::iter::from_fn(|| a.poll_transmit())
        .find(|t| t.kind == TransmitKind::Rtcp)
        .unwrap();
    b.handle_datagram(&bye.data, from, now);
    assert_eq!(b.stats().rtcp_auth_failed, 0);
    assert!(b.peers()[0].said_bye);
    let mut clear = Vec::new();
    let outgoing = Outgoing {
        ssrc: a.ssrc(),
        cname: "lipcall-in-the-clear",
        ..Default::default()
    };
    rtcp::build(&outgoing, &mut clear).unwrap();
    b.handle_datagram(&clear, from, now);
    let stats = b.stats();
    assert_eq!((stats.auth_failed, stats.rtcp_auth_failed), (2, 1));
}

/// Two calls' sessions wired back to back, each datagram arriving one 20 ms step after it
/// left (RTP from the cores' RTP ports, RTCP from the ports above), `lose` deciding which of
/// A's RTP packets (by count) never arrive.
struct Wire {
    a: SessionCore,
    b: SessionCore,
    now: Instant,
    in_flight: Vec<(bool, Transmit)>,
    a_rtp_sent: u32,
}

impl Wire {
    fn new() -> Self {
        let now = Instant::now();
        let mut towards_a = negotiated();
        towards_a.remote = "127.0.0.1:4000".parse().unwrap();
        towards_a.rtcp = "127.0.0.1:4001".parse().unwrap();
        let b_local: SocketAddr = "127.0.0.1:9000".parse().unwrap();
        Self {
            a: core(&negotiated(), &SdesKey([1; 30]), LOCAL, now),
            b: core(&towards_a, &SdesKey([1; 30]), b_local, now),
            now,
            in_flight: Vec::new(),
            a_rtp_sent: 0,
        }
    }

    fn step(&mut self, lose: impl Fn(u32) -> bool) {
        self.now += Duration::from_millis(20);
        for (to_b, t) in std::mem::take(&mut self.in_flight) {
            let (core, rtp_port) = if to_b {
                (&mut self.b, 4000)
            } else {
                (&mut self.a, 9000)
            };
            let port = rtp_port + u16::from(t.kind == TransmitKind::Rtcp);
            core.handle_datagram(&t.data, ([127, 0, 0, 1], port).into(), self.now);
        }
        self.a.send_packet(&[0xff; 160], 160, self.now).unwrap();
        self.b.send_packet(&[0xff; 160], 160, self.now).unwrap();
        self.a.handle_timeout(self.now);
        self.b.handle_timeout(self.now);
        let mut played = Vec::new();
        self.a.pull(self.now, &mut played);
        self.b.pull(self.now, &mut played);
        while let Some(t) = self.a.poll_transmit() {
            if t.kind == TransmitKind::Rtp {
                self.a_rtp_sent += 1;
                if lose(self.a_rtp_sent) {
                    continue;
                }
            }
            self.in_flight.push((true, t));
        }
        while let Some(t) = self.b.poll_transmit() {
            self.in_flight.push((false, t));
        }
    }
}

#[test]
fn each_side_reports_what_it_lost_of_the_other_and_learns_what_the_other_lost() {
    let mut wire = Wire::new();
    let mut reports_to = Vec::new();
    for _ in 0..1000 {
        wire.step(|n| n % 10 == 0);
        reports_to.extend(
            wire.in_flight
                .iter()
                .filter(|(to_b, t)| *to_b && t.kind == TransmitKind::Rtcp)
                .map(|(_, t)| t.to),
        );
    }
    // 20 s at 5 s spread 0.5-1.5x (and the SR where the stream starts): two to nine
    // reports, to B's RTCP port.
    assert!((2..=9).contains(&reports_to.len()), "{reports_to:?}");
    assert!(
        reports_to
            .iter()
            .all(|&to| to == "127.0.0.1:9001".parse().unwrap())
    );
    // B lost every tenth of A's packets, and said so; A lost nothing of B's.
    let said_to_a = wire.a.heard().about_us.expect("B reported");
    assert_eq!(said_to_a.ssrc, wire.a.ssrc());
    let fraction = f64::from(said_to_a.fraction_lost) / 256.0;
    assert!((0.08..=0.12).contains(&fraction), "{said_to_a:?}");
    assert!(said_to_a.cumulative_lost >= 20, "{said_to_a:?}");
    let said_to_b: ReportBlock = wire.b.heard().about_us.expect("A reported");
    assert_eq!(said_to_b.cumulative_lost, 0, "{said_to_b:?}");
    // Both sides sent SRs and heard the other's: the round trip is the two steps' 40 ms.
    let rtt = wire.a.heard().rtt_ms.expect("a round trip");
    assert!((35.0..=45.0).contains(&rtt), "{rtt} ms");
    let peer = &wire.a.peers()[0];
    assert!(
        peer.cname
            .as_deref()
            .is_some_and(|c| c.starts_with("lipcall-"))
    );
    let (a, b) = (wire.a.stats(), wire.b.stats());
    assert_eq!((a.foreign_rtcp, b.foreign_rtcp), (0, 0));
}
