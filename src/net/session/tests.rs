//! The core's rules in simulated time, without sockets; then a few tests of the socket thread
//! that drives it.

use std::collections::HashMap;

use super::latch::{Latch, Named};
use super::remote::{CONFIRM_PACKETS, PENDING_NAMES, UNCONFIRMED_TIMEOUT};
use super::timers::{Due, EXPIRY_INTERVAL};
use super::*;
use crate::codec::any::{EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD};
use crate::codec::g711::ulaw_to_linear;
use crate::net::control::{Control, ControlKind, Cookie, Refusal};
use crate::net::peer::{FrameKind, PlayedFrame};
use crate::net::rtcp::{self, Outgoing, SenderInfo, system_draw};
use crate::net::rtp::{self, RtpStream};
use crate::net::srtp::MasterKey;
use crate::vocab::FRAME_SIZE;

const FRAME: Duration = Duration::from_millis(20);

/// Where the core under test is bound (no socket is).
const LOCAL: SocketAddr =
    SocketAddr::new(std::net::IpAddr::V4(std::net::Ipv4Addr::LOCALHOST), 4000);

fn session(max_peers: usize) -> SessionCore {
    let mut config = SessionConfig::new(LOCAL);
    config.max_peers = max_peers;
    config.ssrc = Some(1);
    SessionCore::new(config, LOCAL, Instant::now()).unwrap()
}

fn addr(port: u16) -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], port))
}

fn voice(frame: u32) -> [i16; FRAME_SIZE] {
    std::array::from_fn(|i| {
        let t = (frame as usize * FRAME_SIZE + i) as f32 / 8000.0;
        let s: f32 = (1..12)
            .map(|h| (2.0 * std::f32::consts::PI * 140.0 * h as f32 * t).sin() / h as f32)
            .sum();
        (5000.0 * s) as i16
    })
}

/// One sender of Speex frames.
struct Caller {
    stream: RtpStream,
    encoder: FrameEncoder,
    frame: u32,
}

impl Caller {
    fn new(ssrc: u32, seq: u16, ts: u32) -> Self {
        Self {
            stream: RtpStream::new(ssrc, seq, ts),
            encoder: FrameEncoder::new(Codec::Speex, &EncoderSettings::default()).unwrap(),
            frame: 0,
        }
    }

    fn packet(&mut self) -> Vec<u8> {
        let mut out = [0u8; MAX_FRAME_PAYLOAD];
        let (n, ticks) = self
            .encoder
            .encode(&voice(self.frame), &mut out)
            .unwrap()
            .unwrap();
        self.frame += 1;
        let mut buf = Vec::new();
        self.stream
            .packetize_ticks(&out[..n], ticks, &mut buf)
            .unwrap();
        buf
    }

    /// RTCP from this sender: an SR (where its stream is now), with BYE if `bye`.
    fn report(&self, bye: bool) -> Vec<u8> {
        let sender = SenderInfo {
            ntp: 0,
            rtp_timestamp: self.stream.next_timestamp(),
            packets: self.frame,
            octets: 0,
        };
        rtcp_from(self.stream.ssrc, Some(sender), bye)
    }
}

fn rtcp_from(ssrc: u32, sender: Option<SenderInfo>, bye: bool) -> Vec<u8> {
    let mut buf = Vec::new();
    rtcp::build(
        &Outgoing {
            ssrc,
            sender,
            blocks: &[],
            cname: "spoof",
            name: None,
            bye,
            ..Default::default()
        },
        &mut buf,
    )
    .unwrap();
    buf
}

/// Drives the session in simulated time: before each 20 ms tick `send(k)` gives the
/// datagrams arriving in it, then every peer is pulled. Returns what each SSRC played.
fn drive(
    core: &mut SessionCore,
    ticks: std::ops::Range<u32>,
    mut send: impl FnMut(u32) -> Vec<(SocketAddr, Vec<u8>)>,
    played: &mut HashMap<u32, Vec<FrameKind>>,
) {
    let mut out = Vec::new();
    for k in ticks {
        let now = core.epoch + FRAME * k;
        for (from, data) in send(k) {
            core.handle_datagram(&data, from, now);
        }
        core.pull(now, &mut out);
        for f in out.drain(..) {
            played
                .entry(f.peer.number())
                .or_default()
                .push(f.frame.kind);
        }
        if k % 50 == 0 {
            core.expire(now);
        }
    }
}

fn decoded(played: &HashMap<u32, Vec<FrameKind>>, ssrc: u32) -> usize {
    played.get(&ssrc).map_or(0, |v| {
        v.iter().filter(|&&k| k == FrameKind::Decoded).count()
    })
}

fn peer_addr(core: &SessionCore, ssrc: u32) -> Option<SocketAddr> {
    core.peers.get(&ssrc).map(|p| p.addr)
}

fn names_from(ssrc: u32, name: &str) -> Vec<u8> {
    let mut buf = Vec::new();
    rtcp::build(
        &Outgoing {
            ssrc,
            sender: None,
            blocks: &[],
            cname: "caller@host",
            name: Some(name),
            ..Default::default()
        },
        &mut buf,
    )
    .unwrap();
    buf
}

#[test]
fn a_name_sent_before_the_first_packet_names_the_peer_from_its_address_only() {
    // Every sender's first RTCP (SDES) precedes its media: the caller used to stay
    // nameless until its next report, and the app took its demo peer for a real caller.
    let mut core = session(8);
    let mut played = HashMap::new();
    let mut ann = Caller::new(7, 100, 5000);
    let mut bob = Caller::new(8, 200, 6000);
    drive(
        &mut core,
        0..1,
        |_| {
            let mut junk: Vec<(SocketAddr, Vec<u8>)> = (0..PENDING_NAMES as u32)
                .map(|i| (addr(41_000 + i as u16), names_from(500 + i, "junk")))
                .collect();
            // Bob's name comes from another port than his media: not his.
            junk.insert(0, (addr(5000), names_from(7, "Ann")));
            junk.push((addr(6001), names_from(8, "Mallory")));
            junk
        },
        &mut played,
    );
    assert!(core.peers.is_empty());
    assert_eq!(core.pending_names.len(), PENDING_NAMES);
    // The pending names were full of junk after Ann's: hers was displaced; send it again.
    drive(
        &mut core,
        1..2,
        |_| vec![(addr(5000), names_from(7, "Ann"))],
        &mut played,
    );
    drive(
        &mut core,
        2..12,
        |_| vec![(addr(5000), ann.packet()), (addr(6000), bob.packet())],
        &mut played,
    );
    let rx = &core;
    assert_eq!(rx.peers[&7].name.as_deref(), Some("Ann"));
    assert_eq!(rx.peers[&7].cname.as_deref(), Some("caller@host"));
    assert_eq!(rx.peers[&8].name, None);
}

#[test]
fn junk_rtcp_makes_no_peer_and_keeps_no_caller_out() {
    // 32 receiver reports of 8 bytes from 32 SSRCs used to fill the peer table for 30 s.
    let mut core = session(32);
    let mut played = HashMap::new();
    drive(
        &mut core,
        0..1,
        |_| {
            (0..32u32)
                .map(|i| {
                    let mut rr = vec![0x80, 201, 0, 1];
                    rr.extend_from_slice(&(1000 + i).to_be_bytes());
                    (addr(40_000 + i as u16), rr)
                })
                .collect()
        },
        &mut played,
    );
    assert!(core.peers.is_empty());
    let mut caller = Caller::new(7, 100, 5000);
    drive(
        &mut core,
        1..121,
        |k| {
            if k <= 100 {
                vec![(addr(5000), caller.packet())]
            } else {
                Vec::new()
            }
        },
        &mut played,
    );
    assert_eq!(decoded(&played, 7), 100);
    assert_eq!(core.stats().too_many_peers, 0);
}

#[test]
fn a_socket_churning_new_ssrcs_never_locks_a_new_caller_out() {
    let mut core = session(32);
    let mut caller = Caller::new(7, 100, 5000);
    let mut churn = RtpStream::new(0, 0, 0);
    churn.set_payload(0, 160);
    let mut next_ssrc = 1_000_000;
    let mut heard = 0;
    let mut out = Vec::new();
    for k in 0..260u32 {
        let tick = core.epoch + FRAME * k;
        // 2,000 valid PCMU packets a second, one every 0.5 ms, each from a new SSRC, all from
        // one socket; the caller's packet lands in the middle of a tick's burst.
        for i in 0..40u32 {
            let now = tick + Duration::from_micros(500 * u64::from(i));
            if i == 14 && (10..210).contains(&k) {
                core.handle_datagram(&caller.packet(), addr(5000), now);
            }
            churn.ssrc = next_ssrc;
            next_ssrc += 1;
            let mut buf = Vec::new();
            churn.packetize(&[0x55; 160], 1, &mut buf).unwrap();
            core.handle_datagram(&buf, addr(6000), now);
        }
        core.pull(tick + FRAME, &mut out);
        heard += out
            .drain(..)
            .filter(|f| f.peer == PeerId::Ssrc(7) && f.frame.kind == FrameKind::Decoded)
            .count();
        if k % 50 == 0 {
            core.expire(tick);
        }
    }
    assert!(heard >= 180, "the caller played {heard} of 200 frames");
    assert!(core.stats().evicted > 9000, "{:?}", core.stats());
}

#[test]
fn junk_media_never_evicts_a_talking_caller_nor_blocks_a_new_one() {
    let mut core = session(4);
    let mut played = HashMap::new();
    let mut a = Caller::new(7, 100, 5000);
    let mut b = Caller::new(8, 9000, 77);
    let mut junk = RtpStream::new(0, 0, 0);
    junk.set_payload(0, 160);
    drive(
        &mut core,
        0..260,
        |k| {
            let mut out = Vec::new();
            if k < 200 {
                out.push((addr(5000), a.packet()));
            }
            if (20..120).contains(&k) {
                // A PCMU packet (any bytes decode) from a new SSRC every 20 ms.
                junk.ssrc = 50_000 + k;
                let mut buf = Vec::new();
                junk.packetize(&[0x55; 160], 1, &mut buf).unwrap();
                out.push((addr(6000 + k as u16), buf));
            }
            if (130..230).contains(&k) {
                out.push((addr(5001), b.packet()));
            }
            out
        },
        &mut played,
    );
    assert_eq!(decoded(&played, 7), 200);
    assert_eq!(decoded(&played, 8), 100);
    let stats = core.stats();
    assert!(stats.evicted >= 90, "{stats:?}");
    assert_eq!(stats.too_many_peers, 0, "{stats:?}");
    // The junk ages out within seconds, the callers stay.
    let mut peers: Vec<u32> = core.peers.keys().copied().collect();
    peers.sort_unstable();
    assert_eq!(peers, [7, 8]);
}

#[test]
fn a_spoofed_bye_from_another_address_is_ignored() {
    let mut core = session(32);
    let mut played = HashMap::new();
    let mut caller = Caller::new(7, 100, 5000);
    drive(
        &mut core,
        0..130,
        |k| {
            let mut out = Vec::new();
            if k < 100 {
                out.push((addr(5000), caller.packet()));
            }
            if k == 50 {
                // 8 bytes: BYE for the caller's SSRC, from elsewhere; and a whole compound.
                let mut bye = vec![0x81, 203, 0, 1];
                bye.extend_from_slice(&7u32.to_be_bytes());
                out.push((addr(6666), bye));
                out.push((addr(6667), rtcp_from(7, None, true)));
            }
            out
        },
        &mut played,
    );
    assert_eq!(decoded(&played, 7), 100);
    let peers = core.peers.get(&7).map(|p| p.said_bye).unwrap();
    assert!(!peers);
    // The lone BYE, and the compound's report and BYE.
    assert_eq!(core.stats().foreign, 3);
    // From the caller's own address it counts.
    drive(
        &mut core,
        130..131,
        |_| vec![(addr(5000), caller.report(true))],
        &mut played,
    );
    assert!(core.peers[&7].said_bye);
}

#[test]
fn packets_from_another_port_do_not_hijack_a_caller() {
    let mut core = session(32);
    let mut played = HashMap::new();
    let mut caller = Caller::new(7, 100, 5000);
    // Another port sends 60 packets with the caller's SSRC: first with its own sequence,
    // then copying the caller's next sequence number and timestamp.
    let mut spoof = Caller::new(7, 31_000, 1_000_000);
    drive(
        &mut core,
        0..170,
        |k| {
            let mut out = Vec::new();
            if (30..90).contains(&k) {
                if k >= 60 {
                    spoof.stream = RtpStream::new(7, 100u16.wrapping_add(k as u16), 5000 + k * 160);
                }
                out.push((addr(5999), spoof.packet()));
            }
            if k < 150 {
                out.push((addr(5000), caller.packet()));
            }
            out
        },
        &mut played,
    );
    assert_eq!(peer_addr(&core, 7), Some(addr(5000)));
    assert_eq!(decoded(&played, 7), 150);
    let stats = core.stats();
    assert_eq!((stats.foreign, stats.moved), (60, 0), "{stats:?}");
    let j = core.peers[&7].receiver.stats().jitter;
    assert_eq!((j.received, j.duplicates, j.lost), (150, 0, 0), "{j:?}");
}

#[test]
fn a_caller_whose_address_changes_is_followed() {
    // A NAT rebinding: the stream goes on from a new port, the old one falls quiet.
    let mut core = session(32);
    let mut played = HashMap::new();
    let mut caller = Caller::new(7, 65_500, 5000);
    drive(
        &mut core,
        0..140,
        |k| match k {
            0..60 => vec![(addr(5000), caller.packet())],
            60..120 => vec![(addr(5002), caller.packet())],
            _ => Vec::new(),
        },
        &mut played,
    );
    assert_eq!(peer_addr(&core, 7), Some(addr(5002)));
    assert_eq!(core.stats().moved, 1);
    // The packets that showed the move are not played: two frames concealed.
    assert_eq!(decoded(&played, 7), 120 - 2);
}

#[test]
fn a_redial_on_the_same_ssrc_after_bye_plays() {
    let mut core = session(32);
    let mut played = HashMap::new();
    let mut first = Caller::new(7, 100, 5000);
    let mut second = Caller::new(7, 40_000, 3_000_000);
    drive(
        &mut core,
        0..260,
        |k| match k {
            0..100 => vec![(addr(5000), first.packet())],
            100 => vec![(addr(5000), first.report(true))],
            130 => vec![(addr(5004), second.report(false))],
            131..231 => vec![(addr(5004), second.packet())],
            _ => Vec::new(),
        },
        &mut played,
    );
    assert_eq!(decoded(&played, 7), 200);
    let rx = &core;
    let peer = &rx.peers[&7];
    assert!(!peer.said_bye);
    assert_eq!(peer.addr, addr(5004));
    let j = peer.receiver.stats().jitter;
    assert_eq!((j.restarts, j.lost, j.late), (1, 0, 0), "{j:?}");
}

/// The socket thread in simulated time: the timers run at their deadlines and datagrams arrive
/// at the present, as the driver does with its socket and the clock; the owner pulls every
/// 20 ms. What the core sends goes nowhere.
struct Sim {
    core: SessionCore,
    now: Instant,
    /// What the timers did, and when (since the epoch).
    fired: Vec<(Duration, Due)>,
    /// What `pull` gave, by SSRC: (tick, frame).
    played: HashMap<u32, Vec<(u32, PlayedFrame)>>,
}

impl Sim {
    fn new(config: SessionConfig, draw: fn() -> u32) -> Self {
        let core = SessionCore::with_draw(config, LOCAL, Instant::now(), draw).unwrap();
        let mut sim = Self {
            now: core.epoch,
            core,
            fired: Vec::new(),
            played: HashMap::new(),
        };
        sim.sent();
        sim
    }

    /// A member of a relay room at a made-up address.
    fn in_room() -> Self {
        let mut config = quiet_config(8);
        config.room = Some("room".into());
        config.destinations = vec![addr(3478)];
        Self::new(config, middle)
    }

    /// What the core had to send, sent (nowhere).
    fn sent(&mut self) {
        while let Some(t) = self.core.poll_transmit() {
            self.core.transmitted(t, true);
        }
    }

    /// Runs the timers due until `at` (since the epoch), then makes it the present.
    fn advance_to(&mut self, at: Duration) {
        let epoch = self.core.epoch;
        let at = epoch + at;
        while self.core.poll_timeout() <= at {
            let deadline = self.core.poll_timeout();
            let due = self.core.run_timers(deadline);
            self.fired.push((deadline - epoch, due));
            self.sent();
        }
        self.now = self.now.max(at);
    }

    fn arrive(&mut self, from: SocketAddr, data: Vec<u8>) {
        self.core.handle_datagram(&data, from, self.now);
        self.sent();
    }

    /// 20 ms ticks: at each, the timers due run, `send(k)` gives the datagrams arriving and
    /// the owner pulls.
    fn run(
        &mut self,
        ticks: std::ops::Range<u32>,
        mut send: impl FnMut(u32) -> Vec<(SocketAddr, Vec<u8>)>,
    ) {
        let mut out = Vec::new();
        for k in ticks {
            self.advance_to(FRAME * k);
            for (from, data) in send(k) {
                self.arrive(from, data);
            }
            self.core.pull(self.now, &mut out);
            for PeerFrame { peer, frame } in out.drain(..) {
                self.played
                    .entry(peer.number())
                    .or_default()
                    .push((k, frame));
            }
        }
    }

    fn relay_says(&mut self, kind: ControlKind, cookie: Cookie) {
        let relay = self.core.config.destinations[0];
        let room = self.core.room.unwrap();
        self.arrive(relay, Control::new(kind, room, cookie).encode().to_vec());
    }

    /// When the timers did `what`.
    fn when(&self, what: fn(&Due) -> bool) -> Vec<Duration> {
        self.fired
            .iter()
            .filter(|(_, due)| what(due))
            .map(|&(at, _)| at)
            .collect()
    }

    fn peers(&self) -> Vec<u32> {
        self.core.peers().iter().map(|p| p.id.number()).collect()
    }
}

/// A session that sends no RTCP (it would go to the made-up peer addresses).
fn quiet_config(max_peers: usize) -> SessionConfig {
    let mut config = SessionConfig::new(LOCAL);
    config.max_peers = max_peers;
    config.ssrc = Some(1);
    config.send_rtcp = false;
    config
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

const NANO: Duration = Duration::from_nanos(1);

/// Draws for the reports' spread: the least, the middle and the most of the range.
fn least() -> u32 {
    0
}

fn middle() -> u32 {
    1 << 31
}

fn most() -> u32 {
    u32::MAX
}

/// `n` packets of `caller` from `from`, at ticks `first..first + n`.
fn talks(
    caller: &mut Caller,
    from: SocketAddr,
    first: u32,
    n: u32,
) -> impl FnMut(u32) -> Vec<(SocketAddr, Vec<u8>)> {
    move |k| match (first..first + n).contains(&k) {
        true => vec![(from, caller.packet())],
        false => Vec::new(),
    }
}

#[test]
fn reports_come_between_half_and_one_and_a_half_intervals_apart() {
    let mut config = quiet_config(8);
    config.send_rtcp = true;
    for (draw, gap) in [(least as fn() -> u32, ms(2500)), (most, ms(7500))] {
        let mut sim = Sim::new(config.clone(), draw);
        sim.advance_to(gap - NANO);
        assert!(sim.when(|d| d.report).is_empty());
        sim.advance_to(gap * 3);
        assert_eq!(sim.when(|d| d.report), [gap, gap * 2, gap * 3]);
    }
    // The system's draws spread them over the whole range, never outside it.
    let mut sim = Sim::new(config, system_draw);
    sim.advance_to(Duration::from_secs(1000));
    let at = sim.when(|d| d.report);
    let gaps: Vec<Duration> = at.windows(2).map(|w| w[1] - w[0]).collect();
    let spread = ms(2500)..=ms(7500);
    assert!(spread.contains(&at[0]), "{at:?}");
    assert!(gaps.iter().all(|g| spread.contains(g)), "{gaps:?}");
    assert!(gaps.iter().any(|&g| g < ms(3500)) && gaps.iter().any(|&g| g > ms(6500)));
}

#[test]
fn the_relay_join_is_retried_every_half_second_until_answered_then_kept_alive_every_5_s() {
    let keepalive = |d: &Due| d.keepalive;
    let mut unanswered = Sim::in_room();
    unanswered.advance_to(ms(4000));
    let half_seconds: Vec<Duration> = (1..=8).map(|i| ms(500 * i)).collect();
    assert_eq!(unanswered.when(keepalive), half_seconds);

    let cookie = Cookie([7; 16]);
    for answer in [ControlKind::Joined, ControlKind::Refused(Refusal::RoomFull)] {
        let mut sim = Sim::in_room();
        sim.advance_to(ms(1200));
        sim.relay_says(ControlKind::Challenge, cookie);
        sim.relay_says(answer, cookie);
        sim.advance_to(ms(12_000));
        // The retry set before the answer still goes; then only the keepalive.
        let at = [500, 1000, 1500, 6500, 11_500].map(ms);
        assert_eq!(sim.when(keepalive), at, "{answer:?}");
        let stats = sim.core.stats();
        assert_eq!(stats.relay_challenges, 1);
        assert_eq!(stats.relay_joined, answer == ControlKind::Joined);
    }
}

#[test]
fn a_confirmed_peer_is_forgotten_after_peer_timeout_of_silence_not_before() {
    let mut sim = Sim::new(quiet_config(8), middle);
    let mut caller = Caller::new(7, 100, 5000);
    // Its last packet arrives at 1 s, on the once-a-second expiry's grid.
    sim.run(41..51, talks(&mut caller, addr(5000), 41, 10));
    let timeout = sim.core.config.peer_timeout;
    sim.advance_to(ms(1000) + timeout - NANO);
    assert_eq!(sim.peers(), [7]);
    sim.advance_to(ms(1000) + timeout);
    assert!(sim.peers().is_empty());
    // Expiry ran once a second throughout.
    let seconds: Vec<Duration> = (1..=31).map(|i| EXPIRY_INTERVAL * i).collect();
    assert_eq!(sim.when(|d| d.expiry), seconds);
}

#[test]
fn an_unconfirmed_peer_is_forgotten_after_2_s_without_media() {
    let mut sim = Sim::new(quiet_config(8), middle);
    let mut once = Caller::new(7, 100, 5000);
    let mut confirmed = Caller::new(8, 200, 6000);
    let mut confirmed = talks(&mut confirmed, addr(6000), 46, CONFIRM_PACKETS as u32);
    sim.run(46..51, |k| {
        let mut out = confirmed(k);
        if k == 50 {
            out.push((addr(5000), once.packet()));
        }
        out
    });
    sim.advance_to(ms(1000) + UNCONFIRMED_TIMEOUT - NANO);
    assert_eq!(sim.peers(), [7, 8]);
    sim.advance_to(ms(1000) + UNCONFIRMED_TIMEOUT);
    assert_eq!(sim.peers(), [8]);
}

#[test]
fn names_and_starts_sent_before_any_media_expire_after_2_s() {
    let mut sim = Sim::new(quiet_config(8), middle);
    let mut caller = Caller::new(7, 100, 5000);
    sim.run(50..51, |_| {
        vec![
            (addr(5000), names_from(7, "Ann")),
            (addr(5000), caller.report(false)),
        ]
    });
    let pending = |sim: &Sim| (sim.core.pending_names.len(), sim.core.pending_starts.len());
    sim.advance_to(ms(1000) + UNCONFIRMED_TIMEOUT - NANO);
    assert_eq!(pending(&sim), (1, 1));
    sim.advance_to(ms(1000) + UNCONFIRMED_TIMEOUT);
    assert_eq!(pending(&sim), (0, 0));
    // Media after that makes a nameless peer.
    sim.run(150..151, talks(&mut caller, addr(5000), 150, 1));
    assert_eq!(sim.core.peers()[0].name, None);
}

#[test]
fn a_full_table_drops_the_unconfirmed_then_the_longest_silent_never_a_talker() {
    let mut sim = Sim::new(quiet_config(3), middle);
    let mut talker = Caller::new(1_000, 100, 5000);
    let mut early = Caller::new(2_000, 200, 6000);
    let mut later = Caller::new(3_000, 300, 7000);
    let newcomer = |ssrc: u32| Caller::new(ssrc, 0, 0).packet();
    let mut talker = talks(&mut talker, addr(5000), 0, 400);
    let mut early = talks(&mut early, addr(6000), 0, 10);
    let mut later = talks(&mut later, addr(7000), 40, 10);
    let mut step = |sim: &mut Sim, ticks: std::ops::Range<u32>, knock: Option<u32>| {
        let end = ticks.end - 1;
        sim.run(ticks, |k| {
            let mut out = [talker(k), early(k), later(k)].concat();
            if let Some(ssrc) = knock.filter(|_| k == end) {
                out.push((addr(9000), newcomer(ssrc)));
            }
            out
        });
        (sim.peers(), sim.core.stats())
    };
    // At 5.1 s the others have been silent for 4.9 and 4.1 s: no room.
    let (peers, stats) = step(&mut sim, 0..256, Some(4));
    assert_eq!(peers, [1_000, 2_000, 3_000]);
    assert_eq!((stats.too_many_peers, stats.evicted), (1, 0));
    // At 6.1 s both are idle: the one silent longest goes.
    let (peers, stats) = step(&mut sim, 256..306, Some(4));
    assert_eq!(peers, [4, 1_000, 3_000]);
    assert_eq!(stats.evicted, 1);
    // The unconfirmed newcomer goes before the idle one.
    let (peers, stats) = step(&mut sim, 306..311, Some(5));
    assert_eq!(peers, [5, 1_000, 3_000]);
    assert_eq!(stats.evicted, 2);
    // The talker played throughout.
    let talked = decoded_frames(&sim, 1_000);
    assert!(talked >= 300, "{talked}");
}

fn decoded_frames(sim: &Sim, ssrc: u32) -> usize {
    sim.played[&ssrc]
        .iter()
        .filter(|(_, f)| f.kind == FrameKind::Decoded)
        .count()
}

#[test]
fn a_peers_frames_come_out_of_pull_every_20_ms_in_order_with_a_loss_concealed() {
    let mut sim = Sim::new(quiet_config(8), middle);
    // PCMU: frame k is the constant sample of code k, so the order shows in the audio.
    let mut stream = RtpStream::new(7, 65_530, 5000);
    stream.set_payload(0, 160);
    sim.run(0..50, |k| {
        let mut packet = Vec::new();
        stream.packetize(&[k as u8; 160], 1, &mut packet).unwrap();
        match k {
            20 | 40.. => Vec::new(),
            _ => vec![(addr(5000), packet)],
        }
    });
    let played = &sim.played[&7];
    let first = played[0].0;
    assert!(first <= 3, "plays from tick {first}");
    for (i, (tick, frame)) in played.iter().take(40).enumerate() {
        assert_eq!(*tick, first + i as u32, "one frame a pull");
        if i == 20 {
            assert_eq!(frame.kind, FrameKind::Concealed);
        } else {
            assert_eq!(frame.kind, FrameKind::Decoded, "frame {i}");
            let sample = ulaw_to_linear(i as u8);
            assert!(frame.pcm.iter().all(|&s| s == sample), "frame {i}");
        }
    }
}

#[test]
fn a_peer_that_says_bye_plays_out_and_is_forgotten_after_peer_timeout() {
    let mut sim = Sim::new(quiet_config(8), middle);
    let mut caller = Caller::new(7, 100, 5000);
    sim.run(0..60, |k| match k {
        ..50 => vec![(addr(5000), caller.packet())],
        50 => vec![(addr(5000), caller.report(true))],
        _ => Vec::new(),
    });
    assert_eq!(decoded_frames(&sim, 7), 50);
    let peer = &sim.core.peers()[0];
    assert!(peer.said_bye && peer.ended, "{peer:?}");
    let timeout = sim.core.config.peer_timeout;
    sim.advance_to(ms(1000) + timeout - NANO);
    assert_eq!(sim.peers(), [7]);
    sim.advance_to(ms(1000) + timeout);
    assert!(sim.peers().is_empty());
}

#[test]
fn the_relay_is_asked_with_a_join_then_confirmed_with_its_cookie() {
    let relay = addr(3478);
    let mut config = quiet_config(8);
    config.room = Some("room".into());
    config.destinations = vec![relay];
    let mut core = SessionCore::new(config, LOCAL, Instant::now()).unwrap();
    let room = core.room.unwrap();
    let epoch = core.epoch;
    let sent = |core: &mut SessionCore| -> Vec<(SocketAddr, ControlKind, Cookie)> {
        let mut controls = Vec::new();
        while let Some(t) = core.poll_transmit() {
            assert_eq!(t.kind, TransmitKind::Control);
            let c = Control::decode(&t.data).unwrap();
            assert_eq!(c.room, room);
            controls.push((t.to, c.kind, c.cookie));
            core.transmitted(t, true);
        }
        controls
    };
    assert_eq!(sent(&mut core), [(relay, ControlKind::Join, Cookie::NONE)]);
    core.handle_timeout(epoch + ms(499));
    assert!(sent(&mut core).is_empty());
    core.handle_timeout(epoch + ms(500));
    assert_eq!(sent(&mut core), [(relay, ControlKind::Join, Cookie::NONE)]);
    let cookie = Cookie([9; 16]);
    let challenge = Control::new(ControlKind::Challenge, room, cookie).encode();
    core.handle_datagram(&challenge, addr(6666), epoch + ms(505));
    assert!(sent(&mut core).is_empty(), "a challenge not from the relay");
    core.handle_datagram(&challenge, relay, epoch + ms(510));
    assert_eq!(sent(&mut core), [(relay, ControlKind::Confirm, cookie)]);
    core.handle_timeout(epoch + ms(1000));
    assert_eq!(sent(&mut core), [(relay, ControlKind::Confirm, cookie)]);
    core.leave(epoch + ms(1200));
    assert_eq!(sent(&mut core), [(relay, ControlKind::Leave, cookie)]);
    assert_eq!(core.stats().relay_challenges, 1);
}

/// Waits up to 2 s for `done`.
fn eventually(mut done: impl FnMut() -> bool) -> bool {
    let until = Instant::now() + Duration::from_secs(2);
    while Instant::now() < until {
        if done() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    done()
}

#[test]
fn the_socket_thread_carries_media_between_two_sessions() {
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
    config.send_rtcp = false;
    let receiver = Session::start(config.clone()).unwrap();
    config.destinations = vec![receiver.local_addr().unwrap()];
    let sender = Session::start(config).unwrap();
    let mut caller = Caller::new(0, 0, 0);
    for _ in 0..10 {
        let packet = caller.packet();
        // The caller's payload, past its 12-byte RTP header.
        sender.send_frames(&packet[12..], 1).unwrap();
    }
    assert!(
        eventually(|| receiver.stats().rtp == 10),
        "{:?}",
        receiver.stats()
    );
    assert_eq!(sender.stats().sent_rtp, 10);
    let peers = receiver.peers();
    assert_eq!(peers.len(), 1);
    assert_eq!(peers[0].id, PeerId::Ssrc(sender.ssrc()));
    assert_eq!(peers[0].addr, sender.local_addr().unwrap());
    let mut frames = Vec::new();
    receiver.pull(Instant::now() + Duration::from_millis(100), &mut frames);
    assert_eq!(frames.len(), 1, "{frames:?}");
}

#[test]
fn the_socket_thread_counts_a_datagram_cut_short_as_malformed() {
    let session = Session::start(SessionConfig::new("127.0.0.1:0".parse().unwrap())).unwrap();
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut oversized = vec![0u8; LARGEST_DATAGRAM + 100];
    oversized[0] = 0x80;
    socket
        .send_to(&oversized, session.local_addr().unwrap())
        .unwrap();
    assert!(eventually(|| session.stats().datagrams == 1));
    let stats = session.stats();
    assert_eq!(
        (stats.malformed, stats.rtp, stats.bytes),
        (1, 0, 0),
        "{stats:?}"
    );
}

#[test]
fn the_socket_thread_joins_the_relay_and_retries_until_answered() {
    let relay = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    relay
        .set_read_timeout(Some(Duration::from_secs(2)))
        .unwrap();
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
    config.room = Some("room".into());
    config.destinations = vec![relay.local_addr().unwrap()];
    config.send_rtcp = false;
    let session = Session::start(config).unwrap();
    let mut buf = [0u8; 64];
    for _ in 0..2 {
        let (n, from) = relay.recv_from(&mut buf).unwrap();
        assert_eq!(from, session.local_addr().unwrap());
        let control = Control::decode(&buf[..n]).unwrap();
        assert_eq!(control.kind, ControlKind::Join);
    }
}

#[test]
fn a_pure_receivers_report_about_our_stream_says_someone_hears_us() {
    let (us, them) = (addr(5000), addr(6000));
    let mut listener = session(8);
    let mut config = SessionConfig::new(LOCAL);
    config.ssrc = Some(7);
    let mut caller = SessionCore::new(config, us, Instant::now()).unwrap();
    let mut voice = Caller::new(7, 100, 1000);
    let mut played = HashMap::new();
    drive(
        &mut listener,
        0..10,
        |_| vec![(us, voice.packet())],
        &mut played,
    );
    // A report naming someone else's stream says nothing about ours.
    caller.handle_datagram(&rtcp_from(9, None, false), them, caller.epoch);
    assert_eq!(caller.stats().reports_about_us, 0);
    listener.send_periodic_report(listener.epoch + FRAME * 10);
    let mut reports = 0;
    while let Some(t) = listener.poll_transmit() {
        assert_eq!(t.to, us, "a pure receiver reports back to its sender");
        caller.handle_datagram(&t.data, them, caller.epoch);
        reports += 1;
    }
    assert_eq!(reports, 1);
    assert_eq!(caller.stats().reports_about_us, 1);
}

/// A caller session (SSRC 7, at `us`) that calls `them`, heard by a listening session that
/// rings for its callers.
fn ringing_call(us: SocketAddr, them: SocketAddr) -> (SessionCore, SessionCore) {
    let mut listener = session(8);
    listener.config.rings_for_callers = true;
    let mut config = SessionConfig::new(LOCAL);
    config.ssrc = Some(7);
    config.destinations = vec![them];
    let caller = SessionCore::new(config, us, Instant::now()).unwrap();
    let mut voice = Caller::new(7, 100, 1000);
    drive(
        &mut listener,
        0..10,
        |_| vec![(us, voice.packet())],
        &mut HashMap::new(),
    );
    (listener, caller)
}

/// Hands what `listener` sends to `caller`, as if from `from`; how many went.
fn deliver(listener: &mut SessionCore, caller: &mut SessionCore, from: SocketAddr) -> usize {
    let mut sent = 0;
    while let Some(t) = listener.poll_transmit() {
        caller.handle_datagram(&t.data, from, caller.epoch);
        sent += 1;
    }
    sent
}

#[test]
fn a_listener_that_rings_tells_its_caller_until_the_answer() {
    let (us, them) = (addr(5000), addr(6000));
    let (mut listener, mut caller) = ringing_call(us, them);
    listener.send_periodic_report(listener.epoch + FRAME * 10);
    assert_eq!(deliver(&mut listener, &mut caller, them), 1);
    let s = caller.stats();
    assert_eq!((s.reports_about_us, s.ringing_reports), (1, 1), "{s:?}");
    // The same report from anywhere but where we call says nothing of our call.
    listener.send_periodic_report(listener.epoch + FRAME * 11);
    deliver(&mut listener, &mut caller, addr(6001));
    let s = caller.stats();
    assert_eq!((s.reports_about_us, s.ringing_reports), (2, 1), "{s:?}");
    let codec = listener.config.codec;
    listener.answer(&[us], codec);
    listener.send_periodic_report(listener.epoch + FRAME * 12);
    assert_eq!(deliver(&mut listener, &mut caller, them), 1);
    let s = caller.stats();
    assert_eq!(
        (s.reports_about_us, s.ringing_reports),
        (3, 1),
        "answered: {s:?}"
    );
    listener.hang_up_on(us, listener.epoch + FRAME * 13);
    deliver(&mut listener, &mut caller, them);
    assert_eq!(caller.stats().declined, 0, "hung up on after the answer");
}

#[test]
fn a_caller_hung_up_on_before_the_answer_hears_it_was_declined() {
    let (us, them) = (addr(5000), addr(6000));
    let (mut listener, mut caller) = ringing_call(us, them);
    listener.hang_up_on(us, listener.epoch + FRAME * 10);
    assert_eq!(deliver(&mut listener, &mut caller, them), 2, "BYE, twice");
    assert_eq!(caller.stats().declined, 2);
    // A listener that does not ring (`lipcall receive`) neither rings nor declines.
    let (mut listener, mut caller) = ringing_call(us, them);
    listener.config.rings_for_callers = false;
    listener.send_periodic_report(listener.epoch + FRAME * 10);
    listener.hang_up_on(us, listener.epoch + FRAME * 11);
    deliver(&mut listener, &mut caller, them);
    let s = caller.stats();
    assert_eq!(
        (s.reports_about_us, s.ringing_reports, s.declined),
        (1, 0, 0),
        "{s:?}"
    );
}

fn fixed_session(named: Named, key: Option<(MasterKey, MasterKey)>, ssrc: u32) -> SessionCore {
    let mut config = SessionConfig::new(LOCAL);
    config.ssrc = Some(ssrc);
    config.latch = Latch::Fixed(named);
    if let Some((ours, theirs)) = key {
        config.key = Some(ours);
        config.peer_key = Some(theirs);
    }
    SessionCore::new(config, LOCAL, Instant::now()).unwrap()
}

/// Where what the core queued went: (RTP, RTCP) destinations, each once.
fn sent_to(core: &mut SessionCore) -> (Vec<SocketAddr>, Vec<SocketAddr>) {
    let (mut rtp, mut rtcp) = (Vec::new(), Vec::new());
    while let Some(t) = core.poll_transmit() {
        let to = if t.kind == TransmitKind::Rtcp {
            &mut rtcp
        } else {
            &mut rtp
        };
        if !to.contains(&t.to) {
            to.push(t.to);
        }
    }
    (rtp, rtcp)
}

#[test]
fn a_fixed_call_takes_only_its_named_address_then_keeps_its_first_source_for_good() {
    let named = Named {
        rtp: addr(5000),
        rtcp: addr(5001),
        signalling: None,
    };
    let mut core = fixed_session(named, None, 1);
    let mut played = HashMap::new();
    let mut caller = Caller::new(7, 65_500, 5000);
    let mut stranger = Caller::new(9, 1, 0);
    // Before the peer's first packet: another port of its IP makes no peer, and ours go to
    // the named addresses.
    drive(
        &mut core,
        0..10,
        talks(&mut stranger, addr(6000), 0, 10),
        &mut played,
    );
    assert!(core.peers().is_empty());
    assert_eq!((core.stats().foreign, core.latched()), (10, None));
    core.send_packet(&[0; 20], 160, core.epoch).unwrap();
    assert_eq!(sent_to(&mut core), (vec![addr(5000)], vec![addr(5001)]));
    // The peer from the named address; then its stream goes on from another port while the
    // named one is quiet (what a Rebinding session follows): never taken.
    drive(
        &mut core,
        10..130,
        |k| match k {
            10..60 => vec![(addr(5000), caller.packet())],
            60..120 => vec![(addr(5002), caller.packet())],
            _ => Vec::new(),
        },
        &mut played,
    );
    assert_eq!(peer_addr(&core, 7), Some(addr(5000)));
    assert_eq!(decoded(&played, 7), 50);
    let stats = core.stats();
    assert_eq!((stats.foreign, stats.moved), (70, 0), "{stats:?}");
    assert_eq!(core.latched(), Some(addr(5000)));
    // Its RTCP is believed from the RTCP address it named (or its RTP's IP), not from
    // elsewhere.
    let at = core.epoch + FRAME * 130;
    let elsewhere: SocketAddr = "127.0.0.9:5001".parse().unwrap();
    core.handle_datagram(&names_from(7, "Mallory"), elsewhere, at);
    core.handle_datagram(&names_from(7, "Bob"), addr(5001), at);
    assert_eq!(core.peers()[0].name.as_deref(), Some("Bob"));
    assert_eq!(core.stats().foreign, 71);
    core.send_packet(&[0; 20], 160, at).unwrap();
    core.send_periodic_report(at);
    assert_eq!(sent_to(&mut core), (vec![addr(5000)], vec![addr(5001)]));
    // A re-INVITE naming another address opens the call to it, and only to it.
    core.rename_peer(Named {
        rtp: addr(5010),
        ..named
    });
    drive(
        &mut core,
        131..141,
        |_| {
            let packet = caller.packet();
            vec![(addr(5000), packet.clone()), (addr(5010), packet)]
        },
        &mut played,
    );
    assert_eq!(peer_addr(&core, 7), Some(addr(5010)));
    assert_eq!(core.stats().foreign, 81);
    core.send_packet(&[0; 20], 160, at).unwrap();
    assert_eq!(sent_to(&mut core).0, vec![addr(5010)]);

    // The same stream into a Rebinding session moves with it.
    let mut rebinding = session(32);
    let mut caller = Caller::new(7, 65_500, 5000);
    drive(
        &mut rebinding,
        0..120,
        |k| match k {
            0..50 => vec![(addr(5000), caller.packet())],
            _ => vec![(addr(5002), caller.packet())],
        },
        &mut HashMap::new(),
    );
    assert_eq!(peer_addr(&rebinding, 7), Some(addr(5002)));
    assert_eq!(rebinding.stats().moved, 1);
}

#[test]
fn a_fixed_call_takes_its_first_packet_from_the_signalling_ip_and_is_answered_there() {
    let nat: SocketAddr = "127.0.0.2:40000".parse().unwrap();
    let mut core = fixed_session(
        Named {
            rtp: addr(5000),
            rtcp: addr(5001),
            signalling: Some(nat.ip()),
        },
        None,
        1,
    );
    let mut caller = Caller::new(7, 100, 5000);
    let mut played = HashMap::new();
    drive(
        &mut core,
        0..20,
        talks(&mut caller, nat, 0, 20),
        &mut played,
    );
    let received = core.peers()[0].receiver.jitter.received;
    assert_eq!((core.latched(), received), (Some(nat), 20));
    // Now the named address is a stranger; the peer's RTCP comes from the NAT's next port.
    let at = core.epoch + FRAME * 20;
    core.handle_datagram(&caller.packet(), addr(5000), at);
    assert_eq!(core.stats().foreign, 1);
    let rtcp_from_nat: SocketAddr = "127.0.0.2:40001".parse().unwrap();
    core.handle_datagram(&names_from(7, "Bob"), rtcp_from_nat, at);
    assert_eq!(core.peers()[0].name.as_deref(), Some("Bob"));
    core.send_packet(&[0; 20], 160, at).unwrap();
    core.send_periodic_report(at);
    assert_eq!(sent_to(&mut core), (vec![nat], vec![rtcp_from_nat]));
}

#[test]
fn each_direction_has_its_own_srtp_key_and_a_keyed_fixed_call_latches_the_first_authentic_packet() {
    let (a_key, b_key) = (
        MasterKey::from_bytes(&[1; 30]).unwrap(),
        MasterKey::from_bytes(&[2; 30]).unwrap(),
    );
    let named = Named {
        rtp: addr(5000),
        rtcp: addr(5001),
        signalling: None,
    };
    let mut a = fixed_session(named, Some((a_key.clone(), b_key.clone())), 1);
    let mut b = fixed_session(named, Some((b_key.clone(), a_key.clone())), 2);
    // B reads what A sends under A's key; B's key both ways (one key a session) reads nothing.
    let mut one_key = fixed_session(named, Some((b_key.clone(), b_key)), 3);
    let mut speaker = Caller::new(7, 100, 0);
    let payload = |packet: Vec<u8>| rtp::parse(&packet, None).unwrap().payload.to_vec();
    let nat = addr(7000);
    for k in 0..10 {
        let now = a.epoch + FRAME * k;
        a.send_packet(&payload(speaker.packet()), 160, now).unwrap();
        while let Some(t) = a.poll_transmit() {
            if t.kind == TransmitKind::Rtp {
                b.handle_datagram(&t.data, nat, now);
                one_key.handle_datagram(&t.data, nat, now);
            }
        }
    }
    // Authenticated, A's first packet fixed B's source wherever it came from.
    assert_eq!((b.stats().rtp, b.stats().auth_failed), (10, 0));
    assert_eq!(b.latched(), Some(nat));
    assert_eq!(one_key.stats().auth_failed, 10);
    assert!(one_key.peers().is_empty());
    // Now plain or replayed packets from elsewhere are dropped before decryption.
    let mut plain = Caller::new(7, 200, 0);
    b.handle_datagram(&plain.packet(), addr(5000), b.epoch);
    assert_eq!((b.stats().foreign, b.stats().auth_failed), (1, 0));
}

/// What the core queued since the last look: (to, kind, whether an RTCP packet says BYE).
fn queued(core: &mut SessionCore) -> Vec<(SocketAddr, TransmitKind, bool)> {
    let mut out = Vec::new();
    while let Some(t) = core.poll_transmit() {
        let bye = t.kind == TransmitKind::Rtcp
            && rtcp::parse(&t.data).is_ok_and(|items| {
                items
                    .iter()
                    .any(|i| matches!(i, rtcp::RtcpItem::Bye { .. }))
            });
        out.push((t.to, t.kind, bye));
        core.transmitted(t, true);
    }
    out
}

#[test]
fn a_listening_session_answers_its_callers_in_their_codec_and_reports_to_each_once() {
    let mut core = session(8);
    let (bob, carol) = (addr(6001), addr(6002));
    let mut caller = Caller::new(7, 100, 0);
    for k in 0..10 {
        core.handle_datagram(&caller.packet(), bob, core.epoch + FRAME * k);
    }
    let now = core.epoch + FRAME * 10;
    core.send_packet(&[1, 2, 3], 160, now).unwrap();
    assert!(
        queued(&mut core)
            .iter()
            .all(|(_, kind, _)| *kind != TransmitKind::Rtp),
        "a listening session that answers nobody sends no media"
    );
    assert_eq!(core.answer(&[bob, carol], Codec::Pcmu), Codec::Pcmu);
    core.send_packet(&[0x55; 160], 160, now).unwrap();
    core.send_periodic_report(now);
    let sent = queued(&mut core);
    for to in [bob, carol] {
        let rtp = sent
            .iter()
            .filter(|(t, kind, _)| *t == to && *kind == TransmitKind::Rtp)
            .count();
        let rtcp = sent
            .iter()
            .filter(|(t, kind, _)| *t == to && *kind == TransmitKind::Rtcp)
            .count();
        assert_eq!((rtp, rtcp), (1, 1), "to {to}: {sent:?}");
    }
    let answers: Vec<SocketAddr> = (0..MAX_ANSWERED as u16 * 2)
        .map(|p| addr(7000 + p))
        .collect();
    core.answer(&answers, Codec::Pcmu);
    assert_eq!(core.answering().len(), MAX_ANSWERED, "capped");
    core.answer(&[], Codec::Pcmu);
    core.send_packet(&[0x55; 160], 160, now).unwrap();
    assert!(
        queued(&mut core)
            .iter()
            .all(|(_, kind, _)| *kind != TransmitKind::Rtp),
        "answering nobody again"
    );
}

#[test]
fn a_caller_hung_up_on_hears_bye_and_stays_out_while_it_keeps_sending() {
    let mut core = session(8);
    let (bob, carol) = (addr(6001), addr(6002));
    let mut bob_says = Caller::new(7, 100, 0);
    for k in 0..10 {
        core.handle_datagram(&bob_says.packet(), bob, core.epoch + FRAME * k);
    }
    core.answer(&[bob], Codec::Speex);
    let now = core.epoch + FRAME * 10;
    core.hang_up_on(bob, now);
    let sent = queued(&mut core);
    assert!(
        sent.iter().any(|&(to, _, bye)| to == bob && bye),
        "{sent:?}"
    );
    assert!(core.peers().is_empty() && core.answering().is_empty());
    // Bob goes on sending for 30 s: never a peer again.
    let mut played = HashMap::new();
    drive(
        &mut core,
        11..1500,
        |_| vec![(bob, bob_says.packet())],
        &mut played,
    );
    assert!(core.peers().is_empty(), "{:?}", core.peers());
    assert!(core.stats().blocked > 1000);
    // Carol may call meanwhile.
    let mut carol_says = Caller::new(9, 100, 0);
    drive(
        &mut core,
        1500..1510,
        |_| vec![(carol, carol_says.packet())],
        &mut played,
    );
    assert_eq!(core.peers().len(), 1);
    // Bob quiet for the block's quiet time, then heard again.
    let back = 1510 + (BLOCK_QUIET.as_millis() / 20) as u32 + 1;
    drive(
        &mut core,
        back..back + 10,
        |_| vec![(bob, bob_says.packet())],
        &mut played,
    );
    assert!(peer_addr(&core, 7) == Some(bob), "{:?}", core.peers());
}

/// A negotiated call (as SIP's SDP makes one): Speex (110) and events (101) agreed, its peer
/// named at 5000 (RTP) and 5001 (RTCP), keepalive after [`CALL_KEEPALIVE`].
fn negotiated_session(ssrc: u32) -> SessionCore {
    let mut config = SessionConfig::new(LOCAL);
    config.ssrc = Some(ssrc);
    config.latch = Latch::Fixed(Named {
        rtp: addr(5000),
        rtcp: addr(5001),
        signalling: None,
    });
    config.call = Some(negotiated_call(false));
    SessionCore::with_draw(config, LOCAL, Instant::now(), middle).unwrap()
}

fn negotiated_call(held: bool) -> NegotiatedCall {
    NegotiatedCall {
        audio_types: vec![110],
        events: Some(101),
        held,
        keepalive: Some(CALL_KEEPALIVE),
    }
}

/// The media the core queued: (to, payload type, empty) of each RTP datagram.
fn media_sent(core: &mut SessionCore) -> Vec<(SocketAddr, Option<u8>)> {
    std::iter::from_fn(|| core.poll_transmit())
        .filter(|t| t.kind == TransmitKind::Rtp)
        .map(|t| {
            let pt = rtp::parse(&t.data, None)
                .ok()
                .map(|p| p.header.payload_type);
            (t.to, pt)
        })
        .collect()
}

#[test]
fn a_negotiated_call_keeps_one_stream_and_a_second_takes_over_only_after_200_ms_of_silence() {
    let mut core = negotiated_session(1);
    let mut played = HashMap::new();
    let (mut first, mut second) = (Caller::new(7, 100, 0), Caller::new(8, 900, 70_000));
    // Both from the call's address: the second, interleaved while the first talks, is dropped.
    drive(
        &mut core,
        0..50,
        |k| {
            let mut arriving = vec![(addr(5000), first.packet())];
            if k >= 20 {
                arriving.push((addr(5000), second.packet()));
            }
            arriving
        },
        &mut played,
    );
    assert_eq!(core.stats().other_stream, 30);
    // All but the jitter buffer's few frames of delay.
    assert!(decoded(&played, 7) >= 45, "{}", decoded(&played, 7));
    assert_eq!(decoded(&played, 8), 0);
    // The first falls silent: within 200 ms the second is still dropped, then it takes over
    // and is the call's one peer.
    drive(
        &mut core,
        50..60,
        talks(&mut second, addr(5000), 50, 10),
        &mut played,
    );
    assert_eq!(core.stats().other_stream, 39);
    let peers: Vec<PeerId> = core.peers().iter().map(|p| p.id).collect();
    assert_eq!(peers, vec![PeerId::Ssrc(8)]);
    drive(
        &mut core,
        60..120,
        talks(&mut second, addr(5000), 60, 60),
        &mut played,
    );
    assert!(decoded(&played, 8) >= 50, "{:?}", decoded(&played, 8));
    assert_eq!(core.peers().len(), 1);
}

#[test]
fn a_negotiated_call_takes_only_its_agreed_types_counts_events_and_plays_its_own_echo() {
    let mut core = negotiated_session(1);
    let mut played = HashMap::new();
    let mut pcmu = RtpStream::new(7, 1, 0);
    pcmu.set_payload(0, 160);
    let mut event = Vec::new();
    RtpStream::new(7, 1, 0)
        .packetize_other(101, true, 0, &[1, 10, 0, 160], &mut event)
        .unwrap();
    drive(
        &mut core,
        0..10,
        |_| {
            let mut packet = Vec::new();
            pcmu.packetize(&[0xff; 160], 1, &mut packet).unwrap();
            vec![(addr(5000), packet), (addr(5000), event.clone())]
        },
        &mut played,
    );
    // PCMU is a codec lipcall reads, but not one this call agreed.
    let stats = core.stats();
    assert_eq!(
        (stats.unknown_payload, stats.events_in, stats.rtp),
        (10, 10, 0)
    );
    assert!(core.peers().is_empty() && core.latched().is_none());
    // Our own stream echoed back by the peer (SIPp's echo) is the call's stream, played.
    let mut echo = Caller::new(1, 100, 0);
    drive(
        &mut core,
        10..40,
        talks(&mut echo, addr(5000), 10, 30),
        &mut played,
    );
    assert_eq!(core.stats().own, 0);
    assert!(decoded(&played, 1) >= 25, "{}", decoded(&played, 1));
    // In a session of lipcall's own, the same is an echo, dropped.
    let mut own = session(8);
    let mut echo = Caller::new(1, 100, 0);
    drive(
        &mut own,
        0..10,
        talks(&mut echo, addr(5000), 0, 10),
        &mut played,
    );
    assert_eq!((own.stats().own, own.peers().len()), (10, 0));
}

#[test]
fn a_held_negotiated_call_sends_nothing_and_its_clock_moves_on() {
    let mut core = negotiated_session(1);
    let t0 = core.epoch;
    core.send_packet(&[0; 20], 160, t0).unwrap();
    assert_eq!(media_sent(&mut core), vec![(addr(5000), Some(110))]);
    let named = Named {
        rtp: addr(5000),
        rtcp: addr(5001),
        signalling: None,
    };
    core.renegotiate(
        named,
        negotiated_call(true),
        Codec::Speex,
        Default::default(),
    );
    for _ in 0..10 {
        core.send_packet(&[0; 20], 160, t0).unwrap();
    }
    assert!(media_sent(&mut core).is_empty());
    core.renegotiate(
        named,
        negotiated_call(false),
        Codec::Speex,
        Default::default(),
    );
    core.send_packet(&[0; 20], 160, t0).unwrap();
    let t = core.poll_transmit().unwrap();
    let header = rtp::parse(&t.data, None).unwrap().header;
    assert_eq!(
        header.timestamp.wrapping_sub(core.stream.first_timestamp()),
        11 * 160
    );
}

#[test]
fn a_negotiated_call_silent_for_15_s_sends_an_empty_datagram_to_its_rtp_address() {
    let mut core = negotiated_session(1);
    let t0 = core.epoch;
    let keepalives = |core: &mut SessionCore, secs: u64| {
        core.handle_timeout(t0 + Duration::from_secs(secs));
        std::iter::from_fn(|| core.poll_transmit())
            .filter(|t| t.kind == TransmitKind::Rtp && t.data.is_empty())
            .map(|t| t.to)
            .collect::<Vec<_>>()
    };
    for secs in 1..15 {
        assert!(keepalives(&mut core, secs).is_empty(), "at {secs} s");
    }
    assert_eq!(keepalives(&mut core, 15), vec![addr(5000)]);
    assert!(keepalives(&mut core, 16).is_empty());
    // Audio at 20 s: the next one is due 15 s after it.
    core.send_packet(&[0; 20], 160, t0 + Duration::from_secs(20))
        .unwrap();
    for secs in 21..35 {
        assert!(keepalives(&mut core, secs).is_empty(), "at {secs} s");
    }
    assert_eq!(keepalives(&mut core, 35).len(), 1);
    let stats = core.stats();
    assert_eq!(stats.keepalives, 2);
    // A keepalive that went out is no RTP packet sent.
    core.transmitted(
        Transmit {
            to: addr(5000),
            data: Vec::new(),
            kind: TransmitKind::Rtp,
        },
        true,
    );
    assert_eq!(core.stats().sent_rtp, 0);
    // None once the call said BYE.
    core.leave(t0 + Duration::from_secs(36));
    assert!(keepalives(&mut core, 60).is_empty());
}

#[test]
fn a_negotiated_calls_reports_go_to_its_rtcp_port_sr_by_rfc_3550s_rule_none_after_bye() {
    let mut core = negotiated_session(1);
    let t0 = core.epoch;
    let reports = |core: &mut SessionCore| {
        std::iter::from_fn(|| core.poll_transmit())
            .filter(|t| t.kind == TransmitKind::Rtcp)
            .map(|t| match &rtcp::parse(&t.data).unwrap()[0] {
                rtcp::RtcpItem::Report { sender, .. } => (t.to, sender.is_some()),
                other => panic!("{other:?}"),
            })
            .collect::<Vec<_>>()
    };
    core.send_packet(&[0; 20], 160, t0).unwrap();
    // The start SR, then reports each `rtcp_interval` (5 s, drawn in the middle).
    assert_eq!(reports(&mut core), vec![(addr(5001), true)]);
    let mut kinds = Vec::new();
    for secs in 1..=20 {
        core.handle_timeout(t0 + Duration::from_secs(secs));
        kinds.extend(reports(&mut core).into_iter().map(|(to, sr)| {
            assert_eq!(to, addr(5001));
            sr
        }));
    }
    // Sent before the first periodic one only: an SR while we sent since the report before
    // the last (RFC 3550 6.4: in the last two intervals), then receiver reports.
    assert_eq!(kinds, vec![true, true, false]);
    core.leave(t0 + Duration::from_secs(21));
    assert_eq!(
        reports(&mut core).len(),
        1,
        "BYE, once to a negotiated call's peer"
    );
    core.handle_timeout(t0 + Duration::from_secs(60));
    assert!(reports(&mut core).is_empty(), "nothing after BYE");
}

#[test]
fn a_digit_is_five_growing_event_packets_then_three_ends_on_one_timestamp() {
    let mut core = negotiated_session(1);
    let now = core.epoch;
    assert!(core.queue_digits("1#"));
    assert!(!core.queue_digits("x"));
    assert!(!session(8).queue_digits("1"), "no negotiated call");
    let mut packets = Vec::new();
    for _ in 0..13 {
        core.step_digits(now).unwrap();
        packets.extend(
            std::iter::from_fn(|| core.poll_transmit())
                .filter(|t| t.kind == TransmitKind::Rtp)
                .map(|t| t.data),
        );
    }
    assert_eq!(packets.len(), 8);
    let parsed: Vec<_> = packets
        .iter()
        .map(|p| rtp::parse(p, None).unwrap())
        .collect();
    assert!(parsed[0].header.marker && !parsed[1].header.marker);
    assert!(parsed.iter().all(|p| p.header.payload_type == 101));
    assert!(
        parsed
            .iter()
            .all(|p| p.header.timestamp == parsed[0].header.timestamp)
    );
    assert_eq!(parsed[0].payload, &[1, 10, 0, 160]);
    assert_eq!(parsed[7].payload, &[1, 128 | 10, 3, 32]);
    let seqs: Vec<u16> = parsed.iter().map(|p| p.header.sequence).collect();
    assert!(
        seqs.windows(2).all(|w| w[1] == w[0].wrapping_add(1)),
        "{seqs:?}"
    );
    assert!(!core.digits_sent());
    core.step_digits(now).unwrap();
    let data = core.poll_transmit().unwrap().data;
    let next = rtp::parse(&data, None).unwrap();
    assert_eq!(next.payload[0], 11, "then #");
    // No audio went out between them: # starts at a timestamp of its own.
    assert_eq!(
        next.header.timestamp,
        parsed[0].header.timestamp.wrapping_add(13 * 160)
    );
    assert_eq!(core.stats().sent_events, 9);
}
