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
use crate::codec::any::Codec;

mod blocked;
mod call;
mod dtmf;
mod inbound;
pub mod latch;
mod negotiated;
mod protocol;
mod remote;
mod timers;
mod types;

pub use blocked::{BLOCK_LONGEST, BLOCK_QUIET, BLOCKS_KEPT, Blocked};
pub use call::{CALL_KEEPALIVE, STREAM_HANDOVER};
pub use dtmf::event_code;
pub use protocol::{LARGEST_DATAGRAM, MAX_ANSWERED, SessionCore};
pub use types::{NegotiatedCall, SessionConfig, SessionStats};

use super::transport::{Driver, PeerFrame, PeerId, PeerInfo, SansIo, Transmit, TransmitKind};

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
        Self::on_sockets(socket, None, config)
    }

    /// A session on `socket` already bound (`config.bind` unused), its RTCP on `rtcp` where
    /// it has a port of its own (a negotiated call's).
    pub fn on_sockets(
        socket: UdpSocket,
        rtcp: Option<UdpSocket>,
        config: SessionConfig,
    ) -> Result<Self, NetError> {
        let local = socket
            .local_addr()
            .map_err(|e| NetError::io("local address", e))?;
        let encrypted = config.key.is_some();
        let core = SessionCore::new(config, local, Instant::now())?;
        let (ssrc, epoch) = (core.ssrc(), core.epoch());
        let driver = Driver::start_with_rtcp(socket, rtcp, core, "lipcall-net", POLL)
            .map_err(|e| NetError::io("cannot start the network thread", e))?;
        Ok(Self {
            driver,
            ssrc,
            epoch,
            encrypted,
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
        self.driver.access(|core| core.config().codec)
    }

    /// Sends one payload of the session's codec holding `frames` 20 ms frames to every
    /// destination.
    pub fn send_frames(&self, payload: &[u8], frames: u32) -> Result<(), NetError> {
        self.driver.with(|core| {
            let ticks = core.config().codec.frame_ticks() * frames.max(1);
            core.send_packet(payload, ticks, Instant::now())
        })
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

    /// A listening session sends to the callers `to` as well, in `codec` where it can
    /// ([`SessionCore::answer`]); says the codec it sends.
    pub fn answer(&self, to: &[SocketAddr], codec: Codec) -> Codec {
        self.driver.access(|core| core.answer(to, codec))
    }

    /// The user hung up on the caller at `addr` ([`SessionCore::hang_up_on`]).
    pub fn hang_up_on(&self, addr: SocketAddr) {
        self.driver
            .with(|core| core.hang_up_on(addr, Instant::now()));
    }

    /// The callers kept out ([`Blocked`]).
    pub fn blocked(&self) -> Blocked {
        self.driver.access(|core| core.blocked().clone())
    }

    /// Keeps out those `blocked` keeps out (the session before's).
    pub fn keep_blocked(&self, blocked: Blocked) {
        self.driver.access(|core| core.keep_blocked(blocked));
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

    /// Runs `f` on the core, then sends what it queued (what only some sessions use: a
    /// negotiated call's DTMF, renegotiation, reports heard).
    pub fn with<T>(&self, f: impl FnOnce(&mut SessionCore) -> T) -> T {
        self.driver.with(f)
    }

    /// Stops the socket thread (after [`Self::leave`]); the core's figures stay readable.
    pub fn stop(&mut self) {
        self.driver.stop();
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
