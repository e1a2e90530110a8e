use super::*;
use crate::codec::any::{EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD};
use crate::codec::g711::ulaw_to_linear;
use crate::net::peer::FrameKind;
use crate::vocab::FRAME_SIZE;
use timers::EXPIRY_INTERVAL;

const FRAME: Duration = Duration::from_millis(20);

fn session(max_peers: usize) -> Shared {
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
    config.max_peers = max_peers;
    config.ssrc = Some(1);
    Shared::new(config).unwrap().0
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
        let (n, frames) = self
            .encoder
            .encode(&voice(self.frame), &mut out)
            .unwrap()
            .unwrap();
        self.frame += 1;
        let mut buf = Vec::new();
        self.stream.packetize(&out[..n], frames, &mut buf).unwrap();
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
        },
        &mut buf,
    )
    .unwrap();
    buf
}

/// Drives the session in simulated time: before each 20 ms tick `send(k)` gives the
/// datagrams arriving in it, then every peer is pulled. Returns what each SSRC played.
fn drive(
    shared: &Shared,
    ticks: std::ops::Range<u32>,
    mut send: impl FnMut(u32) -> Vec<(SocketAddr, Vec<u8>)>,
    played: &mut HashMap<u32, Vec<FrameKind>>,
) {
    for k in ticks {
        let now = shared.epoch + FRAME * k;
        for (from, mut data) in send(k) {
            shared.handle(&mut data, from, now);
        }
        let mut rx = lock(&shared.rx);
        for (&ssrc, peer) in rx.peers.iter_mut() {
            if let Some(f) = peer.receiver.pull(now) {
                played.entry(ssrc).or_default().push(f.kind);
            }
        }
        drop(rx);
        if k % 50 == 0 {
            shared.expire(now);
        }
    }
}

fn decoded(played: &HashMap<u32, Vec<FrameKind>>, ssrc: u32) -> usize {
    played.get(&ssrc).map_or(0, |v| {
        v.iter().filter(|&&k| k == FrameKind::Decoded).count()
    })
}

fn peer_addr(shared: &Shared, ssrc: u32) -> Option<SocketAddr> {
    lock(&shared.rx).peers.get(&ssrc).map(|p| p.addr)
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
            bye: false,
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
    let shared = session(8);
    let mut played = HashMap::new();
    let mut ann = Caller::new(7, 100, 5000);
    let mut bob = Caller::new(8, 200, 6000);
    drive(
        &shared,
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
    assert!(lock(&shared.rx).peers.is_empty());
    assert_eq!(lock(&shared.rx).pending_names.len(), PENDING_NAMES);
    // The pending names were full of junk after Ann's: hers was displaced; send it again.
    drive(
        &shared,
        1..2,
        |_| vec![(addr(5000), names_from(7, "Ann"))],
        &mut played,
    );
    drive(
        &shared,
        2..12,
        |_| vec![(addr(5000), ann.packet()), (addr(6000), bob.packet())],
        &mut played,
    );
    let rx = lock(&shared.rx);
    assert_eq!(rx.peers[&7].name.as_deref(), Some("Ann"));
    assert_eq!(rx.peers[&7].cname.as_deref(), Some("caller@host"));
    assert_eq!(rx.peers[&8].name, None);
}

#[test]
fn junk_rtcp_makes_no_peer_and_keeps_no_caller_out() {
    // 32 receiver reports of 8 bytes from 32 SSRCs used to fill the peer table for 30 s.
    let shared = session(32);
    let mut played = HashMap::new();
    drive(
        &shared,
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
    assert!(lock(&shared.rx).peers.is_empty());
    let mut caller = Caller::new(7, 100, 5000);
    drive(
        &shared,
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
    assert_eq!(shared.stats_now().too_many_peers, 0);
}

#[test]
fn junk_media_never_evicts_a_talking_caller_nor_blocks_a_new_one() {
    let shared = session(4);
    let mut played = HashMap::new();
    let mut a = Caller::new(7, 100, 5000);
    let mut b = Caller::new(8, 9000, 77);
    let mut junk = RtpStream::new(0, 0, 0);
    junk.set_payload(0, 160);
    drive(
        &shared,
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
    let stats = shared.stats_now();
    assert!(stats.evicted >= 90, "{stats:?}");
    assert_eq!(stats.too_many_peers, 0, "{stats:?}");
    // The junk ages out within seconds, the callers stay.
    let mut peers: Vec<u32> = lock(&shared.rx).peers.keys().copied().collect();
    peers.sort_unstable();
    assert_eq!(peers, [7, 8]);
}

#[test]
fn a_spoofed_bye_from_another_address_is_ignored() {
    let shared = session(32);
    let mut played = HashMap::new();
    let mut caller = Caller::new(7, 100, 5000);
    drive(
        &shared,
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
    let peers = lock(&shared.rx).peers.get(&7).map(|p| p.said_bye).unwrap();
    assert!(!peers);
    // The lone BYE, and the compound's report and BYE.
    assert_eq!(shared.stats_now().foreign, 3);
    // From the caller's own address it counts.
    drive(
        &shared,
        130..131,
        |_| vec![(addr(5000), caller.report(true))],
        &mut played,
    );
    assert!(lock(&shared.rx).peers[&7].said_bye);
}

#[test]
fn packets_from_another_port_do_not_hijack_a_caller() {
    let shared = session(32);
    let mut played = HashMap::new();
    let mut caller = Caller::new(7, 100, 5000);
    // Another port sends 60 packets with the caller's SSRC: first with its own sequence,
    // then copying the caller's next sequence number and timestamp.
    let mut spoof = Caller::new(7, 31_000, 1_000_000);
    drive(
        &shared,
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
    assert_eq!(peer_addr(&shared, 7), Some(addr(5000)));
    assert_eq!(decoded(&played, 7), 150);
    let stats = shared.stats_now();
    assert_eq!((stats.foreign, stats.moved), (60, 0), "{stats:?}");
    let j = lock(&shared.rx).peers[&7].receiver.stats().jitter;
    assert_eq!((j.received, j.duplicates, j.lost), (150, 0, 0), "{j:?}");
}

#[test]
fn a_caller_whose_address_changes_is_followed() {
    // A NAT rebinding: the stream goes on from a new port, the old one falls quiet.
    let shared = session(32);
    let mut played = HashMap::new();
    let mut caller = Caller::new(7, 65_500, 5000);
    drive(
        &shared,
        0..140,
        |k| match k {
            0..60 => vec![(addr(5000), caller.packet())],
            60..120 => vec![(addr(5002), caller.packet())],
            _ => Vec::new(),
        },
        &mut played,
    );
    assert_eq!(peer_addr(&shared, 7), Some(addr(5002)));
    assert_eq!(shared.stats_now().moved, 1);
    // The packets that showed the move are not played: two frames concealed.
    assert_eq!(decoded(&played, 7), 120 - 2);
}

#[test]
fn a_redial_on_the_same_ssrc_after_bye_plays() {
    let shared = session(32);
    let mut played = HashMap::new();
    let mut first = Caller::new(7, 100, 5000);
    let mut second = Caller::new(7, 40_000, 3_000_000);
    drive(
        &shared,
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
    let rx = lock(&shared.rx);
    let peer = &rx.peers[&7];
    assert!(!peer.said_bye);
    assert_eq!(peer.addr, addr(5004));
    let j = peer.receiver.stats().jitter;
    assert_eq!((j.restarts, j.lost, j.late), (1, 0, 0), "{j:?}");
}

/// The network thread in simulated time: the timers run at their deadlines and datagrams arrive
/// at the present, as `net_loop` does with its socket and the clock; the owner pulls every 20 ms.
/// The session has no thread.
struct Sim {
    session: Session,
    timers: Timers,
    now: Instant,
    /// What the timers did, and when (since the epoch).
    fired: Vec<(Duration, Due)>,
    /// What `pull` gave, by SSRC: (tick, frame).
    played: HashMap<u32, Vec<(u32, PlayedFrame)>>,
}

impl Sim {
    fn new(config: SessionConfig, draw: fn() -> u32) -> Self {
        Self::start(Shared::new(config).unwrap().0, draw)
    }

    /// Like [`Session::start`], without the thread.
    fn start(shared: Shared, draw: fn() -> u32) -> Self {
        if shared.config.room.is_some() {
            shared.request_place();
        }
        let now = shared.epoch;
        Self {
            timers: Timers::new(&shared.config, now, draw),
            session: Session {
                shared: Arc::new(shared),
                thread: None,
            },
            now,
            fired: Vec::new(),
            played: HashMap::new(),
        }
    }

    /// A member of a relay room whose "relay" is its own socket (what it sends there is never
    /// read).
    fn in_room() -> Self {
        let mut config = quiet_config(8);
        config.room = Some("room".into());
        let mut shared = Shared::new(config).unwrap().0;
        shared.config.destinations = vec![shared.socket.local_addr().unwrap()];
        Self::start(shared, middle)
    }

    fn shared(&self) -> &Shared {
        &self.session.shared
    }

    /// Runs the timers due until `at` (since the epoch), then makes it the present.
    fn advance_to(&mut self, at: Duration) {
        let at = self.shared().epoch + at;
        while self.timers.next_deadline() <= at {
            let deadline = self.timers.next_deadline();
            let due = self.session.shared.run_timers(&mut self.timers, deadline);
            self.fired.push((deadline - self.shared().epoch, due));
        }
        self.now = self.now.max(at);
    }

    fn arrive(&mut self, from: SocketAddr, mut data: Vec<u8>) {
        self.shared().handle(&mut data, from, self.now);
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
            self.session.pull(self.now, &mut out);
            for PeerFrame { ssrc, frame } in out.drain(..) {
                self.played.entry(ssrc).or_default().push((k, frame));
            }
        }
    }

    fn relay_says(&mut self, kind: ControlKind, cookie: Cookie) {
        let relay = self.shared().config.destinations[0];
        let room = self.shared().room.unwrap();
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
        self.session.peers().iter().map(|p| p.ssrc).collect()
    }
}

/// A session that sends no RTCP (it would go to the made-up peer addresses).
fn quiet_config(max_peers: usize) -> SessionConfig {
    let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
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
        let stats = sim.session.stats();
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
    let timeout = sim.shared().config.peer_timeout;
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
    let pending = |sim: &Sim| {
        let rx = lock(&sim.shared().rx);
        (rx.pending_names.len(), rx.pending_starts.len())
    };
    sim.advance_to(ms(1000) + UNCONFIRMED_TIMEOUT - NANO);
    assert_eq!(pending(&sim), (1, 1));
    sim.advance_to(ms(1000) + UNCONFIRMED_TIMEOUT);
    assert_eq!(pending(&sim), (0, 0));
    // Media after that makes a nameless peer.
    sim.run(150..151, talks(&mut caller, addr(5000), 150, 1));
    assert_eq!(sim.session.peers()[0].name, None);
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
        (sim.peers(), sim.session.stats())
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
    let peer = &sim.session.peers()[0];
    assert!(peer.said_bye && peer.ended, "{peer:?}");
    let timeout = sim.shared().config.peer_timeout;
    sim.advance_to(ms(1000) + timeout - NANO);
    assert_eq!(sim.peers(), [7]);
    sim.advance_to(ms(1000) + timeout);
    assert!(sim.peers().is_empty());
}
