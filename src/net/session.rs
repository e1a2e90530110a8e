//! A call session: any number of remote peers (each identified by SSRC, its address noted),
//! RTCP reports, optional SRTP and an optional relay room, on one UDP socket.
//!
//! The rules live in [`SessionCore`], which does no I/O: datagrams and the time go in,
//! datagrams to send and decoded frames come out (as the relay's [`crate::net::relay::RelayCore`]
//! does). [`Session`] is its driver: one thread reads the socket and runs the core's timers (no
//! async runtime), and the owner's calls go to the same core.
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

use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use super::NetError;
use super::control::Refusal;
use super::jitter::JitterConfig;
use super::peer::{PlayedFrame, ReceiverStats};
use super::srtp::{DEFAULT_CLOCK_TOLERANCE, MasterKey};
use crate::codec::any::{Codec, PayloadMap};

pub(crate) mod driver;
mod inbound;
mod protocol;
mod timers;

use driver::{Driver, SansIo};
pub use driver::{Transmit, TransmitKind};
pub use protocol::{LARGEST_DATAGRAM, SessionCore};

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
/// How long the socket thread waits at most for a datagram before it looks at whether to stop.
const POLL: Duration = Duration::from_millis(10);

impl SansIo for SessionCore {
    // One byte over the largest datagram taken: one that fills the buffer was cut short.
    const BUFFER: usize = LARGEST_DATAGRAM + 1;

    fn handle_datagram(&mut self, data: &[u8], from: SocketAddr, now: Instant) {
        SessionCore::handle_datagram(self, data, from, now);
    }

    fn poll_timeout(&self) -> Instant {
        SessionCore::poll_timeout(self)
    }

    fn handle_timeout(&mut self, now: Instant) {
        SessionCore::handle_timeout(self, now);
    }

    fn poll_transmit(&mut self) -> Option<Transmit> {
        SessionCore::poll_transmit(self)
    }

    fn transmitted(&mut self, transmit: Transmit, sent: bool) {
        SessionCore::transmitted(self, transmit, sent);
    }
}

/// A running session: a [`SessionCore`] driven by a socket thread. Dropping it says BYE and
/// stops the thread.
pub struct Session {
    driver: Driver<SessionCore>,
    ssrc: u32,
    epoch: Instant,
    encrypted: bool,
    codec: Codec,
}

impl std::fmt::Debug for Session {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Session")
            .field("ssrc", &self.ssrc)
            .finish_non_exhaustive()
    }
}

impl Session {
    pub fn start(config: SessionConfig) -> Result<Self, NetError> {
        let socket = UdpSocket::bind(config.bind)
            .map_err(|e| NetError::io(format!("cannot listen on {}", config.bind), e))?;
        let local = socket
            .local_addr()
            .map_err(|e| NetError::io("local address", e))?;
        let (encrypted, codec) = (config.key.is_some(), config.codec);
        let core = SessionCore::new(config, local, Instant::now())?;
        let (ssrc, epoch) = (core.ssrc(), core.epoch());
        let driver = Driver::start(socket, core, "lipcall-net", POLL)
            .map_err(|e| NetError::io("cannot start the network thread", e))?;
        Ok(Self {
            driver,
            ssrc,
            epoch,
            encrypted,
            codec,
        })
    }

    pub fn local_addr(&self) -> Result<SocketAddr, NetError> {
        self.driver
            .socket()
            .local_addr()
            .map_err(|e| NetError::io("local address", e))
    }

    pub fn ssrc(&self) -> u32 {
        self.ssrc
    }

    /// The instant the session's jitter buffers measure time from.
    pub fn epoch(&self) -> Instant {
        self.epoch
    }

    pub fn encrypted(&self) -> bool {
        self.encrypted
    }

    /// The codec this session sends.
    pub fn codec(&self) -> Codec {
        self.codec
    }

    /// Sends one payload of the session's codec holding `frames` 20 ms frames to every
    /// destination.
    pub fn send_frames(&self, payload: &[u8], frames: u32) -> Result<(), NetError> {
        let ticks = self.codec.frame_ticks() * frames.max(1);
        self.send_packet(payload, ticks)
    }

    /// Sends one payload of the session's codec lasting `ticks` of its RTP clock (an Opus
    /// packet of 60 ms: 2880) to every destination.
    pub fn send_packet(&self, payload: &[u8], ticks: u32) -> Result<(), NetError> {
        self.driver
            .with(|core| core.send_packet(payload, ticks, Instant::now()))
    }

    /// Frames not sent (silence, mute): the timestamp moves on and the next packet starts a
    /// new talk spurt.
    pub fn skip_frames(&self, frames: u32) {
        self.driver.access(|core| core.skip_frames(frames));
    }

    /// Pulls the next 20 ms (starting at `now` on the output clock) from every peer that is
    /// playing, appending to `out`.
    pub fn pull(&self, now: Instant, out: &mut Vec<PeerFrame>) {
        self.driver.access(|core| core.pull(now, out));
    }

    pub fn stats(&self) -> SessionStats {
        self.driver.access(|core| core.stats())
    }

    pub fn peers(&self) -> Vec<PeerInfo> {
        self.driver.access(|core| core.peers())
    }

    /// Sends a report now (normally the network thread does so every `rtcp_interval`).
    pub fn send_report(&self) {
        self.driver
            .with(|core| core.send_periodic_report(Instant::now()));
    }

    /// Says BYE (with a final SR marking where the stream ends) and leaves the relay room.
    pub fn leave(&self) {
        self.driver.with(|core| core.leave(Instant::now()));
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        self.leave();
        self.driver.stop();
    }
}

#[cfg(test)]
mod tests;
