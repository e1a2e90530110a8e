//! A call session: one UDP socket read by its own thread (no async runtime), any number of
//! remote peers (each identified by SSRC, its address noted), RTCP reports, optional SRTP and
//! an optional relay room.
//!
//! The owner sends payloads of its codec with [`Session::send_frames`] (or
//! [`Session::send_packet`]) and pulls the mixed-down timeline with [`Session::pull`] once per
//! 20 ms of its output clock (a playback thread, or a timer in the headless receiver); decoding
//! happens in `pull`, on the caller's thread. Each peer may send another codec.

use std::collections::HashMap;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::control::{Control, ControlKind, RoomId};
use super::jitter::JitterConfig;
use super::peer::{PeerReceiver, PlayedFrame, ReceiverStats};
use super::rtcp::{self, Outgoing, ReportBlock, RtcpItem, SenderInfo};
use super::rtp::{self, RtpStream};
use super::srtp::{MasterKey, Srtp, SrtpError};
use super::{DatagramKind, MAX_DATAGRAM, NetError, classify};
use crate::codec::any::{Codec, PayloadMap};

#[derive(Debug, Clone)]
pub struct SessionConfig {
    pub bind: SocketAddr,
    /// Where media and reports go: peers of a mesh, or the relay.
    pub destinations: Vec<SocketAddr>,
    /// A relay room to join (the relay is `destinations[0]`).
    pub room: Option<String>,
    /// SRTP master key; `None` sends plain RTP.
    pub key: Option<MasterKey>,
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
    /// Unparseable RTP/RTCP/control datagrams.
    pub malformed: u64,
    /// Datagrams of no known kind.
    pub unknown: u64,
    /// RTP packets of a payload type no codec is mapped to (dropped, never decoded).
    pub unknown_payload: u64,
    /// SRTP/SRTCP packets that failed authentication.
    pub auth_failed: u64,
    pub replayed: u64,
    /// Packets from new SSRCs beyond `max_peers`.
    pub too_many_peers: u64,
    /// Our own packets coming back (a relay or multicast echo).
    pub own: u64,
    pub sent_rtp: u64,
    pub sent_rtcp: u64,
    pub send_errors: u64,
    pub relay_joined: bool,
    pub relay_refused: bool,
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

struct Peer {
    receiver: PeerReceiver,
    addr: SocketAddr,
    cname: Option<String>,
    name: Option<String>,
    last_heard: Instant,
    last_sr: Option<(u32, Instant)>,
    rtt_ms: Option<f64>,
    their_loss: Option<f64>,
    said_bye: bool,
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
}

struct Shared {
    config: SessionConfig,
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
        let shared = Arc::new(Shared {
            cname: format!("lipcall-{ssrc:08x}@{local}"),
            ssrc,
            epoch: Instant::now(),
            tx: Mutex::new(Tx {
                stream,
                srtp: config.key.as_ref().map(Srtp::new),
                buf: Vec::with_capacity(MAX_DATAGRAM),
                sent_since_report: false,
                started: false,
                left: false,
            }),
            rx: Mutex::new(Rx {
                peers: HashMap::new(),
                srtp: config.key.as_ref().map(Srtp::new),
                stats: SessionStats::default(),
            }),
            stop: AtomicBool::new(false),
            socket,
            config,
        });
        if shared.config.room.is_some() {
            shared.send_control(ControlKind::Join);
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
            self.shared.send_control(ControlKind::Leave);
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

    fn send_control(&self, kind: ControlKind) {
        let Some(room) = &self.config.room else {
            return;
        };
        let msg = Control {
            kind,
            room: RoomId::from_name(room),
        }
        .encode();
        if let Some(relay) = self.config.destinations.first() {
            let _ = self.socket.send_to(&msg, relay);
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
                match Control::decode(data) {
                    Ok(c) if self.config.destinations.first() == Some(&from) => match c.kind {
                        ControlKind::Joined => rx.stats.relay_joined = true,
                        ControlKind::Refused => rx.stats.relay_refused = true,
                        _ => rx.stats.unknown += 1,
                    },
                    Ok(_) => rx.stats.unknown += 1,
                    Err(_) => rx.stats.malformed += 1,
                }
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
            Err(SrtpError::AuthFailed | SrtpError::TooManyStreams) => {
                rx.stats.auth_failed += 1;
                false
            }
            Err(_) => {
                rx.stats.malformed += 1;
                false
            }
        }
    }

    fn peer<'a>(&self, rx: &'a mut Rx, ssrc: u32, from: SocketAddr) -> Option<&'a mut Peer> {
        if !rx.peers.contains_key(&ssrc) {
            if rx.peers.len() >= self.config.max_peers {
                rx.stats.too_many_peers += 1;
                return None;
            }
            let receiver = PeerReceiver::with_payloads(
                self.config.jitter,
                self.epoch,
                self.config.enhancer,
                self.config.payloads.clone(),
            );
            rx.peers.insert(
                ssrc,
                Peer {
                    receiver,
                    addr: from,
                    cname: None,
                    name: None,
                    last_heard: Instant::now(),
                    last_sr: None,
                    rtt_ms: None,
                    their_loss: None,
                    said_bye: false,
                },
            );
        }
        let peer = rx.peers.get_mut(&ssrc)?;
        peer.addr = from;
        Some(peer)
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
        if packet.header.ssrc == self.ssrc {
            rx.stats.own += 1;
            return;
        }
        rx.stats.rtp += 1;
        if let Some(peer) = self.peer(rx, packet.header.ssrc, from) {
            peer.last_heard = arrival;
            if !peer.receiver.insert(&packet, arrival) {
                rx.stats.unknown_payload += 1;
            }
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
                    let Some(peer) = self.peer(rx, reporter, from) else {
                        continue;
                    };
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
                    if let Some(peer) = self.peer(rx, ssrc, from) {
                        if cname.is_some() {
                            peer.cname = cname;
                        }
                        if name.is_some() {
                            peer.name = name;
                        }
                    }
                }
                RtcpItem::Bye { ssrcs } => {
                    for ssrc in ssrcs {
                        if let Some(peer) = rx.peers.get_mut(&ssrc) {
                            peer.said_bye = true;
                            if let Some(&ts) = end_ts.get(&ssrc) {
                                peer.receiver.jitter().hint_end(ts);
                            }
                        }
                    }
                }
            }
        }
    }

    fn expire(&self, now: Instant) {
        let mut rx = lock(&self.rx);
        let timeout = self.config.peer_timeout;
        let mut gone = Vec::new();
        rx.peers.retain(|&ssrc, p| {
            let keep = now.saturating_duration_since(p.last_heard) < timeout;
            if !keep {
                gone.push(ssrc);
            }
            keep
        });
        if let Some(srtp) = rx.srtp.as_mut() {
            for ssrc in gone {
                srtp.forget(ssrc);
            }
        }
    }
}

fn jittered(interval: Duration) -> Duration {
    let r = getrandom::u32().unwrap_or(0x8000_0000);
    interval.mul_f64(0.5 + f64::from(r) / f64::from(u32::MAX))
}

fn net_loop(shared: &Shared, socket: &UdpSocket) {
    let mut buf = vec![0u8; MAX_DATAGRAM + 64];
    let mut datagram = Vec::with_capacity(MAX_DATAGRAM + 64);
    let mut next_report = Instant::now() + jittered(shared.config.rtcp_interval);
    let mut next_keepalive = Instant::now() + shared.config.keepalive_interval;
    let mut next_expiry = Instant::now() + Duration::from_secs(1);
    while !shared.stop.load(Ordering::Relaxed) {
        match socket.recv_from(&mut buf) {
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
        if shared.config.send_rtcp && now >= next_report {
            shared.send_report(ReportKind::Periodic);
            next_report = now + jittered(shared.config.rtcp_interval);
        }
        if now >= next_keepalive {
            if !lock(&shared.tx).left {
                shared.send_control(ControlKind::Join);
            }
            next_keepalive = now + shared.config.keepalive_interval;
        }
        if now >= next_expiry {
            shared.expire(now);
            next_expiry = now + Duration::from_secs(1);
        }
    }
}
