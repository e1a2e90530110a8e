//! The WebRTC media of a Janus room: one UDP socket carrying any number of str0m peer
//! connections: at most one that publishes our Opus stream and one per subscribed publisher.
//! Datagrams are handed to the connection that accepts them (ICE credentials, then the remote
//! address).
//!
//! str0m does ICE, DTLS-SRTP and RTCP. Received RTP packets (str0m's RTP mode: no
//! depacketising, no reordering) go into a [`PeerReceiver`] per publisher, the same jitter
//! buffer, decoder and features as a direct call; the owner pulls frames every 20 ms.
//!
//! As a session is, the media is a core without I/O (`MediaCore`: the connections and the
//! feeds' receivers) under the same socket thread as a session's.

use std::collections::{HashMap, VecDeque};
use std::net::{IpAddr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use str0m::change::{SdpAnswer, SdpOffer, SdpPendingOffer};
use str0m::media::{Direction, Frequency, MediaKind, MediaTime, Mid, Pt};
use str0m::net::{Protocol, Receive};
use str0m::{Candidate, Event, IceConnectionState, Input, Output, Rtc};

use super::JanusError;
use super::candidates::{self, IceServers};
use super::feeds::{self, Feed, FeedInfo, MediaStats};
use crate::codec::any::PayloadMap;
use crate::net::jitter::JitterConfig;
use crate::net::peer::PeerReceiver;
use crate::net::rtp::{Rtp, RtpHeader};
use crate::net::transport::{Driver, PeerFrame, SansIo, Transmit, TransmitKind};
use crate::net::turn::TurnClient;

/// How long the socket thread waits at most for a datagram: a connection's timeout that an
/// owner's call brought forward is seen within it.
const POLL: Duration = Duration::from_millis(2);
/// With no connection, when the core next wants to be woken.
const IDLE: Duration = Duration::from_secs(1);
/// How long a join waits for a TURN allocation.
const TURN_WAIT: Duration = Duration::from_secs(4);

/// The media side of a room: shared by the room's signalling and the receive tick, its thread
/// stops when the last owner drops it.
pub struct Media {
    driver: Driver<MediaCore>,
    closed: AtomicBool,
}

impl std::fmt::Debug for Media {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Media").finish_non_exhaustive()
    }
}

fn stopped() -> JanusError {
    JanusError::Media("the media thread has stopped".into())
}

impl Media {
    /// Starts the media thread on one UDP port, offered as a host candidate on each of `ips`
    /// (all of one family), and with a `stun` server (HOST:PORT) as the server-reflexive
    /// candidate it sees.
    pub fn start(
        ips: &[IpAddr],
        jitter: JitterConfig,
        ice: &IceServers,
    ) -> Result<Self, JanusError> {
        let any: IpAddr = match ips.first() {
            Some(IpAddr::V6(_)) => std::net::Ipv6Addr::UNSPECIFIED.into(),
            _ => std::net::Ipv4Addr::UNSPECIFIED.into(),
        };
        let socket = UdpSocket::bind((any, 0))
            .map_err(|e| JanusError::Media(format!("cannot bind UDP: {e}")))?;
        let port = socket
            .local_addr()
            .map_err(|e| JanusError::Media(format!("UDP: {e}")))?
            .port();
        let local: Vec<SocketAddr> = ips.iter().map(|&ip| SocketAddr::new(ip, port)).collect();
        let mut core = MediaCore::new(local, jitter, Instant::now());
        core.relay_only = ice.relay_only;
        if let Some(server) = &ice.stun {
            core.reflexive = candidates::reflexive(&socket, server, port, &core.local);
        }
        if let (Some(turn), Some(&family)) = (&ice.turn, core.local.first()) {
            core.turn = Some(candidates::turn_client(turn, port, family, Instant::now())?);
        }
        let driver = Driver::start(socket, core, "lipcall-webrtc", POLL)
            .map_err(|e| JanusError::Media(format!("cannot start the media thread: {e}")))?;
        let media = Self {
            driver,
            closed: AtomicBool::new(false),
        };
        if ice.turn.is_some() {
            media.await_relay(ice.relay_only)?;
        }
        Ok(media)
    }

    /// Waits for the TURN allocation, so that the first offer carries the relay; without one
    /// the call goes on with our own addresses, unless it was to be relayed only.
    fn await_relay(&self, relay_only: bool) -> Result<(), JanusError> {
        let deadline = Instant::now() + TURN_WAIT;
        loop {
            let state = self.driver.access(|core| {
                core.turn
                    .as_ref()
                    .map(|(t, _)| (t.server(), t.relayed(), t.failed().cloned()))
            });
            let Some((server, relayed, failed)) = state else {
                return Ok(());
            };
            let failed = match (relayed, failed) {
                (Some(relayed), _) => {
                    tracing::info!("TURN server {server}: relaying through {relayed}");
                    return Ok(());
                }
                (None, Some(e)) => e.to_string(),
                (None, None) if Instant::now() >= deadline => {
                    format!("TURN server {server} gave no relay within {TURN_WAIT:?}")
                }
                (None, None) => {
                    std::thread::sleep(Duration::from_millis(10));
                    continue;
                }
            };
            if relay_only {
                return Err(JanusError::Media(format!(
                    "{failed}: the call was to be relayed only"
                )));
            }
            tracing::warn!("{failed}: offering our own addresses only");
            return Ok(());
        }
    }

    /// Runs `f` on the core while the media runs.
    fn with<T>(
        &self,
        f: impl FnOnce(&mut MediaCore, Instant) -> Result<T, JanusError>,
    ) -> Result<T, JanusError> {
        if self.closed.load(Ordering::Relaxed) {
            return Err(stopped());
        }
        self.driver.with(|core| f(core, Instant::now()))
    }

    /// The SDP offer of our publishing connection (audio only, Opus, send only).
    pub fn publish_offer(&self) -> Result<String, JanusError> {
        self.with(MediaCore::offer)
    }

    pub fn publish_answer(&self, sdp: &str) -> Result<(), JanusError> {
        self.with(|core, _| core.answer(sdp))
    }

    /// Answers Janus's offer for one publisher's stream; its frames come out of [`Self::pull`].
    pub fn subscribe(&self, feed: &str, name: &str, offer: &str) -> Result<String, JanusError> {
        self.with(|core, now| core.subscribe(feed.to_string(), name.to_string(), offer, now))
    }

    /// The publisher left: its buffered audio still plays out, then it falls silent.
    pub fn feed_left(&self, feed: &str) {
        let closed = self.closed.load(Ordering::Relaxed);
        self.driver.with(|core| core.feed_left(feed, !closed));
    }

    /// Sends one Opus payload lasting `ticks` of the 48 kHz RTP clock.
    pub fn send(&self, payload: &[u8], ticks: u32) -> Result<(), JanusError> {
        self.with(|core, now| {
            core.send(payload, ticks, now);
            Ok(())
        })
    }

    /// Moves the published stream's RTP clock on by `ticks` (48 kHz) without sending: a
    /// silent gap that the subscribers play as silence, not loss.
    pub fn skip(&self, ticks: u32) {
        // A stopped media thread has nothing to skip.
        let _ = self.with(|core, _| {
            core.skip(ticks);
            Ok(())
        });
    }

    /// The next 20 ms of every subscribed publisher that is playing.
    pub fn pull(&self, now: Instant, out: &mut Vec<PeerFrame>) {
        self.driver.with_waiting(|core| core.pull(now, out));
    }

    pub fn feeds(&self) -> Vec<FeedInfo> {
        self.driver.access(|core| core.feeds())
    }

    pub fn stats(&self) -> MediaStats {
        self.driver.access(|core| core.stats)
    }

    /// Closes every connection (DTLS close and RTCP BYE go out); the thread stops with the
    /// last owner.
    pub fn hang_up(&self) {
        if !self.closed.swap(true, Ordering::Relaxed) {
            self.driver.with(MediaCore::close_all);
        }
    }
}

impl Drop for Media {
    fn drop(&mut self) {
        self.hang_up();
        self.driver.stop();
    }
}

enum Role {
    Publisher {
        pending: Option<SdpPendingOffer>,
        mid: Option<Mid>,
        pt: Option<Pt>,
        /// RTP time of the next packet, in 48 kHz ticks.
        time: u64,
    },
    Subscriber {
        feed: String,
    },
}

struct Conn {
    rtc: Rtc,
    role: Role,
    timeout: Instant,
    alive: bool,
}

/// The connections and what they receive, without the socket: datagrams and the time go in,
/// datagrams to send and decoded frames come out.
struct MediaCore {
    /// Our host candidates: one port, several addresses.
    local: Vec<SocketAddr>,
    /// Our address outside a NAT (from STUN) and the local address it maps.
    reflexive: Option<(SocketAddr, SocketAddr)>,
    /// A TURN allocation, and the local address it is asked from.
    turn: Option<(TurnClient, SocketAddr)>,
    /// Offer the relay only.
    relay_only: bool,
    epoch: Instant,
    jitter: JitterConfig,
    /// The latest time the core was given.
    now: Instant,
    /// When the datagram being handled arrived (the kernel's stamp), for its RTP packets.
    arrived: Option<Instant>,
    conns: Vec<Conn>,
    feeds: HashMap<String, Feed>,
    /// Publishers gone and played out, oldest first.
    departed: VecDeque<FeedInfo>,
    stats: MediaStats,
    outbox: VecDeque<Transmit>,
}

impl SansIo for MediaCore {
    const BUFFER: usize = 2000;

    fn handle_datagram(&mut self, data: &[u8], source: SocketAddr, arrived: Instant) {
        // str0m's clock only moves on; the jitter buffers get the kernel's arrival stamp,
        // which a burst read after a stall has from before the last timeout handled.
        self.now = self.now.max(arrived);
        self.arrived = Some(arrived);
        self.datagram(data, source, self.now);
        self.arrived = None;
        self.conns.retain(|c| c.alive);
    }

    fn poll_timeout(&self) -> Instant {
        let idle = self.now + IDLE;
        let turn = self.turn.as_ref().and_then(|(t, _)| t.poll_timeout());
        let conns = self.conns.iter().map(|c| c.timeout);
        conns.chain(turn).min().unwrap_or(idle)
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.now = now;
        if let Some((turn, _)) = &mut self.turn {
            turn.handle_timeout(now);
        }
        for i in 0..self.conns.len() {
            if self.conns[i].timeout <= now {
                let result = self.conns[i].rtc.handle_input(Input::Timeout(now));
                self.after(i, result.map_err(|e| e.to_string()));
            }
        }
        self.conns.retain(|c| c.alive);
    }

    fn poll_transmit(&mut self) -> Option<Transmit> {
        if let Some((turn, _)) = &mut self.turn
            && let Some(data) = turn.poll_transmit()
        {
            return Some(Transmit {
                to: turn.server(),
                data,
                kind: TransmitKind::WebRtc,
            });
        }
        self.outbox.pop_front()
    }

    fn transmitted(&mut self, _: Transmit, sent: bool) {
        if sent {
            self.stats.sent += 1;
        } else {
            self.stats.send_errors += 1;
        }
    }
}

impl MediaCore {
    fn new(local: Vec<SocketAddr>, jitter: JitterConfig, now: Instant) -> Self {
        Self {
            local,
            reflexive: None,
            turn: None,
            relay_only: false,
            epoch: now,
            jitter,
            now,
            arrived: None,
            conns: Vec::new(),
            feeds: HashMap::new(),
            departed: VecDeque::new(),
            stats: MediaStats::default(),
            outbox: VecDeque::new(),
        }
    }

    fn new_rtc(&self, rtp_mode: bool, now: Instant) -> Result<Rtc, JanusError> {
        let mut rtc = Rtc::builder()
            .clear_codecs()
            .enable_opus(true, false)
            .set_rtp_mode(rtp_mode)
            .build(now);
        let relayed = self.relayed();
        if let Some((relayed, base)) = relayed {
            let candidate = Candidate::relayed(relayed, base, "udp")
                .map_err(|e| JanusError::Media(format!("relayed candidate {relayed}: {e}")))?;
            rtc.add_local_candidate(candidate);
        }
        if self.relay_only {
            return match relayed {
                Some(_) => Ok(rtc),
                None => Err(JanusError::Media("no TURN relay to offer".into())),
            };
        }
        for &addr in &self.local {
            let candidate = Candidate::host(addr, "udp")
                .map_err(|e| JanusError::Media(format!("host candidate {addr}: {e}")))?;
            rtc.add_local_candidate(candidate);
        }
        if let Some((public, base)) = self.reflexive {
            let candidate = Candidate::server_reflexive(public, base, "udp").map_err(|e| {
                JanusError::Media(format!("server-reflexive candidate {public}: {e}"))
            })?;
            rtc.add_local_candidate(candidate);
        }
        Ok(rtc)
    }

    /// The relay's address and our local address it is asked from, once allocated.
    fn relayed(&self) -> Option<(SocketAddr, SocketAddr)> {
        let (turn, base) = self.turn.as_ref()?;
        turn.relayed().map(|r| (r, *base))
    }

    fn datagram(&mut self, data: &[u8], source: SocketAddr, now: Instant) {
        self.stats.datagrams += 1;
        if let Some((turn, _)) = self.turn.as_mut().filter(|(t, _)| t.server() == source) {
            // TURN's own answers stay with the client; what a peer sent through the relay
            // came, as far as ICE knows, to the relayed address.
            let relayed = turn.handle(data, now).zip(turn.relayed());
            if let Some(((peer, data), relayed)) = relayed {
                self.deliver(&data, peer, relayed, now);
            }
            return;
        }
        // The socket listens on every address; which one a datagram came to is taken to be
        // the one on the same side of loopback as its source.
        let destination = self
            .local
            .iter()
            .find(|a| a.ip().is_loopback() == source.ip().is_loopback())
            .or(self.local.first())
            .copied()
            .unwrap_or(source);
        self.deliver(data, source, destination, now);
    }

    /// Hands a datagram to the connection that takes it.
    fn deliver(&mut self, data: &[u8], source: SocketAddr, destination: SocketAddr, now: Instant) {
        let Ok(contents) = data.try_into() else {
            self.stats.unmatched += 1;
            return;
        };
        let input = Input::Receive(
            now,
            Receive {
                proto: Protocol::Udp,
                source,
                destination,
                contents,
            },
        );
        match self.conns.iter().position(|c| c.rtc.accepts(&input)) {
            Some(i) => {
                let result = self.conns[i].rtc.handle_input(input);
                self.after(i, result.map_err(|e| e.to_string()));
            }
            None => self.stats.unmatched += 1,
        }
    }

    /// Drains connection `i` after a mutation, as str0m requires; a failure closes it.
    fn after(&mut self, i: usize, result: Result<(), String>) {
        if result.is_err() {
            self.fail(i, "WebRTC input rejected");
            return;
        }
        loop {
            let output = match self.conns[i].rtc.poll_output() {
                Ok(o) => o,
                Err(_) => {
                    self.fail(i, "WebRTC connection error");
                    return;
                }
            };
            match output {
                Output::Timeout(t) => {
                    self.conns[i].timeout = t;
                    if !self.conns[i].rtc.is_alive() {
                        self.conns[i].alive = false;
                    }
                    return;
                }
                Output::Transmit(t) => match &mut self.turn {
                    // A relay that has ended drops what was to leave from it: sent from our
                    // own socket it would tell the peer our address (--turn-only).
                    Some((turn, _)) if turn.relays_from(t.source) => {
                        turn.send_to(t.destination, &t.contents, self.now);
                    }
                    _ => self.outbox.push_back(Transmit {
                        to: t.destination,
                        data: t.contents.to_vec(),
                        kind: TransmitKind::WebRtc,
                    }),
                },
                Output::Event(e) => self.event(i, e),
            }
        }
    }

    fn fail(&mut self, i: usize, reason: &'static str) {
        self.conns[i].alive = false;
        self.stats.failed = Some(reason);
        if let Role::Subscriber { feed } = &self.conns[i].role
            && let Some(f) = self.feeds.get_mut(feed)
        {
            f.connected = false;
        }
    }

    fn event(&mut self, i: usize, event: Event) {
        match (&mut self.conns[i].role, event) {
            (Role::Subscriber { feed }, Event::RtpPacket(p)) => {
                let header = RtpHeader {
                    marker: p.header.marker,
                    payload_type: *p.header.payload_type,
                    sequence: *p.seq_no as u16,
                    timestamp: p.header.timestamp,
                    ssrc: *p.header.ssrc,
                };
                if let Some(f) = self.feeds.get_mut(feed.as_str()) {
                    f.ssrc.get_or_insert(header.ssrc);
                    f.receiver.insert(
                        &Rtp {
                            header,
                            payload: &p.payload,
                        },
                        self.arrived.unwrap_or(p.timestamp),
                    );
                }
            }
            (Role::Subscriber { feed }, Event::Connected) => {
                if let Some(f) = self.feeds.get_mut(feed.as_str()) {
                    f.connected = true;
                }
            }
            (Role::Publisher { mid, .. }, Event::MediaAdded(m)) => *mid = Some(m.mid),
            (Role::Publisher { .. }, Event::Connected) => {
                self.stats.publisher_connected = true;
            }
            (_, Event::IceConnectionStateChange(IceConnectionState::Disconnected)) => {
                self.fail(i, "ICE disconnected");
            }
            (_, Event::Closed) => self.conns[i].alive = false,
            _ => {}
        }
    }

    fn publisher(&self) -> Option<usize> {
        self.conns
            .iter()
            .position(|c| matches!(c.role, Role::Publisher { .. }))
    }

    /// The feed left: marked so, and (while `running`) its connection disconnected.
    fn feed_left(&mut self, feed: &str, running: bool) {
        if let Some(f) = self.feeds.get_mut(feed) {
            f.left = true;
        }
        if !running {
            return;
        }
        if let Some(i) = self
            .conns
            .iter()
            .position(|c| matches!(&c.role, Role::Subscriber { feed: f } if f == feed))
        {
            self.conns[i].rtc.disconnect();
            self.after(i, Ok(()));
            self.conns[i].alive = false;
        }
        self.conns.retain(|c| c.alive);
    }

    fn close_all(&mut self) {
        for i in 0..self.conns.len() {
            let result = self.conns[i].rtc.close().map_err(|e| e.to_string());
            self.after(i, result);
        }
        self.conns.clear();
        if let Some((turn, _)) = &mut self.turn {
            turn.close(self.now);
        }
    }

    fn offer(&mut self, now: Instant) -> Result<String, JanusError> {
        if self.publisher().is_some() {
            return Err(JanusError::Media("already publishing".into()));
        }
        let mut rtc = self.new_rtc(false, now)?;
        let mut change = rtc.sdp_api();
        let mid = change.add_media(MediaKind::Audio, Direction::SendOnly, None, None, None);
        let (offer, pending) = change
            .apply()
            .ok_or_else(|| JanusError::Media("str0m made no offer".into()))?;
        let pt = rtc
            .codec_config()
            .params()
            .iter()
            .find_map(|p| (p.spec().codec == str0m::format::Codec::Opus).then(|| p.pt()));
        self.conns.push(Conn {
            rtc,
            role: Role::Publisher {
                pending: Some(pending),
                mid: Some(mid),
                pt,
                time: 0,
            },
            timeout: now,
            alive: true,
        });
        let i = self.conns.len() - 1;
        self.after(i, Ok(()));
        Ok(offer.to_sdp_string())
    }

    fn answer(&mut self, sdp: &str) -> Result<(), JanusError> {
        let i = self
            .publisher()
            .ok_or_else(|| JanusError::Media("an answer without an offer".into()))?;
        let answer = SdpAnswer::from_sdp_string(sdp)
            .map_err(|e| JanusError::Media(format!("Janus's SDP answer: {e}")))?;
        let conn = &mut self.conns[i];
        let Role::Publisher { pending, .. } = &mut conn.role else {
            unreachable!("publisher() finds publishers");
        };
        let pending = pending
            .take()
            .ok_or_else(|| JanusError::Media("the offer was already answered".into()))?;
        let result = conn.rtc.sdp_api().accept_answer(pending, answer);
        let err = result.as_ref().err().map(|e| e.to_string());
        self.after(i, Ok(()));
        match err {
            Some(e) => Err(JanusError::Media(format!("Janus's SDP answer: {e}"))),
            None => Ok(()),
        }
    }

    fn subscribe(
        &mut self,
        feed: String,
        name: String,
        offer: &str,
        now: Instant,
    ) -> Result<String, JanusError> {
        let pt = super::messages::opus_payload_type(offer)
            .ok_or_else(|| JanusError::Media(format!("Janus offers no Opus for {name}")))?;
        let sdp = SdpOffer::from_sdp_string(offer)
            .map_err(|e| JanusError::Media(format!("Janus's SDP offer: {e}")))?;
        let mut rtc = self.new_rtc(true, now)?;
        let answer = rtc
            .sdp_api()
            .accept_offer(sdp)
            .map_err(|e| JanusError::Media(format!("Janus's SDP offer: {e}")))?;
        let payloads = PayloadMap::default()
            .with_assignments(&[format!("opus={pt}")])
            .map_err(|e| JanusError::Media(format!("Opus payload type {pt}: {e}")))?;
        let receiver = PeerReceiver::with_payloads(self.jitter, self.epoch, true, payloads);
        self.feeds.insert(
            feed.clone(),
            Feed {
                name,
                receiver,
                ssrc: None,
                connected: false,
                left: false,
            },
        );
        self.conns.push(Conn {
            rtc,
            role: Role::Subscriber { feed },
            timeout: now,
            alive: true,
        });
        let i = self.conns.len() - 1;
        self.after(i, Ok(()));
        Ok(answer.to_sdp_string())
    }

    fn skip(&mut self, ticks: u32) {
        let Some(i) = self.publisher() else { return };
        if let Role::Publisher { time, .. } = &mut self.conns[i].role {
            *time += u64::from(ticks);
        }
    }

    fn send(&mut self, payload: &[u8], ticks: u32, now: Instant) {
        let Some(i) = self.publisher() else { return };
        let conn = &mut self.conns[i];
        let Role::Publisher { mid, pt, time, .. } = &mut conn.role else {
            return;
        };
        let (Some(mid), Some(pt)) = (*mid, *pt) else {
            return;
        };
        let at = MediaTime::new(*time, Frequency::FORTY_EIGHT_KHZ);
        *time += u64::from(ticks);
        let Some(writer) = conn.rtc.writer(mid) else {
            return;
        };
        // A packet str0m refuses is counted, not a reason to hang up.
        if writer.write(pt, now, at, payload.to_vec()).is_ok() {
            self.stats.published += 1;
        } else {
            self.stats.send_errors += 1;
        }
        // str0m's pacer lets a packet out only at a timeout handled after the last one left:
        // handled here, the packet leaves with this call instead of when the socket thread
        // next wakes (up to 20 ms later on a quiet machine, 60 on a busy one: jitter that
        // every listener has to buffer).
        let now = now.max(self.now);
        self.now = now;
        let result = self.conns[i].rtc.handle_input(Input::Timeout(now));
        self.after(i, result.map_err(|e| e.to_string()));
    }

    /// The next 20 ms of every subscribed publisher that is playing.
    fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) {
        feeds::pull(&mut self.feeds, &mut self.departed, now, out);
    }

    fn feeds(&self) -> Vec<FeedInfo> {
        feeds::infos(&self.feeds, &self.departed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_offer_carries_the_address_stun_saw() {
        let local: SocketAddr = "10.0.0.5:40000".parse().unwrap();
        let public: SocketAddr = "198.51.100.7:61000".parse().unwrap();
        let now = Instant::now();
        let mut core = MediaCore::new(vec![local], JitterConfig::default(), now);
        let plain = core.offer(now).unwrap();
        assert!(plain.contains("typ host"), "{plain}");
        assert!(!plain.contains("typ srflx"), "{plain}");
        let mut core = MediaCore::new(vec![local], JitterConfig::default(), now);
        core.reflexive = Some((public, local));
        let offer = core.offer(now).unwrap();
        assert!(offer.contains("198.51.100.7 61000 typ srflx"), "{offer}");
        assert!(offer.contains("10.0.0.5 40000 typ host"), "{offer}");
    }

    #[test]
    fn a_relay_only_offer_carries_the_relay_alone() {
        use crate::net::turn::TurnConfig;
        let local: SocketAddr = "10.0.0.5:40000".parse().unwrap();
        let now = Instant::now();
        let mut core = MediaCore::new(vec![local], JitterConfig::default(), now);
        core.relay_only = true;
        let config = TurnConfig {
            server: "192.0.2.10:3478".parse().unwrap(),
            username: "ann".into(),
            password: "secret".into(),
        };
        core.turn = Some((TurnClient::new(config, now), local));
        // Until the relay is allocated there is nothing to offer.
        assert!(core.offer(now).is_err());
        let relayed: SocketAddr = "192.0.2.10:50000".parse().unwrap();
        let turn = &mut core.turn.as_mut().unwrap().0;
        let request = turn.poll_transmit().unwrap();
        turn.handle(&crate::net::turn::tests::allocated(&request, relayed), now);
        let offer = core.offer(now).unwrap();
        let candidates: Vec<&str> = offer.lines().filter(|l| l.contains("candidate")).collect();
        assert_eq!(candidates.len(), 1, "{offer}");
        assert!(
            candidates[0].contains("192.0.2.10 50000 typ relay"),
            "{offer}"
        );
    }
}
