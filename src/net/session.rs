//! A call session: one UDP socket read by its own thread (no async runtime), any number of
//! remote peers (each identified by SSRC, its address noted), RTCP reports, optional SRTP and
//! an optional relay room.
//!
//! The owner sends payloads of its codec with [`Session::send_frames`] (or
//! [`Session::send_packet`]) and pulls the mixed-down timeline with [`Session::pull`] once per
//! 20 ms of its output clock (a playback thread, or a timer in the headless receiver); decoding
//! happens in `pull`, on the caller's thread. Each peer may send another codec.
//!
//! Who may disturb a call (plain RTP has no authentication; SRTP is the real answer): a peer is
//! created only from media that a mapped codec can read, never from RTCP, and stays unconfirmed
//! (aged out within seconds, the first to make room) until it has sent a few packets. A peer
//! that is talking is never evicted for a newcomer. A peer is pinned to the address its media
//! came from: RTCP (BYE included) and RTP from elsewhere are ignored, unless the pinned address
//! has gone quiet and the other one continues its sequence (a NAT rebinding, a roaming
//! device), or the peer said BYE and a new stream comes (a redial).

use std::collections::HashMap;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::control::{Control, ControlError, ControlKind, Cookie, Refusal, RoomId};
use super::jitter::JitterConfig;
use super::peer::{PeerReceiver, PlayedFrame, ReceiverStats};
use super::rtcp::{self, Outgoing, ReportBlock, RtcpItem, SenderInfo};
use super::rtp::{self, Rtp, RtpStream};
use super::srtp::{DEFAULT_CLOCK_TOLERANCE, MasterKey, Srtp, SrtpError};
use super::{DatagramKind, MAX_DATAGRAM, NetError, classify};
use crate::codec::any::{Codec, PayloadMap};

mod timers;

use timers::{Due, Timers, system_draw};

#[derive(Debug, Clone)]
pub struct SessionConfig {
    pub bind: SocketAddr,
    /// Where media and reports go: peers of a mesh, or the relay.
    pub destinations: Vec<SocketAddr>,
    /// A relay room to join (the relay is `destinations[0]`).
    pub room: Option<String>,
    /// SRTP master key; `None` sends plain RTP.
    pub key: Option<MasterKey>,
    /// How far a new SRTP stream's sender clock may be from ours (per-session keys: a stream
    /// stamped further off is a replay of an earlier call, or a clock that is wrong).
    pub clock_tolerance: Duration,
    /// Display name sent as SDES NAME.
    pub name: Option<String>,
    pub jitter: JitterConfig,
    pub max_peers: usize,
    /// Peers silent for this long are forgotten.
    pub peer_timeout: Duration,
    /// Mean interval between RTCP reports (randomised by +-50 %).
    pub rtcp_interval: Duration,
    pub keepalive_interval: Duration,
    pub send_rtcp: bool,
    /// Perceptual enhancer in the decoders.
    pub enhancer: bool,
    /// Fixed SSRC (for interop set-ups that need it in advance); random when `None`.
    pub ssrc: Option<u32>,
    /// The codec this session sends.
    pub codec: Codec,
    /// Which codec each payload type carries, received and sent.
    pub payloads: PayloadMap,
}

impl SessionConfig {
    pub fn new(bind: SocketAddr) -> Self {
        Self {
            bind,
            destinations: Vec::new(),
            room: None,
            key: None,
            clock_tolerance: Duration::from_secs(u64::from(DEFAULT_CLOCK_TOLERANCE)),
            name: None,
            jitter: JitterConfig::default(),
            max_peers: 32,
            peer_timeout: Duration::from_secs(30),
            rtcp_interval: Duration::from_secs(5),
            keepalive_interval: Duration::from_secs(5),
            send_rtcp: true,
            enhancer: true,
            ssrc: None,
            codec: Codec::Speex,
            payloads: PayloadMap::default(),
        }
    }
}

/// Datagram counters of a session.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SessionStats {
    pub datagrams: u64,
    pub bytes: u64,
    pub rtp: u64,
    pub rtcp: u64,
    pub control: u64,
    /// Unparseable RTP/RTCP/control datagrams, and oversized ones (cut short by the socket,
    /// dropped unparsed).
    pub malformed: u64,
    /// Datagrams of no known kind.
    pub unknown: u64,
    /// RTP packets of a payload type no codec is mapped to (dropped, never decoded).
    pub unknown_payload: u64,
    /// SRTP/SRTCP packets that failed authentication.
    pub auth_failed: u64,
    pub replayed: u64,
    /// SRTP streams new to us stamped further from our clock than `clock_tolerance`: a replay
    /// of an earlier call, or a sender whose clock is off.
    pub stale: u64,
    /// Packets from new SSRCs beyond `max_peers`.
    pub too_many_peers: u64,
    /// Unconfirmed or idle peers removed to make room for a new one.
    pub evicted: u64,
    /// RTP or RTCP about a known peer from an address other than its own (ignored).
    pub foreign: u64,
    /// Peers that moved to a new address (their stream continued from it).
    pub moved: u64,
    /// Our own packets coming back (a relay or multicast echo).
    pub own: u64,
    pub sent_rtp: u64,
    pub sent_rtcp: u64,
    pub send_errors: u64,
    /// The relay confirmed our place in the room.
    pub relay_joined: bool,
    /// Why the relay last turned our join down (cleared when it confirms one).
    pub relay_refusal: Option<Refusal>,
    /// Cookies the relay sent us to confirm our address with.
    pub relay_challenges: u64,
    /// The relay speaks another protocol version (an outdated lipcall on one side).
    pub relay_outdated: bool,
}

/// What the session knows about one remote peer.
#[derive(Debug, Clone, PartialEq)]
pub struct PeerInfo {
    pub ssrc: u32,
    pub addr: SocketAddr,
    pub cname: Option<String>,
    pub name: Option<String>,
    pub receiver: ReceiverStats,
    /// Round trip from the peer's last report about us.
    pub rtt_ms: Option<f64>,
    /// Share of our packets the peer reported lost (last report, 0..1).
    pub their_loss: Option<f64>,
    pub said_bye: bool,
    pub ended: bool,
}

/// One peer's frame in a pull.
#[derive(Debug, Clone, PartialEq)]
pub struct PeerFrame {
    pub ssrc: u32,
    pub frame: PlayedFrame,
}

/// Packets a peer's media must have brought before it is confirmed.
const CONFIRM_PACKETS: u64 = 5;
/// An unconfirmed peer without media for this long is forgotten.
const UNCONFIRMED_TIMEOUT: Duration = Duration::from_secs(2);
/// A confirmed peer without media for this long may make room for a new one.
const IDLE_EVICT: Duration = Duration::from_secs(5);
/// Packets in sequence from a new address before a quiet peer moves there.
const MOVE_PACKETS: u32 = 3;
/// Start hints (SRs sent before a stream's first packet) kept for peers not yet created.
const PENDING_STARTS: usize = 8;
/// How soon an unanswered relay join is sent again.
const JOIN_RETRY: Duration = Duration::from_millis(500);
/// Names (SDES sent before a stream's first packet, as every sender's first RTCP is) kept for
/// peers not yet created: without them a caller stays nameless until its next report.
const PENDING_NAMES: usize = 8;

/// SDES of a source that is not a peer yet: (SSRC, where from, CNAME, NAME, when).
type PendingNames = (u32, SocketAddr, Option<String>, Option<String>, Instant);

struct Peer {
    receiver: PeerReceiver,
    /// Where its media comes from: RTCP and RTP from elsewhere are ignored.
    addr: SocketAddr,
    cname: Option<String>,
    name: Option<String>,
    last_heard: Instant,
    /// The last media packet from `addr`.
    last_media: Instant,
    /// Media packets filed.
    media: u64,
    /// Another address continuing this peer's sequence: (address, its next sequence number,
    /// packets so far).
    candidate: Option<(SocketAddr, u16, u32)>,
    last_sr: Option<(u32, Instant)>,
    rtt_ms: Option<f64>,
    their_loss: Option<f64>,
    said_bye: bool,
}

impl Peer {
    fn confirmed(&self) -> bool {
        self.media >= CONFIRM_PACKETS
    }

    /// Whether a packet from `from`, not the pinned address, shows the peer has moved there:
    /// its pinned address is quiet and `from` sent `MOVE_PACKETS` in a row continuing the
    /// peer's sequence. Packets from the pinned address cancel a candidate.
    fn moved_to(&mut self, from: SocketAddr, seq: u16) -> bool {
        let count = match self.candidate {
            Some((addr, next, count)) if addr == from && next == seq => count + 1,
            _ => {
                let continues = self
                    .receiver
                    .highest_sequence()
                    .is_some_and(|h| (1..=16).contains(&seq.wrapping_sub(h)));
                if !continues {
                    return false;
                }
                1
            }
        };
        self.candidate = Some((from, seq.wrapping_add(1), count));
        count >= MOVE_PACKETS
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ReportKind {
    /// Before the first packet: an SR with no packets marks where the stream starts.
    Start,
    Periodic,
    /// The last word: SR (marking where the stream ends) + SDES + BYE.
    Bye,
}

struct Tx {
    stream: RtpStream,
    srtp: Option<Srtp>,
    buf: Vec<u8>,
    sent_since_report: bool,
    started: bool,
    left: bool,
}

struct Rx {
    peers: HashMap<u32, Peer>,
    srtp: Option<Srtp>,
    stats: SessionStats,
    /// SRs with no packets sent yet (where a stream will start), by SSRC, from senders not yet
    /// peers: (ssrc, RTP timestamp, from, arrival).
    pending_starts: Vec<(u32, u32, SocketAddr, Instant)>,
    pending_names: Vec<PendingNames>,
    relay: RelayLink,
}

/// Our side of the relay's join handshake (see [`super::control`]).
#[derive(Default)]
struct RelayLink {
    /// The relay's cookie for our address: echoed to join, in keepalives and in the leave.
    cookie: Option<Cookie>,
    /// A join or keepalive is unanswered: a challenge now is the relay's answer to it, not
    /// one provoked by someone else's forged join in our name.
    awaiting: bool,
}

struct Shared {
    config: SessionConfig,
    /// The relay room's id, when the session joins one.
    room: Option<RoomId>,
    socket: UdpSocket,
    epoch: Instant,
    ssrc: u32,
    cname: String,
    tx: Mutex<Tx>,
    rx: Mutex<Rx>,
    stop: AtomicBool,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding a lock leaves data that is still consistent enough for counters
    // and buffers; keep serving rather than cascading the panic.
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

pub struct Session {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for Session {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Session")
            .field("ssrc", &self.shared.ssrc)
            .finish_non_exhaustive()
    }
}

impl Session {
    pub fn start(config: SessionConfig) -> Result<Self, NetError> {
        let (shared, reader) = Shared::new(config)?;
        let shared = Arc::new(shared);
        if shared.config.room.is_some() {
            shared.request_place();
        }
        let thread_shared = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("lipcall-net".into())
            .spawn(move || net_loop(&thread_shared, &reader))
            .map_err(|e| NetError::io("cannot start the network thread", e))?;
        Ok(Self {
            shared,
            thread: Some(thread),
        })
    }

    pub fn local_addr(&self) -> Result<SocketAddr, NetError> {
        self.shared
            .socket
            .local_addr()
            .map_err(|e| NetError::io("local address", e))
    }

    pub fn ssrc(&self) -> u32 {
        self.shared.ssrc
    }

    /// The instant the session's jitter buffers measure time from.
    pub fn epoch(&self) -> Instant {
        self.shared.epoch
    }

    pub fn encrypted(&self) -> bool {
        self.shared.config.key.is_some()
    }

    /// The codec this session sends.
    pub fn codec(&self) -> Codec {
        self.shared.config.codec
    }

    /// Sends one payload of the session's codec holding `frames` 20 ms frames to every
    /// destination.
    pub fn send_frames(&self, payload: &[u8], frames: u32) -> Result<(), NetError> {
        let ticks = self.shared.config.codec.frame_ticks() * frames.max(1);
        self.send_packet(payload, ticks)
    }

    /// Sends one payload of the session's codec lasting `ticks` of its RTP clock (an Opus
    /// packet of 60 ms: 2880) to every destination.
    pub fn send_packet(&self, payload: &[u8], ticks: u32) -> Result<(), NetError> {
        let first = !lock(&self.shared.tx).started;
        if first && self.shared.config.send_rtcp {
            // Tells receivers where the stream starts, in case its first packet is lost.
            self.shared.send_report(ReportKind::Start);
        }
        let mut tx = lock(&self.shared.tx);
        tx.started = true;
        let Tx {
            stream, srtp, buf, ..
        } = &mut *tx;
        stream.packetize_ticks(payload, ticks, buf)?;
        if let Some(srtp) = srtp {
            srtp.protect_rtp(buf)?;
        }
        tx.sent_since_report = true;
        let sent = self.shared.send_all(&tx.buf);
        drop(tx);
        let mut rx = lock(&self.shared.rx);
        rx.stats.sent_rtp += sent.0;
        rx.stats.send_errors += sent.1;
        Ok(())
    }

    /// Frames not sent (silence, mute): the timestamp moves on and the next packet starts a
    /// new talk spurt.
    pub fn skip_frames(&self, frames: u32) {
        lock(&self.shared.tx).stream.skip(frames);
    }

    /// Pulls the next 20 ms (starting at `now` on the output clock) from every peer that is
    /// playing, appending to `out`.
    pub fn pull(&self, now: Instant, out: &mut Vec<PeerFrame>) {
        let mut rx = lock(&self.shared.rx);
        for (&ssrc, peer) in rx.peers.iter_mut() {
            if let Some(frame) = peer.receiver.pull(now) {
                out.push(PeerFrame { ssrc, frame });
            }
        }
    }

    pub fn stats(&self) -> SessionStats {
        lock(&self.shared.rx).stats
    }

    pub fn peers(&self) -> Vec<PeerInfo> {
        let rx = lock(&self.shared.rx);
        let mut peers: Vec<PeerInfo> = rx
            .peers
            .iter()
            .map(|(&ssrc, p)| PeerInfo {
                ssrc,
                addr: p.addr,
                cname: p.cname.clone(),
                name: p.name.clone(),
                receiver: p.receiver.stats(),
                rtt_ms: p.rtt_ms,
                their_loss: p.their_loss,
                said_bye: p.said_bye,
                ended: p.said_bye && p.receiver.stats().jitter.buffered_frames == 0,
            })
            .collect();
        peers.sort_by_key(|p| p.ssrc);
        peers
    }

    /// Sends a report now (normally the network thread does so every `rtcp_interval`).
    pub fn send_report(&self) {
        self.shared.send_report(ReportKind::Periodic);
    }

    /// Says BYE (with a final SR marking where the stream ends) and leaves the relay room.
    pub fn leave(&self) {
        let mut tx = lock(&self.shared.tx);
        if tx.left {
            return;
        }
        tx.left = true;
        drop(tx);
        if self.shared.config.send_rtcp {
            // Twice: a lost BYE would leave receivers concealing until their timeout.
            self.shared.send_report(ReportKind::Bye);
            self.shared.send_report(ReportKind::Bye);
        }
        if self.shared.config.room.is_some() {
            self.shared.leave_room();
        }
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        self.leave();
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Shared {
    #[cfg(test)]
    fn stats_now(&self) -> SessionStats {
        lock(&self.rx).stats
    }

    /// The session's state and socket, and a second handle on the socket to read it with.
    fn new(config: SessionConfig) -> Result<(Self, UdpSocket), NetError> {
        let socket = UdpSocket::bind(config.bind)
            .map_err(|e| NetError::io(format!("cannot listen on {}", config.bind), e))?;
        socket
            .set_read_timeout(Some(Duration::from_millis(10)))
            .map_err(|e| NetError::io("socket timeout", e))?;
        let reader = socket
            .try_clone()
            .map_err(|e| NetError::io("socket clone", e))?;
        let mut stream = RtpStream::new_random()?;
        if let Some(ssrc) = config.ssrc {
            stream.ssrc = ssrc;
        }
        let payload_type = config
            .payloads
            .payload_type(config.codec)
            .ok_or(NetError::NoPayloadType(config.codec))?;
        stream.set_payload(payload_type, config.codec.frame_ticks());
        let ssrc = stream.ssrc;
        let local = socket
            .local_addr()
            .map_err(|e| NetError::io("local address", e))?;
        let shared = Shared {
            cname: format!("lipcall-{ssrc:08x}@{local}"),
            ssrc,
            epoch: Instant::now(),
            tx: Mutex::new(Tx {
                stream,
                srtp: srtp(config.key.as_ref(), config.clock_tolerance)?,
                buf: Vec::with_capacity(MAX_DATAGRAM),
                sent_since_report: false,
                started: false,
                left: false,
            }),
            rx: Mutex::new(Rx {
                peers: HashMap::new(),
                srtp: srtp(config.key.as_ref(), config.clock_tolerance)?,
                stats: SessionStats::default(),
                pending_starts: Vec::with_capacity(PENDING_STARTS),
                pending_names: Vec::with_capacity(PENDING_NAMES),
                relay: RelayLink::default(),
            }),
            room: config.room.as_deref().map(RoomId::from_name),
            stop: AtomicBool::new(false),
            socket,
            config,
        };
        Ok((shared, reader))
    }

    /// Sends to every destination; returns (sent, failed).
    fn send_all(&self, datagram: &[u8]) -> (u64, u64) {
        let mut counts = (0, 0);
        for dest in &self.config.destinations {
            match self.socket.send_to(datagram, dest) {
                Ok(_) => counts.0 += 1,
                Err(_) => counts.1 += 1,
            }
        }
        counts
    }

    fn send_to_relay(&self, control: Control) {
        if let Some(relay) = self.config.destinations.first() {
            let _ = self.socket.send_to(&control.encode(), relay);
        }
    }

    /// Asks the relay for our place in the room: a join, or (with its cookie) the confirm that
    /// is also the keepalive.
    fn request_place(&self) {
        let Some(room) = self.room else { return };
        let mut rx = lock(&self.rx);
        rx.relay.awaiting = true;
        let request = match rx.relay.cookie {
            Some(cookie) => Control::new(ControlKind::Confirm, room, cookie),
            None => Control::new(ControlKind::Join, room, Cookie::NONE),
        };
        drop(rx);
        self.send_to_relay(request);
    }

    fn leave_room(&self) {
        let Some(room) = self.room else { return };
        let cookie = lock(&self.rx).relay.cookie;
        if let Some(cookie) = cookie {
            self.send_to_relay(Control::new(ControlKind::Leave, room, cookie));
        }
    }

    /// The relay's answers; anything else (not from the relay, another room, a cookie that is
    /// not ours) is ignored.
    fn handle_control(&self, rx: &mut Rx, data: &[u8], from: SocketAddr) {
        let from_relay = self.room.is_some() && self.config.destinations.first() == Some(&from);
        let control = match Control::decode(data) {
            Ok(control) if from_relay && Some(control.room) == self.room => control,
            Ok(_) => {
                rx.stats.unknown += 1;
                return;
            }
            Err(ControlError::Version(_)) if from_relay => {
                rx.stats.relay_outdated = true;
                rx.stats.malformed += 1;
                return;
            }
            Err(_) => {
                rx.stats.malformed += 1;
                return;
            }
        };
        let ours = rx.relay.cookie.is_some_and(|c| c.matches(&control.cookie));
        match control.kind {
            ControlKind::Challenge if rx.relay.awaiting => {
                rx.stats.relay_challenges += 1;
                rx.relay.cookie = Some(control.cookie);
                self.send_to_relay(Control::new(
                    ControlKind::Confirm,
                    control.room,
                    control.cookie,
                ));
            }
            ControlKind::Joined if ours => {
                rx.relay.awaiting = false;
                rx.stats.relay_joined = true;
                rx.stats.relay_refusal = None;
            }
            ControlKind::Refused(why) if ours => {
                rx.relay.awaiting = false;
                rx.stats.relay_refusal = Some(why);
            }
            _ => rx.stats.unknown += 1,
        }
    }

    fn send_report(&self, kind: ReportKind) {
        let now = Instant::now();
        let ntp = rtcp::ntp_now();
        let (blocks, peer_addrs) = {
            let mut rx = lock(&self.rx);
            let mut blocks = Vec::new();
            let mut addrs = Vec::new();
            for (&ssrc, peer) in rx.peers.iter_mut() {
                addrs.push(peer.addr);
                let Some((fraction, lost, highest, jitter)) = peer.receiver.jitter().report()
                else {
                    continue;
                };
                let (last_sr, delay) = match peer.last_sr {
                    Some((middle, at)) => (
                        middle,
                        (now.saturating_duration_since(at).as_secs_f64() * 65536.0) as u32,
                    ),
                    None => (0, 0),
                };
                blocks.push(ReportBlock {
                    ssrc,
                    fraction_lost: fraction,
                    cumulative_lost: lost,
                    highest_sequence: highest,
                    jitter,
                    last_sr,
                    delay_since_last_sr: delay,
                });
            }
            (blocks, addrs)
        };
        let mut tx = lock(&self.tx);
        let info = SenderInfo {
            ntp,
            rtp_timestamp: tx.stream.next_timestamp(),
            packets: tx.stream.packets_sent,
            octets: tx.stream.octets_sent,
        };
        let sender = match kind {
            ReportKind::Start => Some(info),
            ReportKind::Bye => tx.started.then_some(info),
            ReportKind::Periodic => tx.sent_since_report.then_some(info),
        };
        tx.sent_since_report = false;
        let mut buf = Vec::with_capacity(256);
        let built = rtcp::build(
            &Outgoing {
                ssrc: self.ssrc,
                sender,
                blocks: &blocks,
                cname: &self.cname,
                name: self.config.name.as_deref(),
                bye: kind == ReportKind::Bye,
            },
            &mut buf,
        );
        if built.is_err() {
            return;
        }
        if let Some(srtp) = tx.srtp.as_mut()
            && srtp.protect_rtcp(&mut buf).is_err()
        {
            return;
        }
        drop(tx);
        let mut sent = self.send_all(&buf);
        if self.config.destinations.is_empty() {
            // A pure receiver reports back to where its peers send from.
            let mut done: Vec<SocketAddr> = Vec::new();
            for addr in peer_addrs {
                if !done.contains(&addr) {
                    done.push(addr);
                    match self.socket.send_to(&buf, addr) {
                        Ok(_) => sent.0 += 1,
                        Err(_) => sent.1 += 1,
                    }
                }
            }
        }
        let mut rx = lock(&self.rx);
        rx.stats.sent_rtcp += sent.0;
        rx.stats.send_errors += sent.1;
    }

    fn handle(&self, data: &mut Vec<u8>, from: SocketAddr, arrival: Instant) {
        let mut rx = lock(&self.rx);
        rx.stats.datagrams += 1;
        rx.stats.bytes += data.len() as u64;
        match classify(data) {
            DatagramKind::Control => {
                rx.stats.control += 1;
                self.handle_control(&mut rx, data, from);
            }
            DatagramKind::Rtcp => {
                rx.stats.rtcp += 1;
                self.handle_rtcp(&mut rx, data, from, arrival);
            }
            DatagramKind::Rtp => self.handle_rtp(&mut rx, data, from, arrival),
            DatagramKind::Unknown => rx.stats.unknown += 1,
        }
    }

    fn unprotect(
        rx: &mut Rx,
        data: &mut Vec<u8>,
        f: fn(&mut Srtp, &mut Vec<u8>) -> Result<(), SrtpError>,
    ) -> bool {
        let Some(srtp) = rx.srtp.as_mut() else {
            return true;
        };
        match f(srtp, data) {
            Ok(()) => true,
            Err(SrtpError::Replay) => {
                rx.stats.replayed += 1;
                false
            }
            Err(SrtpError::Stale) => {
                rx.stats.stale += 1;
                false
            }
            Err(SrtpError::AuthFailed) => {
                rx.stats.auth_failed += 1;
                false
            }
            Err(_) => {
                rx.stats.malformed += 1;
                false
            }
        }
    }

    /// Makes room for a new peer: the oldest unconfirmed one goes, else one that has sent no
    /// media for `IDLE_EVICT`; a talking peer never does. False if there is no room.
    fn make_room(&self, rx: &mut Rx, now: Instant) -> bool {
        if rx.peers.len() < self.config.max_peers {
            return true;
        }
        let victim = rx
            .peers
            .iter()
            .filter(|(_, p)| {
                !p.confirmed() || now.saturating_duration_since(p.last_media) >= IDLE_EVICT
            })
            .min_by_key(|(_, p)| (p.confirmed(), p.last_media))
            .map(|(&ssrc, _)| ssrc);
        let Some(ssrc) = victim else {
            rx.stats.too_many_peers += 1;
            return false;
        };
        rx.peers.remove(&ssrc);
        rx.stats.evicted += 1;
        true
    }

    /// A new peer from its first media packet, if it is media a mapped codec can read.
    fn new_peer(&self, rx: &mut Rx, packet: &Rtp<'_>, from: SocketAddr, arrival: Instant) -> bool {
        let readable = self
            .config
            .payloads
            .codec(packet.header.payload_type)
            .is_some_and(|c| c.payload_duration(packet.payload).is_some());
        if !readable {
            rx.stats.unknown_payload += 1;
            return false;
        }
        if !self.make_room(rx, arrival) {
            return false;
        }
        let ssrc = packet.header.ssrc;
        let mut receiver = PeerReceiver::with_payloads(
            self.config.jitter,
            self.epoch,
            self.config.enhancer,
            self.config.payloads.clone(),
        );
        if let Some(i) = rx
            .pending_starts
            .iter()
            .position(|&(s, _, addr, _)| s == ssrc && addr == from)
        {
            let (_, ts, _, _) = rx.pending_starts.swap_remove(i);
            receiver.jitter().hint_start(ts);
        }
        let (cname, name) = match rx
            .pending_names
            .iter()
            .position(|(s, addr, ..)| *s == ssrc && *addr == from)
        {
            Some(i) => {
                let (_, _, cname, name, _) = rx.pending_names.swap_remove(i);
                (cname, name)
            }
            None => (None, None),
        };
        rx.peers.insert(
            ssrc,
            Peer {
                receiver,
                addr: from,
                cname,
                name,
                last_heard: arrival,
                last_media: arrival,
                media: 0,
                candidate: None,
                last_sr: None,
                rtt_ms: None,
                their_loss: None,
                said_bye: false,
            },
        );
        true
    }

    fn handle_rtp(&self, rx: &mut Rx, data: &mut Vec<u8>, from: SocketAddr, arrival: Instant) {
        if !Self::unprotect(rx, data, Srtp::unprotect_rtp) {
            return;
        }
        let packet = match rtp::parse(data, None) {
            Ok(p) => p,
            Err(_) => {
                rx.stats.malformed += 1;
                return;
            }
        };
        let ssrc = packet.header.ssrc;
        if ssrc == self.ssrc {
            rx.stats.own += 1;
            return;
        }
        rx.stats.rtp += 1;
        if !rx.peers.contains_key(&ssrc) && !self.new_peer(rx, &packet, from, arrival) {
            return;
        }
        let Some(peer) = rx.peers.get_mut(&ssrc) else {
            return;
        };
        if peer.addr == from {
            peer.candidate = None;
        } else if peer.said_bye {
            // A redial may come from anywhere; a straggler of the old stream changes nothing.
            peer.addr = from;
            peer.candidate = None;
        } else if peer.moved_to(from, packet.header.sequence) {
            peer.addr = from;
            peer.candidate = None;
            rx.stats.moved += 1;
        } else {
            rx.stats.foreign += 1;
            return;
        }
        peer.last_heard = arrival;
        peer.last_media = arrival;
        peer.media += 1;
        let restarts = peer.receiver.restarts();
        if !peer.receiver.insert(&packet, arrival) {
            rx.stats.unknown_payload += 1;
        }
        if peer.receiver.restarts() != restarts {
            peer.said_bye = false;
        }
    }

    fn handle_rtcp(&self, rx: &mut Rx, data: &mut Vec<u8>, from: SocketAddr, arrival: Instant) {
        if !Self::unprotect(rx, data, Srtp::unprotect_rtcp) {
            return;
        }
        let items = match rtcp::parse(data) {
            Ok(items) => items,
            Err(_) => {
                rx.stats.malformed += 1;
                return;
            }
        };
        let arrival_ntp = rtcp::ntp_now();
        let mut end_ts: HashMap<u32, u32> = HashMap::new();
        for item in items {
            match item {
                RtcpItem::Report {
                    reporter,
                    sender,
                    blocks,
                } => {
                    if reporter == self.ssrc {
                        rx.stats.own += 1;
                        continue;
                    }
                    let Some(peer) = rx.peers.get_mut(&reporter) else {
                        // Not a peer (until its media comes): only where its stream will start
                        // is worth keeping, a few at most.
                        if let Some(info) = sender.filter(|i| i.packets == 0) {
                            if rx.pending_starts.len() == PENDING_STARTS {
                                rx.pending_starts.remove(0);
                            }
                            rx.pending_starts
                                .push((reporter, info.rtp_timestamp, from, arrival));
                        }
                        continue;
                    };
                    if peer.addr != from {
                        rx.stats.foreign += 1;
                        continue;
                    }
                    peer.last_heard = arrival;
                    if let Some(info) = sender {
                        peer.last_sr = Some((rtcp::ntp_middle(info.ntp), arrival));
                        end_ts.insert(reporter, info.rtp_timestamp);
                        if info.packets == 0 {
                            peer.receiver.jitter().hint_start(info.rtp_timestamp);
                        }
                    }
                    if let Some(about_us) = blocks.iter().find(|b| b.ssrc == self.ssrc) {
                        peer.rtt_ms = rtcp::round_trip(about_us, arrival_ntp).map(|s| s * 1000.0);
                        peer.their_loss = Some(f64::from(about_us.fraction_lost) / 256.0);
                    }
                }
                RtcpItem::Names { ssrc, cname, name } => {
                    if ssrc == self.ssrc {
                        continue;
                    }
                    match rx.peers.get_mut(&ssrc) {
                        Some(peer) if peer.addr == from => {
                            if cname.is_some() {
                                peer.cname = cname;
                            }
                            if name.is_some() {
                                peer.name = name;
                            }
                        }
                        Some(_) => {}
                        None => {
                            // Kept until its media comes, a few at most; junk only displaces
                            // other pending names.
                            rx.pending_names
                                .retain(|(s, addr, ..)| (*s, *addr) != (ssrc, from));
                            if rx.pending_names.len() == PENDING_NAMES {
                                rx.pending_names.remove(0);
                            }
                            rx.pending_names.push((ssrc, from, cname, name, arrival));
                        }
                    }
                }
                RtcpItem::Bye { ssrcs } => {
                    for ssrc in ssrcs {
                        let Some(peer) = rx.peers.get_mut(&ssrc) else {
                            continue;
                        };
                        if peer.addr != from {
                            rx.stats.foreign += 1;
                            continue;
                        }
                        peer.said_bye = true;
                        match end_ts.get(&ssrc) {
                            Some(&ts) => peer.receiver.jitter().hint_end(ts),
                            None => peer.receiver.jitter().bye(),
                        }
                    }
                }
            }
        }
    }

    /// Whether the relay has yet to confirm or refuse our place in its room.
    fn joining(&self) -> bool {
        let rx = lock(&self.rx);
        !rx.stats.relay_joined && rx.stats.relay_refusal.is_none()
    }

    /// Does what the loop's timers say is due at `now`, and says what that was.
    fn run_timers(&self, timers: &mut Timers, now: Instant) -> Due {
        let due = timers.due(now, || self.joining());
        if due.report {
            self.send_report(ReportKind::Periodic);
        }
        if due.keepalive && !lock(&self.tx).left {
            self.request_place();
        }
        if due.expiry {
            self.expire(now);
        }
        due
    }

    fn expire(&self, now: Instant) {
        let mut rx = lock(&self.rx);
        let timeout = self.config.peer_timeout;
        rx.pending_starts
            .retain(|&(_, _, _, at)| now.saturating_duration_since(at) < UNCONFIRMED_TIMEOUT);
        rx.pending_names
            .retain(|(.., at)| now.saturating_duration_since(*at) < UNCONFIRMED_TIMEOUT);
        // A forgotten peer's SRTP replay state stays: replayed, its packets are still refused.
        rx.peers.retain(|_, p| {
            if p.confirmed() {
                now.saturating_duration_since(p.last_heard) < timeout
            } else {
                now.saturating_duration_since(p.last_media) < UNCONFIRMED_TIMEOUT
            }
        });
    }
}

/// The session's SRTP end, when it has a key.
fn srtp(key: Option<&MasterKey>, clock_tolerance: Duration) -> Result<Option<Srtp>, NetError> {
    let Some(key) = key else { return Ok(None) };
    let mut srtp = Srtp::new(key)?;
    srtp.set_clock_tolerance(u32::try_from(clock_tolerance.as_secs()).unwrap_or(u32::MAX));
    Ok(Some(srtp))
}

fn net_loop(shared: &Shared, socket: &UdpSocket) {
    // One byte over the largest datagram taken: one that fills the buffer was cut short.
    let mut buf = vec![0u8; MAX_DATAGRAM + 64 + 1];
    let mut datagram = Vec::with_capacity(MAX_DATAGRAM + 64);
    let mut timers = Timers::new(&shared.config, Instant::now(), system_draw);
    while !shared.stop.load(Ordering::Relaxed) {
        match socket.recv_from(&mut buf) {
            Ok((n, _)) if n >= buf.len() => {
                let mut rx = lock(&shared.rx);
                rx.stats.datagrams += 1;
                rx.stats.malformed += 1;
            }
            Ok((n, from)) => {
                datagram.clear();
                datagram.extend_from_slice(&buf[..n.min(buf.len())]);
                shared.handle(&mut datagram, from, Instant::now());
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            // ICMP errors from earlier sends surface here; they do not stop the session.
            Err(_) => {}
        }
        let now = Instant::now();
        if now >= timers.next_deadline() {
            shared.run_timers(&mut timers, now);
        }
    }
}

#[cfg(test)]
mod tests;
