//! The session without I/O ([`SessionCore`]): datagrams and the time go in, datagrams to send
//! and decoded frames come out. It owns no socket, no thread and no lock; the
//! [`super::Session`] handle drives it from one socket thread, and its tests in simulated time.

use std::collections::{HashMap, VecDeque};
use std::net::SocketAddr;
use std::time::{Duration, Instant};

use super::blocked::Blocked;
use super::latch::{FixedSources, Latch, Named};
use super::negotiated::CallMedia;
use super::remote::{PENDING_NAMES, PENDING_STARTS, Peer, PendingNames};
use super::timers::{Due, Timers};
use super::{PeerFrame, PeerId, PeerInfo, SessionConfig, SessionStats};
use super::{Transmit, TransmitKind};
use crate::codec::any::Codec;
use crate::net::control::{Control, ControlError, ControlKind, Cookie, RoomId};
use crate::net::rtcp::{self, NtpClock, Outgoing, ReportBlock, SenderInfo, system_draw};
use crate::net::rtp::RtpStream;
use crate::net::srtp::{MasterKey, Srtp};
use crate::net::{DatagramKind, MAX_DATAGRAM, NetError, classify};

/// The longest datagram the session reads; a longer one was cut short by the socket.
pub const LARGEST_DATAGRAM: usize = MAX_DATAGRAM + 64;
/// Callers a listening session sends back to at most ([`SessionCore::answer`]).
pub const MAX_ANSWERED: usize = 8;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum ReportKind {
    /// Before the first packet: an SR with no packets marks where the stream starts.
    Start,
    Periodic,
    /// The last word: SR (marking where the stream ends) + SDES + BYE.
    Bye,
}

/// What a listening session's report tells a caller of its call ([`SessionConfig::rings_for_callers`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Told {
    Nothing,
    Ringing,
    Declined,
}

/// Our side of the relay's join handshake (see [`crate::net::control`]).
#[derive(Default)]
struct RelayLink {
    /// The relay's cookie for our address: echoed to join, in keepalives and in the leave.
    cookie: Option<Cookie>,
    /// A join or keepalive is unanswered: a challenge now is the relay's answer to it, not
    /// one provoked by someone else's forged join in our name.
    awaiting: bool,
}

/// A call session's state and rules: any number of remote peers (each identified by SSRC, its
/// address noted), RTCP reports, optional SRTP and an optional relay room.
pub struct SessionCore {
    pub(super) config: SessionConfig,
    /// The relay room's id, when the session joins one.
    pub(super) room: Option<RoomId>,
    pub(super) epoch: Instant,
    /// The reports' wall clock, from `epoch`.
    clock: NtpClock,
    pub(super) ssrc: u32,
    cname: String,
    pub(super) stream: RtpStream,
    tx_srtp: Option<Srtp>,
    pub(super) rx_srtp: Option<Srtp>,
    /// The sources of a [`Latch::Fixed`] call.
    pub(super) fixed: Option<FixedSources>,
    /// Our stream's packet count at the report before the last and at the last: more since
    /// the first makes the next periodic report an SR (RFC 3550 6.4).
    packets_at_reports: [u32; 2],
    started: bool,
    pub(super) left: bool,
    /// What a negotiated call (SIP) adds: one stream, hold, keepalive, DTMF.
    pub(super) call: Option<CallMedia>,
    pub(super) peers: HashMap<u32, Peer>,
    pub(super) stats: SessionStats,
    /// SRs with no packets sent yet (where a stream will start), by SSRC, from senders not yet
    /// peers: (ssrc, RTP timestamp, from, arrival).
    pub(super) pending_starts: Vec<(u32, u32, SocketAddr, Instant)>,
    pub(super) pending_names: Vec<PendingNames>,
    relay: RelayLink,
    /// A listening session's callers it sends back to (it has no destinations of its own).
    answering: Vec<SocketAddr>,
    /// Callers the user hung up on, kept out for a while.
    pub(super) blocked: Blocked,
    timers: Timers,
    outbox: VecDeque<Transmit>,
    /// Buffers of datagrams sent, for the next ones.
    pub(super) spare: Vec<Vec<u8>>,
    /// The datagram being handled (decrypted in place).
    scratch: Vec<u8>,
}

impl std::fmt::Debug for SessionCore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SessionCore")
            .field("ssrc", &self.ssrc)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

/// The session's SRTP end, when it has a key.
fn srtp(key: Option<&MasterKey>, clock_tolerance: Duration) -> Result<Option<Srtp>, NetError> {
    let Some(key) = key else { return Ok(None) };
    let mut srtp = Srtp::new(key)?;
    srtp.set_clock_tolerance(u32::try_from(clock_tolerance.as_secs()).unwrap_or(u32::MAX));
    Ok(Some(srtp))
}

impl SessionCore {
    /// A session whose socket is bound at `local`, starting at `now` (the epoch its jitter
    /// buffers measure time from). A relay join, if any, is the first datagram to send.
    pub fn new(config: SessionConfig, local: SocketAddr, now: Instant) -> Result<Self, NetError> {
        Self::with_draw(config, local, now, system_draw)
    }

    /// A session whose reports are spread by `draw` (a uniform draw over `u32`).
    pub(super) fn with_draw(
        config: SessionConfig,
        local: SocketAddr,
        now: Instant,
        draw: fn() -> u32,
    ) -> Result<Self, NetError> {
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
        let mut core = Self {
            cname: rtcp::cname(ssrc, local),
            ssrc,
            epoch: now,
            clock: NtpClock::new(now),
            stream,
            tx_srtp: srtp(config.key.as_ref(), config.clock_tolerance)?,
            rx_srtp: srtp(
                config.peer_key.as_ref().or(config.key.as_ref()),
                config.clock_tolerance,
            )?,
            fixed: match config.latch {
                Latch::Rebinding => None,
                Latch::Fixed(named) => Some(FixedSources::new(named)),
            },
            packets_at_reports: [0; 2],
            started: false,
            call: config.call.clone().map(|c| CallMedia::new(c, now)),
            left: false,
            peers: HashMap::new(),
            stats: SessionStats::default(),
            pending_starts: Vec::with_capacity(PENDING_STARTS),
            pending_names: Vec::with_capacity(PENDING_NAMES),
            relay: RelayLink::default(),
            answering: Vec::new(),
            blocked: Blocked::default(),
            timers: Timers::new(&config, now, draw),
            outbox: VecDeque::new(),
            spare: Vec::new(),
            scratch: Vec::with_capacity(LARGEST_DATAGRAM),
            room: config.room.as_deref().map(RoomId::from_name),
            config,
        };
        core.request_place();
        Ok(core)
    }

    /// `at` on the reports' wall clock, as NTP.
    pub(super) fn ntp_at(&self, at: Instant) -> u64 {
        self.clock.at(at)
    }

    pub fn ssrc(&self) -> u32 {
        self.ssrc
    }

    /// The instant the session's jitter buffers measure time from.
    pub fn epoch(&self) -> Instant {
        self.epoch
    }

    pub fn config(&self) -> &SessionConfig {
        &self.config
    }

    pub fn stats(&self) -> SessionStats {
        self.stats
    }

    pub fn peers(&self) -> Vec<PeerInfo> {
        let mut peers: Vec<PeerInfo> = self.peers.iter().map(|(&s, p)| p.info(s)).collect();
        peers.sort_by_key(|p| p.id);
        peers
    }

    /// The next datagram to send, if any.
    pub fn poll_transmit(&mut self) -> Option<Transmit> {
        self.outbox.pop_front()
    }

    /// A datagram from [`Self::poll_transmit`] went out (`sent`) or failed to.
    pub fn transmitted(&mut self, transmit: Transmit, sent: bool) {
        match (transmit.kind, sent) {
            (TransmitKind::Control | TransmitKind::WebRtc, _) => {}
            // An empty one is a keepalive, counted as such.
            (TransmitKind::Rtp, true) if transmit.data.is_empty() => {}
            (TransmitKind::Rtp, true) => self.stats.sent_rtp += 1,
            (TransmitKind::Rtcp, true) => self.stats.sent_rtcp += 1,
            (_, false) => self.stats.send_errors += 1,
        }
        self.spare.push(transmit.data);
    }

    /// When [`Self::handle_timeout`] is next due.
    pub fn poll_timeout(&self) -> Instant {
        self.timers.next_deadline()
    }

    /// Does what is due at `now`: reports, the relay keepalive, forgetting the silent.
    pub fn handle_timeout(&mut self, now: Instant) {
        if now >= self.timers.next_deadline() {
            self.run_timers(now);
        }
    }

    /// Does what the timers say is due at `now`, and says what that was.
    pub(super) fn run_timers(&mut self, now: Instant) -> Due {
        let joining = !self.stats.relay_joined && self.stats.relay_refusal.is_none();
        let due = self.timers.due(now, || joining);
        if due.report && !self.left {
            self.send_report(ReportKind::Periodic, now);
        }
        if due.keepalive && !self.left {
            self.request_place();
        }
        if due.expiry {
            self.expire(now);
            self.keep_call_alive(now);
        }
        due
    }

    /// Sends one payload of the session's codec lasting `ticks` of its RTP clock (an Opus
    /// packet of 60 ms: 2880) to every destination.
    pub fn send_packet(
        &mut self,
        payload: &[u8],
        ticks: u32,
        now: Instant,
    ) -> Result<(), NetError> {
        if self.call.as_ref().is_some_and(|c| c.config.held) {
            // The peer said it receives nothing: the stream's clock moves on regardless.
            let frame_ticks = self.config.codec.frame_ticks().max(1);
            self.stream.skip(ticks / frame_ticks);
            return Ok(());
        }
        if !self.started && self.config.send_rtcp {
            // Tells receivers where the stream starts, in case its first packet is lost.
            self.send_report(ReportKind::Start, now);
        }
        self.started = true;
        let mut buf = self.spare.pop().unwrap_or_default();
        self.stream.packetize_ticks(payload, ticks, &mut buf)?;
        self.send_media(buf, now)
    }

    /// Protects and sends a media packet `buf` made by our stream.
    pub(super) fn send_media(&mut self, mut buf: Vec<u8>, now: Instant) -> Result<(), NetError> {
        if let Some(srtp) = self.tx_srtp.as_mut() {
            srtp.protect_rtp(&mut buf)?;
        }
        if let Some(call) = self.call.as_mut() {
            call.last_sent = now;
        }
        self.send_all(buf, TransmitKind::Rtp);
        Ok(())
    }

    /// Frames not sent (silence, mute): the timestamp moves on and the next packet starts a
    /// new talk spurt.
    pub fn skip_frames(&mut self, frames: u32) {
        self.stream.skip(frames);
    }

    /// Pulls the next 20 ms (starting at `now` on the output clock) from every peer that is
    /// playing, appending to `out`.
    pub fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) {
        for (&ssrc, peer) in self.peers.iter_mut() {
            if let Some(frame) = peer.receiver.pull(now) {
                out.push(PeerFrame {
                    peer: PeerId::Ssrc(ssrc),
                    frame,
                });
            }
        }
    }

    /// Says BYE (with a final SR marking where the stream ends) and leaves the relay room.
    pub fn leave(&mut self, now: Instant) {
        if std::mem::replace(&mut self.left, true) {
            return;
        }
        if self.config.send_rtcp {
            self.send_report(ReportKind::Bye, now);
            // Twice: a lost BYE would leave receivers concealing until their timeout. Not
            // to a negotiated call's peer: baresip forgets what it received of a stream on
            // its first BYE, and counts nothing of it at the second.
            if self.call.is_none() {
                self.send_report(ReportKind::Bye, now);
            }
        }
        if let (Some(room), Some(cookie)) = (self.room, self.relay.cookie) {
            self.send_to_relay(Control::new(ControlKind::Leave, room, cookie));
        }
    }

    /// Queues `data` to every destination.
    pub(super) fn send_all(&mut self, data: Vec<u8>, kind: TransmitKind) {
        if let Some(fixed) = &self.fixed {
            let to = match kind {
                TransmitKind::Rtcp => fixed.rtcp.target(),
                _ => fixed.rtp.target(),
            };
            self.outbox.push_back(Transmit { to, data, kind });
            return;
        }
        let targets = if self.config.destinations.is_empty() {
            &self.answering
        } else {
            &self.config.destinations
        };
        let Some((&last, others)) = targets.split_last() else {
            self.spare.push(data);
            return;
        };
        for &to in others {
            let mut copy = self.spare.pop().unwrap_or_default();
            copy.clear();
            copy.extend_from_slice(&data);
            self.outbox.push_back(Transmit {
                to,
                data: copy,
                kind,
            });
        }
        self.outbox.push_back(Transmit {
            to: last,
            data,
            kind,
        });
    }

    fn send_to_relay(&mut self, control: Control) {
        if let Some(&to) = self.config.destinations.first() {
            let mut data = self.spare.pop().unwrap_or_default();
            data.clear();
            data.extend_from_slice(&control.encode());
            self.outbox.push_back(Transmit {
                to,
                data,
                kind: TransmitKind::Control,
            });
        }
    }

    /// Asks the relay for our place in the room: a join, or (with its cookie) the confirm that
    /// is also the keepalive.
    fn request_place(&mut self) {
        let Some(room) = self.room else { return };
        self.relay.awaiting = true;
        let request = match self.relay.cookie {
            Some(cookie) => Control::new(ControlKind::Confirm, room, cookie),
            None => Control::new(ControlKind::Join, room, Cookie::NONE),
        };
        self.send_to_relay(request);
    }

    /// The peer of a [`Latch::Fixed`] call named new addresses (a re-INVITE): each one changed
    /// is open to its first packet again. Nothing in a session of another latch.
    pub fn rename_peer(&mut self, named: Named) {
        if let Some(fixed) = self.fixed.as_mut() {
            fixed.rename(named);
        }
    }

    /// Where the media of a [`Latch::Fixed`] call comes from, once its first packet came.
    pub fn latched(&self) -> Option<SocketAddr> {
        self.fixed.as_ref().and_then(|f| f.rtp.latched())
    }

    /// Sends a report now (normally the timers do so every `rtcp_interval`).
    pub fn send_periodic_report(&mut self, now: Instant) {
        self.send_report(ReportKind::Periodic, now);
    }

    fn send_report(&mut self, kind: ReportKind, now: Instant) {
        let mut peer_addrs: Vec<SocketAddr> = self.peers.values().map(|p| p.addr).collect();
        let Some(buf) = self.report(kind, now, Told::Nothing) else {
            return;
        };
        if self.config.destinations.is_empty() && self.fixed.is_none() {
            // A pure receiver reports back to where its peers send from (those it answers
            // get theirs with its media).
            peer_addrs.retain(|a| !self.answering.contains(a));
            peer_addrs.sort_unstable();
            peer_addrs.dedup();
            let ringing = if self.config.rings_for_callers && !peer_addrs.is_empty() {
                self.report(kind, now, Told::Ringing)
            } else {
                None
            };
            for to in peer_addrs {
                self.send_copy(ringing.as_deref().unwrap_or(&buf), to);
            }
            if let Some(ringing) = ringing {
                self.spare.push(ringing);
            }
        }
        self.send_all(buf, TransmitKind::Rtcp);
    }

    /// Queues a copy of the report `buf` to `to` alone.
    fn send_copy(&mut self, buf: &[u8], to: SocketAddr) {
        let mut copy = self.spare.pop().unwrap_or_default();
        copy.clear();
        copy.extend_from_slice(buf);
        self.outbox.push_back(Transmit {
            to,
            data: copy,
            kind: TransmitKind::Rtcp,
        });
    }

    /// A report of `kind` as it goes on the wire, if it could be made, telling the callers it
    /// goes to what became of their call.
    fn report(&mut self, kind: ReportKind, now: Instant, told: Told) -> Option<Vec<u8>> {
        let ntp = self.ntp_at(now);
        let mut blocks = Vec::new();
        for (&ssrc, peer) in self.peers.iter_mut() {
            if let Some(reception) = peer.receiver.jitter().report() {
                blocks.push(ReportBlock::about(
                    ssrc,
                    reception,
                    peer.reports.last_sr,
                    now,
                ));
            }
        }
        let info = SenderInfo::of(&self.stream, ntp);
        let sender = match kind {
            ReportKind::Start => Some(info),
            ReportKind::Bye => self.started.then_some(info),
            ReportKind::Periodic => {
                (self.stream.packets_sent != self.packets_at_reports[0]).then_some(info)
            }
        };
        self.packets_at_reports = [self.packets_at_reports[1], self.stream.packets_sent];
        let mut buf = self.spare.pop().unwrap_or_default();
        buf.clear();
        let built = rtcp::build(
            &Outgoing {
                ssrc: self.ssrc,
                sender,
                blocks: &blocks,
                cname: &self.cname,
                name: self.config.name.as_deref(),
                note: (told != Told::Nothing).then_some(rtcp::RINGING_NOTE),
                bye: kind == ReportKind::Bye,
                bye_reason: (told == Told::Declined).then_some(rtcp::DECLINED_REASON),
            },
            &mut buf,
        );
        if built.is_err() {
            self.spare.push(buf);
            return None;
        }
        if let Some(srtp) = self.tx_srtp.as_mut()
            && srtp.protect_rtcp(&mut buf).is_err()
        {
            self.spare.push(buf);
            return None;
        }
        Some(buf)
    }

    /// A listening session (no destinations of its own) sends its media and reports to `to`
    /// as well, the callers it hears (at most [`MAX_ANSWERED`]), in `codec` where a payload
    /// type is mapped to it; says which codec it sends. Empty: it only listens again.
    pub fn answer(&mut self, to: &[SocketAddr], codec: Codec) -> Codec {
        if self.config.destinations.is_empty() && self.fixed.is_none() {
            self.answering = to.iter().copied().take(MAX_ANSWERED).collect();
        }
        if codec != self.config.codec
            && let Some(payload_type) = self.config.payloads.payload_type(codec)
        {
            self.stream.set_payload(payload_type, codec.frame_ticks());
            self.config.codec = codec;
        }
        self.config.codec
    }

    /// The callers a listening session sends back to.
    pub fn answering(&self) -> &[SocketAddr] {
        &self.answering
    }

    /// The user hung up on the caller at `addr`: it hears our BYE, is forgotten, and what it
    /// sends is kept out for a while ([`Blocked`]).
    pub fn hang_up_on(&mut self, addr: SocketAddr, now: Instant) {
        self.blocked.block(addr, now);
        self.peers.retain(|_, p| p.addr != addr);
        let told = if self.config.rings_for_callers && !self.answering.contains(&addr) {
            Told::Declined
        } else {
            Told::Nothing
        };
        self.answering.retain(|&a| a != addr);
        if self.config.send_rtcp
            && let Some(bye) = self.report(ReportKind::Bye, now, told)
        {
            // Twice, as at the session's end: a lost BYE leaves the caller waiting.
            self.send_copy(&bye, addr);
            self.send_copy(&bye, addr);
            self.spare.push(bye);
        }
    }

    /// The callers kept out, to be kept by the session that follows this one.
    pub fn blocked(&self) -> &Blocked {
        &self.blocked
    }

    /// Keeps out the callers `blocked` keeps out (those of the session before).
    pub fn keep_blocked(&mut self, blocked: Blocked) {
        self.blocked = blocked;
    }

    /// Handles a datagram that arrived from `from` at `now`.
    pub fn handle_datagram(&mut self, data: &[u8], from: SocketAddr, now: Instant) {
        self.stats.datagrams += 1;
        if !self.blocked.admits(from, now) {
            self.stats.blocked += 1;
            return;
        }
        if data.len() > LARGEST_DATAGRAM {
            // Cut short by the socket: whatever it was, it cannot be read.
            self.stats.malformed += 1;
            return;
        }
        self.stats.bytes += data.len() as u64;
        let mut datagram = std::mem::take(&mut self.scratch);
        datagram.clear();
        datagram.extend_from_slice(data);
        match classify(&datagram) {
            DatagramKind::Control => {
                self.stats.control += 1;
                self.handle_control(&datagram, from);
            }
            DatagramKind::Rtcp => {
                self.stats.rtcp += 1;
                self.handle_rtcp(&mut datagram, from, now);
            }
            DatagramKind::Rtp => self.handle_rtp(&mut datagram, from, now),
            DatagramKind::Unknown => self.stats.unknown += 1,
        }
        self.scratch = datagram;
    }

    /// The relay's answers; anything else (not from the relay, another room, a cookie that is
    /// not ours) is ignored.
    fn handle_control(&mut self, data: &[u8], from: SocketAddr) {
        let from_relay = self.room.is_some() && self.config.destinations.first() == Some(&from);
        let control = match Control::decode(data) {
            Ok(control) if from_relay && Some(control.room) == self.room => control,
            Ok(_) => {
                self.stats.unknown += 1;
                return;
            }
            Err(ControlError::Version(_)) if from_relay => {
                self.stats.relay_outdated = true;
                self.stats.malformed += 1;
                return;
            }
            Err(_) => {
                self.stats.malformed += 1;
                return;
            }
        };
        let ours = self
            .relay
            .cookie
            .is_some_and(|c| c.matches(&control.cookie));
        match control.kind {
            ControlKind::Challenge if self.relay.awaiting => {
                self.stats.relay_challenges += 1;
                self.relay.cookie = Some(control.cookie);
                self.send_to_relay(Control::new(
                    ControlKind::Confirm,
                    control.room,
                    control.cookie,
                ));
            }
            ControlKind::Joined if ours => {
                self.relay.awaiting = false;
                self.stats.relay_joined = true;
                self.stats.relay_refusal = None;
            }
            ControlKind::Refused(why) if ours => {
                self.relay.awaiting = false;
                self.stats.relay_refusal = Some(why);
            }
            _ => self.stats.unknown += 1,
        }
    }
}
