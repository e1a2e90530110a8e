//! A Mumble client without I/O: what the server said (control messages from the TLS stream,
//! datagrams from UDP) goes in, what to send (framed control messages, encrypted datagrams)
//! and what happened (events, each speaker's frames) comes out. The connection
//! ([`super::connection`]) drives it from its TLS thread and the UDP socket thread.
//!
//! Voice goes by UDP once a UDP ping has come back through the server's crypt state, and
//! through the TLS stream (UDPTunnel) before that, when UDP is blocked, or when asked to. A
//! server whose datagrams stop decrypting is asked for fresh nonces (an empty CryptSetup), at
//! most every 5 s, as Mumble's own client does.
//!
//! Each speaker (session id) gets a [`PeerReceiver`], the jitter buffer and Opus decoder every
//! other transport uses: its voice packets are handed over as RTP on the 48 kHz clock, one
//! sequence number per packet, the marker on the first packet of a talk spurt.
//!
//! Whatever a server can make grow is bounded: users and channels have caps, a removed user
//! is freed at once (a speaker once their audio played out), who came and went is worked out
//! when asked ([`ClientCore::report_presence`]) rather than queued per message, news beyond a
//! budget is counted instead of said, and a server silent for [`SERVER_SILENT`] counts as lost.

use std::collections::{BTreeMap, VecDeque};
use std::net::SocketAddr;
use std::time::{Duration, Instant};

use super::MumbleError;
use super::crypt::CryptState;
pub use super::events::{Channel, ClientConfig, ClientEvent, ClientStats};
use super::events::{News, NewsBudget, describe_reject};
use super::messages::{
    self, Authenticate, CryptSetup, Deframer, Incoming, MessageType, Ping, UserState, Version,
};
use super::speakers::{Room, Speaker, Speakers, User};
use super::voice::{self, ServerPacket};
use crate::codec::any::PayloadMap;
use crate::net::peer::PeerReceiver;
use crate::net::transport::{PeerFrame, Transmit, TransmitKind};

/// What we announce: 1.3.4, so that 1.5 servers answer with the legacy voice format.
pub const ANNOUNCED_VERSION: u32 = messages::version(1, 3, 4);
/// Between UDP pings, and between TCP pings (murmur drops a client silent for 30 s).
const PING_INTERVAL: Duration = Duration::from_secs(5);
/// UDP counts as working while a datagram came back within this.
const UDP_FRESH: Duration = Duration::from_secs(12);
/// How long the first UDP ping may take to come back before the tunnel is used.
const FIRST_PING_ANSWER: Duration = Duration::from_secs(1);
/// At most one request for fresh nonces in this.
const RESYNC_EVERY: Duration = Duration::from_secs(5);
/// A server that sent nothing for this long (four pings unanswered) counts as lost.
pub const SERVER_SILENT: Duration = Duration::from_secs(20);
/// The longest text message or refusal said (in bytes; longer ones are cut).
const MAX_TEXT: usize = 1000;

/// The protocol state of one server connection (and, after a reconnect, the next).
pub struct ClientCore {
    pub(super) config: ClientConfig,
    server: SocketAddr,
    epoch: Instant,
    deframer: Deframer,
    control: VecDeque<Vec<u8>>,
    datagrams: VecDeque<Transmit>,
    pub(super) events: VecDeque<ClientEvent>,
    pub(super) session: Option<u32>,
    connected: bool,
    pub(super) channels: BTreeMap<u32, Channel>,
    pub(super) users: BTreeMap<u32, User>,
    pub(super) speakers: Speakers,
    /// Who in our channel the owner was told of, by session.
    pub(super) reported: BTreeMap<u32, String>,
    /// Users or our channel changed since the last report.
    pub(super) presence_changed: bool,
    pub(super) news: NewsBudget,
    /// When the server last sent anything on the TLS stream.
    heard_server: Instant,
    /// Our self-mute as last asked for (none asked: the server's default, unmuted).
    pub(super) self_mute: Option<bool>,
    /// What the server was last told of it, and when.
    pub(super) self_mute_told: Option<(bool, Instant)>,
    crypt: Option<CryptState>,
    udp_heard: Option<Instant>,
    udp_working: bool,
    /// A UDP ping went out on this connection.
    pinged_once: bool,
    next_ping: Instant,
    resync_asked: Option<Instant>,
    send_sequence: u64,
    welcome: String,
    /// The server removed us (kicked, banned, or the same name connected from this address):
    /// why. Not rejoined.
    kicked: Option<String>,
    /// A protocol error that ends the connection.
    fatal: Option<MumbleError>,
    pub stats: ClientStats,
}

impl std::fmt::Debug for ClientCore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClientCore")
            .field("session", &self.session)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl ClientCore {
    pub fn new(config: ClientConfig, server: SocketAddr, now: Instant) -> Self {
        Self {
            config,
            server,
            epoch: now,
            deframer: Deframer::default(),
            control: VecDeque::new(),
            datagrams: VecDeque::new(),
            events: VecDeque::new(),
            session: None,
            connected: false,
            channels: BTreeMap::new(),
            users: BTreeMap::new(),
            speakers: Speakers::default(),
            reported: BTreeMap::new(),
            presence_changed: false,
            news: NewsBudget::default(),
            heard_server: now,
            self_mute: None,
            self_mute_told: None,
            crypt: None,
            udp_heard: None,
            udp_working: false,
            pinged_once: false,
            next_ping: now,
            resync_asked: None,
            send_sequence: 0,
            welcome: String::new(),
            kicked: None,
            fatal: None,
            stats: ClientStats::default(),
        }
    }

    /// A TLS connection is up: say who we are. Everything of an earlier connection (session,
    /// keys, users) is forgotten.
    pub fn connected(&mut self, now: Instant) {
        self.deframer = Deframer::default();
        self.control.clear();
        self.session = None;
        self.connected = true;
        self.crypt = None;
        self.udp_heard = None;
        self.set_udp(false);
        self.fatal = None;
        self.heard_server = now;
        self.channels.clear();
        // Session ids start afresh on a restarted server: an old speaker's id may be a new
        // one's. (What was still buffered of the old ones is dropped; the loss cut it anyway.)
        self.forget_users();
        self.speakers.retire_all();
        self.push(
            MessageType::Version,
            &Version {
                version: Some(ANNOUNCED_VERSION),
                release: Some(format!("lipcall {}", env!("CARGO_PKG_VERSION"))),
                os: Some(std::env::consts::OS.into()),
                os_version: Some(std::env::consts::ARCH.into()),
            },
        );
        self.push(
            MessageType::Authenticate,
            &Authenticate {
                username: Some(self.config.name.clone()),
                password: self.config.password.clone(),
                opus: Some(true),
                ..Default::default()
            },
        );
        self.next_ping = now + PING_INTERVAL;
    }

    /// The TLS connection is gone.
    pub fn disconnected(&mut self, now: Instant) {
        self.connected = false;
        self.session = None;
        self.crypt = None;
        self.set_udp(false);
        self.forget_users();
        self.speakers.leave_all(now);
    }

    /// Everyone is forgotten; those whose receiver was let go earlier are listed as departed.
    fn forget_users(&mut self) {
        for (session, user) in std::mem::take(&mut self.users) {
            if let Some(heard) = user.heard {
                self.speakers.depart(session, user.name, *heard);
            }
        }
    }

    /// How long the server has been silent, once that is [`SERVER_SILENT`] or more (murmur
    /// answers every ping, and we ping every [`PING_INTERVAL`]).
    pub fn server_silent(&self, now: Instant) -> Option<Duration> {
        let quiet = now.saturating_duration_since(self.heard_server);
        (self.connected && quiet >= SERVER_SILENT).then_some(quiet)
    }

    pub(super) fn push(&mut self, kind: MessageType, message: &impl prost::Message) {
        self.control.push_back(messages::frame(kind, message));
    }

    /// Bytes read from the TLS stream.
    pub fn handle_stream(&mut self, bytes: &[u8], now: Instant) {
        if !bytes.is_empty() {
            self.heard_server = now;
        }
        self.deframer.push(bytes);
        loop {
            match self.deframer.next_frame() {
                Ok(Some((kind, body))) => match Incoming::decode(kind, &body) {
                    Ok(message) => self.handle_message(message, now),
                    Err(e) => {
                        self.stats.malformed += 1;
                        tracing::debug!("Mumble: {e}");
                    }
                },
                Ok(None) => break,
                Err(e) => {
                    self.fatal = Some(e);
                    break;
                }
            }
        }
    }

    /// Why the server removed us, if it did.
    pub fn kicked(&self) -> Option<&str> {
        self.kicked.as_deref()
    }

    /// A stream error that ends the connection (a frame too large to trust the rest).
    pub fn take_fatal(&mut self) -> Option<MumbleError> {
        self.fatal.take()
    }

    fn handle_message(&mut self, message: Incoming, now: Instant) {
        match message {
            Incoming::UdpTunnel(packet) => {
                self.stats.tunnel_received += 1;
                self.handle_voice(&packet, now);
            }
            // Said once: a join ends at the first, and nothing comes after our ServerSync.
            Incoming::Reject(_) | Incoming::ServerSync(_) if self.session.is_some() => {
                self.stats.malformed += 1;
            }
            Incoming::Reject(r) => {
                self.events.push_back(ClientEvent::Rejected(describe_reject(
                    r.r#type,
                    r.reason.as_deref(),
                )));
            }
            Incoming::ServerSync(sync) => self.synced(sync, now),
            Incoming::ChannelState(c) => self.channel_state(c),
            Incoming::ChannelRemove(c) => {
                if let Some(id) = c.channel_id {
                    self.channels.remove(&id);
                }
            }
            Incoming::UserState(u) => self.user_state(u, now),
            Incoming::UserRemove(u) => match u.session {
                Some(session) if Some(session) == self.session => {
                    if self.kicked.is_none() {
                        let reason = u.reason.filter(|r| !r.is_empty());
                        let why = shortened(reason.unwrap_or_else(|| "no reason given".into()));
                        self.kicked = Some(why.clone());
                        self.events.push_back(ClientEvent::Removed(why));
                    }
                }
                Some(session) => self.user_left(session, now),
                None => self.stats.malformed += 1,
            },
            Incoming::CryptSetup(c) => self.crypt_setup(c),
            Incoming::PermissionDenied(d) => {
                let reason = d
                    .reason
                    .or(d.name.map(|n| format!("name {n:?}")))
                    .unwrap_or_else(|| format!("permission {:?}", d.permission));
                if self.news.say(News::Message, now) {
                    self.events
                        .push_back(ClientEvent::Denied(shortened(reason)));
                }
            }
            Incoming::TextMessage(t) => {
                if self.news.say(News::Message, now) {
                    let from = t
                        .actor
                        .and_then(|a| self.users.get(&a))
                        .map_or_else(|| "the server".to_string(), |u| u.name.clone());
                    self.events.push_back(ClientEvent::Text {
                        from,
                        message: shortened(t.message.unwrap_or_default()),
                    });
                }
            }
            Incoming::Version(_)
            | Incoming::Ping(_)
            | Incoming::CodecVersion(_)
            | Incoming::ServerConfig(_)
            | Incoming::Other(_) => {}
        }
    }

    fn synced(&mut self, sync: messages::ServerSync, now: Instant) {
        let Some(session) = sync.session else {
            self.stats.malformed += 1;
            return;
        };
        self.session = Some(session);
        self.welcome = shortened(sync.welcome_text.unwrap_or_default());
        self.presence_changed = true;
        self.tell_self_mute(now, true);
        if let Some(wanted) = self.config.channel.clone() {
            match self.channels.values().find(|c| c.name == wanted) {
                Some(c) => {
                    let id = c.id;
                    self.push(
                        MessageType::UserState,
                        &UserState {
                            session: Some(session),
                            channel_id: Some(id),
                            ..Default::default()
                        },
                    );
                }
                None => {
                    let names: Vec<&str> =
                        self.channels.values().map(|c| c.name.as_str()).collect();
                    self.events.push_back(ClientEvent::Denied(format!(
                        "no channel named {wanted:?} on this server (it has: {})",
                        names.join(", ")
                    )));
                }
            }
        }
        // A first UDP ping right away: voice takes UDP as soon as it comes back. If none has
        // come back within a second, the next goes through the tunnel as well.
        self.pinged_once = false;
        self.udp_ping(now);
        self.next_ping = now + FIRST_PING_ANSWER;
        let channel = self.channel_name(self.own_channel());
        self.events.push_back(ClientEvent::Synced {
            session,
            channel,
            welcome: self.welcome.clone(),
        });
    }

    fn crypt_setup(&mut self, c: CryptSetup) {
        let block = |b: &Option<Vec<u8>>| b.as_deref().and_then(|v| <[u8; 16]>::try_from(v).ok());
        match (
            block(&c.key),
            block(&c.client_nonce),
            block(&c.server_nonce),
        ) {
            (Some(key), Some(ours), Some(theirs)) => {
                self.crypt = Some(CryptState::new(&key, ours, theirs));
            }
            (None, _, Some(theirs)) => {
                if let Some(crypt) = &mut self.crypt {
                    crypt.decrypt_iv = theirs;
                    crypt.stats.resync += 1;
                }
            }
            (None, None, None) => {
                // The server asks for our nonce.
                if let Some(crypt) = &self.crypt {
                    let nonce = crypt.encrypt_iv.to_vec();
                    self.push(
                        MessageType::CryptSetup,
                        &CryptSetup {
                            client_nonce: Some(nonce),
                            ..Default::default()
                        },
                    );
                }
            }
            _ => self.stats.malformed += 1,
        }
    }

    fn set_udp(&mut self, working: bool) {
        if self.udp_working != working {
            self.udp_working = working;
            self.events.push_back(ClientEvent::UdpWorking(working));
        }
    }

    /// Pings the server by UDP and, while UDP is not working, through the tunnel too: the
    /// server sends voice to the address its last UDP packet came from, and through the
    /// tunnel once it gets a tunnelled one (murmur starts out sending by UDP, to an address
    /// we might not be reachable at).
    fn udp_ping(&mut self, now: Instant) {
        let timestamp = now.saturating_duration_since(self.epoch).as_micros() as u64;
        let packet = voice::ping(timestamp);
        if !self.config.tcp_only {
            self.send_datagram(&packet);
        }
        if !self.udp_working && (self.config.tcp_only || self.pinged_once) {
            self.control.push_back(messages::tunnel(&packet));
        }
        self.pinged_once = true;
    }

    fn send_datagram(&mut self, plain: &[u8]) -> bool {
        let Some(crypt) = &mut self.crypt else {
            return false;
        };
        let data = crypt.encrypt(plain);
        self.datagrams.push_back(Transmit {
            to: self.server,
            data,
            kind: TransmitKind::Rtp,
        });
        true
    }

    /// A voice packet (from UDP or the tunnel), decrypted.
    fn handle_voice(&mut self, packet: &[u8], now: Instant) {
        match voice::parse_server_packet(packet) {
            Ok(ServerPacket::Ping { .. }) => {}
            Ok(ServerPacket::Opus {
                session,
                sequence,
                frame,
                last,
            }) => self.speaker_packet(session, sequence, frame, last, now),
            Ok(ServerPacket::OtherCodec { .. }) => self.stats.other_codec += 1,
            Err(e) => {
                self.stats.malformed += 1;
                tracing::debug!("Mumble voice: {e}");
            }
        }
    }

    fn speaker_packet(
        &mut self,
        session: u32,
        sequence: u64,
        frame: &[u8],
        last: bool,
        now: Instant,
    ) {
        if self.speakers.get_mut(session).is_none() {
            let Some(name) = self.users.get(&session).map(|u| u.name.clone()) else {
                // Voice from someone the server never described: ignored.
                self.stats.malformed += 1;
                return;
            };
            match self.speakers.make_room(now) {
                Room::Free => {}
                Room::LetGo(quiet, stats) => {
                    if let Some(user) = self.users.get_mut(&quiet) {
                        user.heard = Some(stats);
                    }
                }
                Room::Full => {
                    self.stats.over_cap += 1;
                    return;
                }
            }
            if let Some(user) = self.users.get_mut(&session) {
                user.heard = None;
            }
            let receiver = PeerReceiver::with_payloads(
                self.config.jitter,
                self.epoch,
                true,
                PayloadMap::default(),
            );
            self.speakers.insert(session, Speaker::new(name, receiver));
        }
        if let Some(speaker) = self.speakers.get_mut(session) {
            speaker.file(session, sequence, frame, last, now);
        }
    }

    /// Sends one Opus payload lasting `ticks` of the 48 kHz clock (by UDP once it works, else
    /// tunnelled).
    pub fn send_voice(&mut self, payload: &[u8], ticks: u32) -> Result<(), MumbleError> {
        if self.session.is_none() {
            return Err(MumbleError::NotConnected);
        }
        let packet = voice::client_opus(self.send_sequence, payload, false)?;
        // Mumble's sequence counts 10 ms (480 ticks of Opus's 48 kHz clock).
        self.send_sequence += u64::from((ticks / 480).max(1));
        if self.udp_working && !self.config.tcp_only && self.send_datagram(&packet) {
            self.stats.udp_sent += 1;
        } else {
            self.control.push_back(messages::tunnel(&packet));
            self.stats.tunnel_sent += 1;
        }
        Ok(())
    }

    /// Frames not sent (silence): our sequence moves on.
    pub fn skip_frames(&mut self, frames: u32) {
        self.send_sequence += 2 * u64::from(frames);
    }

    /// The next framed control message for the TLS stream.
    pub fn poll_control(&mut self) -> Option<Vec<u8>> {
        self.control.pop_front()
    }

    pub fn poll_event(&mut self) -> Option<ClientEvent> {
        self.events.pop_front()
    }

    /// Our session once joined.
    pub fn session(&self) -> Option<u32> {
        self.session
    }

    pub fn udp_working(&self) -> bool {
        self.udp_working
    }

    /// The next 20 ms of every speaker that is playing.
    pub fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) {
        self.speakers.pull(now, out);
    }
}

/// A server's text as said: at most [`MAX_TEXT`] bytes, cut at a character.
fn shortened(mut text: String) -> String {
    if text.len() > MAX_TEXT {
        let mut end = MAX_TEXT;
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        text.truncate(end);
        text.push('…');
    }
    text
}

impl ClientCore {
    /// A UDP datagram from `from`.
    pub fn datagram(&mut self, data: &[u8], from: SocketAddr, now: Instant) {
        if from != self.server || self.config.tcp_only {
            return;
        }
        let Some(crypt) = &mut self.crypt else {
            self.stats.decrypt_failed += 1;
            return;
        };
        match crypt.decrypt(data) {
            Ok(plain) => {
                self.udp_heard = Some(now);
                self.set_udp(true);
                self.stats.udp_received += 1;
                self.handle_voice(&plain, now);
            }
            Err(e) => {
                self.stats.decrypt_failed += 1;
                tracing::debug!("Mumble UDP: {e}");
                let stale = self
                    .udp_heard
                    .is_none_or(|t| now.saturating_duration_since(t) > RESYNC_EVERY);
                let asked_lately = self
                    .resync_asked
                    .is_some_and(|t| now.saturating_duration_since(t) < RESYNC_EVERY);
                if stale && !asked_lately && self.session.is_some() {
                    self.resync_asked = Some(now);
                    self.stats.resyncs += 1;
                    self.push(MessageType::CryptSetup, &CryptSetup::default());
                }
            }
        }
    }

    /// When [`Self::wake`] is next due.
    pub fn next_wake(&self) -> Instant {
        self.self_mute_due()
            .map_or(self.next_ping, |due| due.min(self.next_ping))
    }

    /// Pings and checks on UDP, when due.
    pub fn wake(&mut self, now: Instant) {
        self.tell_self_mute(now, false);
        if now < self.next_ping {
            return;
        }
        self.next_ping = now + PING_INTERVAL;
        self.speakers.expire(now);
        if !self.connected || self.session.is_none() {
            return;
        }
        if self
            .udp_heard
            .is_some_and(|t| now.saturating_duration_since(t) > UDP_FRESH)
        {
            self.set_udp(false);
        }
        let timestamp = now.saturating_duration_since(self.epoch).as_micros() as u64;
        let (good, late, lost, resync) = self.crypt.as_ref().map_or((0, 0, 0, 0), |c| {
            (c.stats.good, c.stats.late, c.stats.lost, c.stats.resync)
        });
        self.push(
            MessageType::Ping,
            &Ping {
                timestamp: Some(timestamp),
                good: Some(good),
                late: Some(late),
                lost: Some(lost),
                resync: Some(resync),
                udp_packets: Some(self.stats.udp_received as u32),
                tcp_packets: Some(self.stats.tunnel_received as u32),
            },
        );
        self.udp_ping(now);
    }

    /// The next datagram to send.
    pub fn next_transmit(&mut self) -> Option<Transmit> {
        self.datagrams.pop_front()
    }
}
