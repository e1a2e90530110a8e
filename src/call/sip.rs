//! A SIP phone call as a call's [`Link`]: the user agent ([`crate::net::sip::agent`]) on its
//! own thread, and once SDP has agreed a codec and an address, the call's RTP: a session
//! configured for the negotiated call ([`crate::net::sip::media`]) on the socket our SDP
//! named, its RTCP on the port above (or on the same one, where both sides agree to
//! multiplex). The caller is one peer like any
//! other: its frames come from the same jitter buffer and decoders, its reports tell the loss
//! it sees of ours.

use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::events::LinkEvents;
use super::link::{Link, LinkEvent};
use super::media::Packets;
use super::sip_sockets::{MediaSockets, bind_media};
use crate::codec::any::{Codec, EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD};
use crate::net::rtcp::HeardReports;
use crate::net::session::{Session, SessionStats, event_code};
use crate::net::sip::agent::{Account, Agent, AgentConfig, AgentEvent, Decision, Role, SipError};
use crate::net::sip::media;
use crate::net::sip::sdp::{LocalAudio, Negotiated, SdesKey};
use crate::net::sip::transport::SrtpPolicy;
use crate::net::transport::{PeerFrame, PeerInfo};

/// How long a hang-up waits for the peer to confirm it.
const HANG_UP_WAIT: Duration = Duration::from_secs(3);
/// Events waiting for a poll at most (a peer's flood of provisional answers or re-INVITEs
/// between two polls drops the oldest progress lines, never the call's start or end).
const MOST_EVENTS: usize = 64;
/// Our side of the call is silence once its owner has sent nothing for this long
/// ([`SipLink::keep_stream`]).
const QUIET_AFTER: Duration = Duration::from_millis(60);

/// Where a call stands.
#[derive(Debug, Clone, PartialEq)]
pub enum CallState {
    /// Registering, dialling, ringing or waiting for a caller.
    Setting,
    Established,
    Ended {
        by_peer: bool,
    },
    Failed(SipError),
}

/// What protects a call: whether its media is SRTP, and the authority its TLS server's
/// certificate may be signed by beside the system's roots (PEM).
#[derive(Debug, Clone, Default)]
pub struct SipSecurity {
    pub srtp: SrtpPolicy,
    pub ca: Option<Vec<u8>>,
}

/// One SIP call.
pub struct SipLink {
    agent: Agent,
    /// Our RTP and RTCP sockets until the media starts on them.
    socket: Option<UdpSocket>,
    rtcp_socket: Option<UdpSocket>,
    local_rtp: SocketAddr,
    local_rtcp: Option<SocketAddr>,
    /// Our SRTP key, used where SDP agrees SRTP.
    key: SdesKey,
    rtp: Option<Session>,
    negotiated: Option<Negotiated>,
    state: CallState,
    /// Who the peer is (the dialled URI, or the caller).
    peer: String,
    /// The call was answered (not only ringing with early media).
    answered: bool,
    /// Incoming calls wait for [`SipLink::decide`] ([`Role::Ask`]).
    asks: bool,
    /// The caller whose call rings, waiting for the owner's decision.
    ringing: Option<String>,
    /// What happened since the last poll: progress lines for the user (registered, ringing,
    /// a caller), the media agreed, the call's start and end.
    events: LinkEvents,
    handle: SipHandle,
    /// Silence sent where the owner sends nothing ([`SipLink::keep_stream`]).
    quiet: Option<QuietFill>,
    /// The codec and SRTP last told ([`LinkEvent::Media`]).
    media_told: Option<(Codec, bool)>,
    /// Audio played into the call ([`SipLink::play`]).
    playing: Option<Playing>,
}

/// Encoded audio sent in real time from the answer on.
struct Playing {
    packets: Packets,
    next: usize,
    /// When the first packet went (or would have gone) out.
    start: Instant,
    sent_ticks: u64,
}

/// What the owner of a call asks of it beside [`Link`]: DTMF keys, and whether the keypad
/// works. Cheap to clone; the call's link sends what was asked as it is pulled.
#[derive(Clone, Debug, Default)]
pub struct SipHandle(Arc<HandleShared>);

#[derive(Debug, Default)]
struct HandleShared {
    keys: Mutex<String>,
    takes_keys: AtomicBool,
    established: AtomicBool,
}

/// DTMF keys waiting to be sent at most (a key lasts about a tenth of a second).
const MAX_QUEUED_KEYS: usize = 64;

impl SipHandle {
    /// Queues DTMF keys; false where the peer agreed no telephone-events, a key is none, or
    /// too many wait already.
    pub fn send_digits(&self, keys: &str) -> bool {
        if !self.0.takes_keys.load(Ordering::Relaxed)
            || keys.chars().any(|k| event_code(k).is_none())
        {
            return false;
        }
        let mut queued = self.0.keys.lock().unwrap_or_else(|e| e.into_inner());
        if queued.len() + keys.len() > MAX_QUEUED_KEYS {
            return false;
        }
        queued.push_str(keys);
        true
    }

    /// The call is established and its peer takes DTMF events (RFC 4733).
    pub fn keypad(&self) -> bool {
        self.0.established.load(Ordering::Relaxed) && self.0.takes_keys.load(Ordering::Relaxed)
    }

    fn take_keys(&self) -> String {
        std::mem::take(&mut *self.0.keys.lock().unwrap_or_else(|e| e.into_inner()))
    }
}

/// Silence in the call's codec for the frames nobody sends.
struct QuietFill {
    encoder: Option<FrameEncoder>,
    /// When the owner last sent (or skipped) a frame of ours.
    ours_at: Instant,
}

impl std::fmt::Debug for SipLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SipLink")
            .field("state", &self.state)
            .finish_non_exhaustive()
    }
}

impl SipLink {
    /// Starts the user agent; `socket` is the RTP socket whose address `config.audio` gives,
    /// `rtcp` the RTCP socket (where it has one of its own).
    pub fn start(
        config: AgentConfig,
        socket: UdpSocket,
        rtcp: Option<UdpSocket>,
        peer: String,
    ) -> Result<Self, SipError> {
        let local_rtp = socket.local_addr().map_err(|e| SipError::Bind {
            addr: config.audio.addr,
            why: e.to_string(),
        })?;
        let local_rtcp = rtcp.as_ref().and_then(|s| s.local_addr().ok());
        let key = config.audio.key.clone();
        let asks = config.role == Role::Ask;
        let agent = Agent::start(config)?;
        Ok(Self {
            agent,
            socket: Some(socket),
            rtcp_socket: rtcp,
            local_rtp,
            local_rtcp,
            key,
            rtp: None,
            negotiated: None,
            state: CallState::Setting,
            answered: false,
            peer,
            asks,
            ringing: None,
            events: LinkEvents::new(MOST_EVENTS),
            handle: SipHandle::default(),
            quiet: None,
            media_told: None,
            playing: None,
        })
    }

    /// A call on `bind` (SIP over UDP) with its media on [`bind_media`]'s sockets, SDP
    /// offering or taking `codecs` (and SRTP with a fresh key where `srtp`); with a `stun`
    /// server (HOST:PORT), the SDP gives the media address that server sees. Asking STUN
    /// blocks (up to 1.5 s): the app binds with [`bind_media`] off its worker and calls
    /// [`SipLink::open_with`].
    pub fn open(
        bind: SocketAddr,
        account: Option<Account>,
        role: Role,
        codecs: Vec<Codec>,
        frame_ms: u8,
        security: &SipSecurity,
        stun: Option<&str>,
    ) -> Result<Self, SipError> {
        let media = bind_media(bind, stun)?;
        Self::open_with(bind, account, role, codecs, frame_ms, security, media)
    }

    /// [`SipLink::open`] on media sockets already bound.
    pub fn open_with(
        bind: SocketAddr,
        account: Option<Account>,
        role: Role,
        codecs: Vec<Codec>,
        frame_ms: u8,
        security: &SipSecurity,
        media: MediaSockets,
    ) -> Result<Self, SipError> {
        let MediaSockets {
            rtp: socket,
            rtcp,
            addr,
            rtcp_addr,
        } = media;
        let cannot = |why: String| SipError::Bind { addr, why };
        let audio = LocalAudio {
            addr,
            rtcp: Some(rtcp_addr),
            codecs,
            session_id: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(1, |d| d.as_secs()),
            key: SdesKey::random().map_err(|e| cannot(format!("no randomness for a key: {e}")))?,
            offer_srtp: false,
            frame_ms,
        };
        let peer = match &role {
            Role::Call(target) => target.clone(),
            Role::Answer | Role::Ask => "the caller".to_owned(),
        };
        let mut config = AgentConfig {
            bind,
            account,
            audio,
            role,
            ca: security.ca.clone(),
            srtp: security.srtp,
        };
        config.audio.offer_srtp = security.srtp.offers(config.transport()?);
        Self::start(config, socket, Some(rtcp), peer)
    }

    /// The caller whose call rings until [`SipLink::decide`] says what to do with it.
    pub fn ringing(&self) -> Option<&str> {
        self.ringing.as_deref()
    }

    /// Answers or refuses the ringing call.
    pub fn decide(&mut self, decision: Decision) {
        self.ringing = None;
        self.agent.decide(decision);
    }

    /// Who the peer is: the dialled URI, or the caller once one came.
    pub fn peer(&self) -> &str {
        &self.peer
    }

    pub fn state(&self) -> &CallState {
        &self.state
    }

    /// What SDP agreed, once it has.
    pub fn negotiated(&self) -> Option<&Negotiated> {
        self.negotiated.as_ref()
    }

    /// What the owner may ask of the call beside [`Link`] ([`SipHandle`]).
    pub fn handle(&self) -> SipHandle {
        self.handle.clone()
    }

    /// Where the owner has nothing to say (its microphone's gate closed, or no microphone),
    /// silence goes out in the call's codec: phones expect a steady stream, their jitter
    /// buffers hold back the last packets (a DTMF key's end included) until more come, and
    /// the stream keeps a NAT's binding open.
    pub fn keep_stream(&mut self) {
        self.quiet = Some(QuietFill {
            encoder: None,
            ours_at: Instant::now(),
        });
    }

    /// Plays `packets` (in the codec agreed) into the call, in real time from the answer on
    /// (not while early media plays), as the link is pulled.
    pub fn play(&mut self, packets: Packets) {
        self.playing = Some(Playing {
            packets,
            next: 0,
            start: Instant::now(),
            sent_ticks: 0,
        });
    }

    /// The packets of [`SipLink::play`] now due.
    fn send_due(&mut self) {
        let (Some(mut playing), Some(codec)) = (self.playing.take(), self.codec()) else {
            return;
        };
        if !self.answered {
            playing.start = Instant::now();
        }
        let clock = f64::from(codec.clock_rate());
        let elapsed = playing.start.elapsed();
        while let Some((payload, ticks)) = playing.packets.get(playing.next) {
            if Duration::from_secs_f64(playing.sent_ticks as f64 / clock) > elapsed {
                break;
            }
            self.send_packet(payload, *ticks);
            playing.sent_ticks += u64::from(*ticks);
            playing.next += 1;
        }
        self.playing = Some(playing);
    }

    fn say(&mut self, line: String) {
        self.events.push(LinkEvent::Progress(line));
    }

    /// The media once answered, when it changed.
    fn tell_media(&mut self) {
        let media = self
            .negotiated
            .as_ref()
            .filter(|_| self.answered)
            .map(|n| (n.codec, n.srtp.is_some()));
        if let Some((codec, srtp)) = media
            && media != self.media_told
        {
            self.media_told = media;
            self.events.push(LinkEvent::Media { codec, srtp });
        }
    }

    fn send_silence(&mut self, frames: u32) {
        let Some(codec) = self.codec().filter(|_| self.answered) else {
            return;
        };
        let Some(mut quiet) = self.quiet.take() else {
            return;
        };
        if quiet.encoder.as_ref().is_none_or(|e| e.codec() != codec) {
            quiet.encoder = FrameEncoder::new(codec, &EncoderSettings::default()).ok();
        }
        if let Some(encoder) = &mut quiet.encoder {
            let silence = vec![0i16; encoder.frame_samples()];
            let mut payload = [0u8; MAX_FRAME_PAYLOAD];
            for _ in 0..frames {
                if let Ok(Some((n, ticks))) = encoder.encode(&silence, &mut payload) {
                    self.send_packet(&payload[..n], ticks);
                }
            }
        }
        self.quiet = Some(quiet);
    }

    pub fn rtp_stats(&self) -> SessionStats {
        self.rtp.as_ref().map(Session::stats).unwrap_or_default()
    }

    /// What the peer's reports said: the loss it sees of our stream, the round trip.
    pub fn heard(&self) -> HeardReports {
        self.rtp
            .as_ref()
            .map(|r| r.with(|c| c.heard()))
            .unwrap_or_default()
    }

    /// Follows the agent for up to `wait` (or only what is there, with zero).
    pub fn follow(&mut self, wait: Duration) {
        let mut next = if wait.is_zero() {
            self.agent.try_event()
        } else {
            self.agent.next_event(wait)
        };
        while let Some(event) = next {
            self.on_agent_event(event);
            next = self.agent.try_event();
        }
    }

    fn on_agent_event(&mut self, event: AgentEvent) {
        match event {
            AgentEvent::Listening(addr, transport) => {
                tracing::info!(
                    "SIP on {addr} ({}), RTP on {}, RTCP on {:?}",
                    transport.name(),
                    self.local_rtp,
                    self.local_rtcp
                );
                self.say(format!(
                    "using SIP on {addr} over {}, sound on port {}",
                    transport.name(),
                    self.local_rtp.port()
                ));
            }
            AgentEvent::Registered(registrar) => {
                self.say(format!("registered with {registrar}"));
            }
            AgentEvent::Incoming(from) if self.asks => {
                self.say(format!("call from {from}"));
                self.peer = from.clone();
                self.ringing = Some(from);
            }
            AgentEvent::Incoming(from) => {
                self.peer = from.clone();
                self.say(format!("call from {from}; answering"));
            }
            AgentEvent::Ringing => {
                self.say(format!("{} is ringing", self.peer));
                self.events.push(LinkEvent::Ringing);
            }
            AgentEvent::EarlyMedia => {
                self.say(format!("{} sends early media before answering", self.peer));
            }
            AgentEvent::Media(negotiated) => self.media(*negotiated),
            AgentEvent::Established => {
                self.ringing = None;
                self.state = CallState::Established;
                self.answered = true;
                self.handle.0.established.store(true, Ordering::Relaxed);
                self.tell_media();
                self.events.push(LinkEvent::Joined {
                    place: format!("a SIP call with {}", self.peer),
                    id: self.local_rtp.to_string(),
                });
            }
            AgentEvent::Ended { by_peer } => {
                self.ringing = None;
                self.say_bye();
                if self.state == CallState::Established {
                    self.events.push(LinkEvent::PeerLeft {
                        id: self.peer.clone(),
                        name: self.peer.clone(),
                    });
                }
                self.events.push(LinkEvent::Ended {
                    reason: if by_peer {
                        format!("{} hung up", self.peer)
                    } else {
                        format!("the call to {} ended", self.peer)
                    },
                });
                self.handle.0.established.store(false, Ordering::Relaxed);
                self.state = CallState::Ended { by_peer };
            }
            AgentEvent::Failed(e) => {
                self.ringing = None;
                self.handle.0.established.store(false, Ordering::Relaxed);
                self.events.push(LinkEvent::Failed(e.to_string()));
                self.state = CallState::Failed(e);
            }
        }
    }

    fn media(&mut self, negotiated: Negotiated) {
        self.say(format!(
            "media: {} (payload type {}) with {} (RTCP {}){}{}",
            negotiated.codec,
            negotiated.payload_type,
            negotiated.remote,
            if negotiated.rtcp_mux {
                "multiplexed".to_owned()
            } else {
                format!("to {}", negotiated.rtcp)
            },
            if negotiated.events.is_some() {
                ", DTMF events"
            } else {
                ""
            },
            if negotiated.srtp.is_some() {
                ", SRTP (keys exchanged in SDP)"
            } else {
                ", NOT encrypted (plain RTP)"
            }
        ));
        match (&self.rtp, self.socket.take()) {
            (Some(rtp), _) => {
                let previous = self.negotiated.as_ref().unwrap_or(&negotiated);
                rtp.with(|core| media::renegotiate(core, previous, &negotiated));
            }
            (None, Some(socket)) => {
                match media::start(socket, self.rtcp_socket.take(), &negotiated, &self.key) {
                    Ok(rtp) => self.rtp = Some(rtp),
                    Err(e) => {
                        let e = SipError::Protocol(format!("cannot start the call's RTP: {e}"));
                        self.events.push(LinkEvent::Failed(e.to_string()));
                        self.state = CallState::Failed(e);
                        self.agent.hang_up();
                    }
                }
            }
            (None, None) => {}
        }
        self.handle
            .0
            .takes_keys
            .store(negotiated.events.is_some(), Ordering::Relaxed);
        self.negotiated = Some(negotiated);
        self.tell_media();
    }

    /// The codec our audio must be sent in, once agreed.
    pub fn codec(&self) -> Option<Codec> {
        self.negotiated.as_ref().map(|n| n.codec)
    }

    /// Whether the call was answered (early media alone is not).
    pub fn answered(&self) -> bool {
        self.answered
    }

    /// Sends one payload of the agreed codec lasting `ticks` (once answered: early media
    /// flows one way).
    pub fn send_packet(&self, payload: &[u8], ticks: u32) {
        if self.state != CallState::Established {
            return;
        }
        if let Some(rtp) = &self.rtp
            && let Err(e) = rtp.send_packet(payload, ticks)
        {
            tracing::debug!("SIP RTP: {e}");
        }
    }

    /// Queues DTMF keys; false where the peer agreed no telephone-events (or a key is none).
    pub fn send_digits(&self, keys: &str) -> bool {
        self.rtp
            .as_ref()
            .is_some_and(|rtp| rtp.with(|c| c.queue_digits(keys)))
    }

    pub fn digits_sent(&self) -> bool {
        self.rtp
            .as_ref()
            .is_none_or(|r| r.with(|c| c.digits_sent()))
    }

    /// RTCP's BYE with our last report (once), as the call ends.
    fn say_bye(&self) {
        if let Some(rtp) = &self.rtp {
            rtp.leave();
        }
    }

    /// Hangs up (our last RTCP report first) and waits (a little) for the peer to confirm.
    pub fn hang_up(&mut self) {
        self.say_bye();
        self.agent.hang_up();
        if !self.agent.wait(HANG_UP_WAIT) {
            tracing::warn!("the SIP peer did not confirm the hang-up");
        }
        self.follow(Duration::ZERO);
        if let Some(rtp) = &mut self.rtp {
            rtp.stop();
        }
    }

    fn ended(&self) -> bool {
        matches!(self.state, CallState::Ended { .. } | CallState::Failed(_))
    }
}

impl Link for SipLink {
    fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) {
        if self
            .quiet
            .as_ref()
            .is_some_and(|q| q.ours_at.elapsed() >= QUIET_AFTER)
        {
            self.send_silence(1);
        }
        self.send_due();
        let keys = self.handle.take_keys();
        if let Some(rtp) = &self.rtp {
            rtp.with(|core| {
                if !keys.is_empty() && !core.queue_digits(&keys) {
                    tracing::debug!("DTMF {keys:?} not sent: the peer takes no events");
                }
                if let Err(e) = core.step_digits(Instant::now()) {
                    tracing::debug!("DTMF: {e}");
                }
                core.pull(now, out);
            });
        }
    }

    fn peers(&self) -> Vec<PeerInfo> {
        let Some(rtp) = &self.rtp else {
            return Vec::new();
        };
        let mut peers = rtp.peers();
        for peer in &mut peers {
            peer.name = Some(self.peer.clone());
            peer.said_bye = self.ended();
            peer.ended = self.ended();
        }
        peers
    }

    fn all_left(&self) -> bool {
        self.ended()
    }

    fn send_audio(&mut self, payload: &[u8], ticks: u32) {
        if let Some(quiet) = &mut self.quiet {
            quiet.ours_at = Instant::now();
        }
        if self.codec().is_some() {
            self.send_packet(payload, ticks);
        }
    }

    fn skip_frames(&mut self, frames: u32) {
        if let Some(quiet) = &mut self.quiet {
            quiet.ours_at = Instant::now();
            self.send_silence(frames);
            return;
        }
        if let Some(rtp) = &self.rtp {
            rtp.skip_frames(frames);
        }
    }

    fn unknown_payload(&self) -> u64 {
        self.rtp_stats().unknown_payload
    }

    fn leave(&mut self) {
        if !self.ended() {
            self.hang_up();
        }
    }

    fn poll(&mut self) -> Vec<LinkEvent> {
        self.follow(Duration::ZERO);
        self.events.take()
    }

    fn over(&self) -> bool {
        self.ended()
    }

    fn local_addr(&self) -> Option<SocketAddr> {
        Some(self.local_rtp)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_handle_takes_keys_only_where_the_peer_takes_events_and_queues_a_bounded_few() {
        let handle = SipHandle::default();
        assert!(!handle.send_digits("1"), "no telephone-event agreed");
        handle.0.takes_keys.store(true, Ordering::Relaxed);
        assert!(!handle.keypad(), "not established yet");
        assert!(handle.send_digits("12#*"));
        assert!(!handle.send_digits("1x"), "x is no DTMF key");
        assert!(!handle.send_digits(&"5".repeat(MAX_QUEUED_KEYS)));
        assert_eq!(handle.take_keys(), "12#*");
        assert!(handle.send_digits(&"5".repeat(MAX_QUEUED_KEYS)));
        handle.0.established.store(true, Ordering::Relaxed);
        assert!(handle.keypad());
    }
}
