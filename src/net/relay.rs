//! The relay: a room server for peers behind NAT and for rooms too large for a mesh.
//!
//! Peers join a room by its hashed id (see [`super::control`]): a join is answered with a
//! cookie bound to the joiner's address, and only its echo from that address makes a member,
//! so a forged join cannot turn an uninvolved address into a member (the relay would reflect
//! the room's traffic at it), and the relay keeps no state for a join until it is confirmed.
//! The cookie stays the member's token: keepalives and leaves without it are ignored, and a
//! member whose keepalives stop expires. The relay forwards every RTP/RTCP datagram from a
//! member to the other members of its room, as it is: with SRTP it cannot read or forge them.
//!
//! Everything is bounded, by quotas that one source cannot use up for others: members per
//! room, rooms, members per source IP (so one host's sockets cannot fill a room or the relay),
//! joins per second per source IP, and packets per second per member (token buckets).
//! Anything else is dropped and counted.

use std::collections::{HashMap, VecDeque};
use std::hash::{BuildHasher, Hasher};
use std::net::{IpAddr, SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use hmac::{Hmac, KeyInit, Mac};
use sha2::Sha256;

use super::control::{self, Control, ControlError, ControlKind, Cookie, Refusal, RoomId};
use super::transport::{Driver, SansIo, Transmit, TransmitKind};
use super::{DatagramKind, MAX_DATAGRAM, NetError, classify};

/// A cookie is valid for the period it was issued in and the next one.
const COOKIE_PERIOD: Duration = Duration::from_secs(30);

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelayConfig {
    pub max_rooms: usize,
    /// Members per room.
    pub max_members: usize,
    /// Members from one IP address, over all rooms.
    pub max_members_per_source: usize,
    /// Sustained packets per second a member may send (RTP + RTCP).
    pub rate_per_second: f64,
    pub burst: f64,
    /// Sustained joins per second from one IP address, and their burst.
    pub joins_per_second: f64,
    pub join_burst: f64,
    /// Members without a keepalive for this long are forgotten.
    pub idle_timeout: Duration,
}

impl Default for RelayConfig {
    fn default() -> Self {
        Self {
            max_rooms: 1024,
            max_members: 16,
            max_members_per_source: 4,
            // 50 packets/s of media plus RTCP, with room for a burst.
            rate_per_second: 120.0,
            burst: 60.0,
            joins_per_second: 2.0,
            join_burst: 8.0,
            idle_timeout: Duration::from_secs(30),
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RelayStats {
    pub datagrams: u64,
    /// Member datagrams forwarded (each counted once, however many copies went out).
    pub forwarded: u64,
    pub copies: u64,
    /// Cookies handed out (answers to joins, and to confirms with a cookie that is not valid).
    pub challenges: u64,
    pub joins: u64,
    pub refused: u64,
    /// Of the refusals: those for the per-source quota or join rate.
    pub source_limited: u64,
    pub leaves: u64,
    pub expired: u64,
    /// Confirms and leaves whose cookie is not the one of that address and room (forged,
    /// stale, or from a relay run before a restart); nothing changes for them.
    pub bad_cookie: u64,
    /// Control datagrams of another protocol version (an outdated client); refused.
    pub outdated: u64,
    /// Media from addresses that are no member.
    pub unknown_source: u64,
    pub malformed: u64,
    pub rate_limited: u64,
    pub send_errors: u64,
    pub rooms: usize,
    pub members: usize,
}

#[derive(Debug, Clone, Copy)]
struct Bucket {
    tokens: f64,
    at: Instant,
}

impl Bucket {
    fn full(burst: f64, now: Instant) -> Self {
        Self {
            tokens: burst,
            at: now,
        }
    }

    fn take(&mut self, now: Instant, rate: f64, burst: f64) -> bool {
        let elapsed = now.saturating_duration_since(self.at).as_secs_f64();
        self.tokens = (self.tokens + elapsed * rate).min(burst);
        self.at = now;
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

#[derive(Debug)]
struct Member {
    room: RoomId,
    /// The cookie it confirmed with: its keepalives and its leave must carry it.
    token: Cookie,
    last_seen: Instant,
    bucket: Bucket,
}

/// What the relay keeps about one IP address while it has members (or joined lately).
#[derive(Debug)]
struct Source {
    members: usize,
    joins: Bucket,
}

/// The relay's state and rules without a socket: datagrams in, datagrams out.
pub struct RelayCore {
    config: RelayConfig,
    /// Keyed with a secret random per process: cookies cannot be made without it.
    mac: Hmac<Sha256>,
    start: Instant,
    members: HashMap<SocketAddr, Member>,
    rooms: HashMap<RoomId, Vec<SocketAddr>>,
    sources: HashMap<IpAddr, Source>,
    stats: RelayStats,
}

impl std::fmt::Debug for RelayCore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RelayCore")
            .field("config", &self.config)
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

/// 64 secret bytes from the OS. Should its random source fail, std's hash keys (which it
/// seeds from the same source, or it could not have built a `HashMap`) stand in.
fn random_secret() -> [u8; 64] {
    let mut secret = [0u8; 64];
    if getrandom::fill(&mut secret).is_err() {
        for chunk in secret.chunks_mut(8) {
            let mut hasher = std::collections::hash_map::RandomState::new().build_hasher();
            hasher.write_usize(chunk.as_ptr() as usize);
            chunk.copy_from_slice(&hasher.finish().to_le_bytes());
        }
    }
    secret
}

impl RelayCore {
    pub fn new(config: RelayConfig, now: Instant) -> Self {
        Self::with_secret(config, random_secret(), now)
    }

    /// A core whose cookies are keyed with `secret` (tests pin it).
    pub fn with_secret(config: RelayConfig, secret: [u8; 64], now: Instant) -> Self {
        Self {
            config,
            mac: Hmac::<Sha256>::new(&secret.into()),
            start: now,
            members: HashMap::new(),
            rooms: HashMap::new(),
            sources: HashMap::new(),
            stats: RelayStats::default(),
        }
    }

    pub fn stats(&self) -> RelayStats {
        RelayStats {
            rooms: self.rooms.len(),
            members: self.members.len(),
            ..self.stats
        }
    }

    /// Handles one datagram; `send` is called for every datagram to go out.
    pub fn handle(
        &mut self,
        data: &[u8],
        from: SocketAddr,
        now: Instant,
        mut send: impl FnMut(&[u8], SocketAddr) -> bool,
    ) {
        self.stats.datagrams += 1;
        match classify(data) {
            DatagramKind::Rtp | DatagramKind::Rtcp => self.forward(data, from, now, &mut send),
            DatagramKind::Control => self.control(data, from, now, &mut send),
            DatagramKind::Unknown => self.stats.malformed += 1,
        }
    }

    fn forward(
        &mut self,
        data: &[u8],
        from: SocketAddr,
        now: Instant,
        send: &mut impl FnMut(&[u8], SocketAddr) -> bool,
    ) {
        let Some(member) = self.members.get_mut(&from) else {
            self.stats.unknown_source += 1;
            return;
        };
        if !member
            .bucket
            .take(now, self.config.rate_per_second, self.config.burst)
        {
            self.stats.rate_limited += 1;
            return;
        }
        let room = member.room;
        self.stats.forwarded += 1;
        for &to in self.rooms.get(&room).into_iter().flatten() {
            if to != from {
                if send(data, to) {
                    self.stats.copies += 1;
                } else {
                    self.stats.send_errors += 1;
                }
            }
        }
    }

    fn control(
        &mut self,
        data: &[u8],
        from: SocketAddr,
        now: Instant,
        send: &mut impl FnMut(&[u8], SocketAddr) -> bool,
    ) {
        let control = match Control::decode(data) {
            Ok(control) => control,
            Err(ControlError::Version(_)) => {
                self.stats.outdated += 1;
                if let Some(refusal) = control::legacy_refusal(data) {
                    self.stats.refused += 1;
                    self.reply(send, &refusal, from);
                }
                return;
            }
            Err(ControlError::Malformed) => {
                self.stats.malformed += 1;
                return;
            }
        };
        let room = control.room;
        let answer = match control.kind {
            ControlKind::Join => Some(self.challenge(from, room, now)),
            ControlKind::Confirm => Some(self.confirm(from, room, control.cookie, now)),
            ControlKind::Leave => {
                if self.is_member(from, room, &control.cookie) {
                    self.remove(from);
                    self.stats.leaves += 1;
                } else {
                    self.stats.bad_cookie += 1;
                }
                None
            }
            ControlKind::Challenge | ControlKind::Joined | ControlKind::Refused(_) => {
                self.stats.malformed += 1;
                None
            }
        };
        if let Some((kind, cookie)) = answer {
            self.reply(send, &Control::new(kind, room, cookie).encode(), from);
        }
    }

    fn reply(
        &mut self,
        send: &mut impl FnMut(&[u8], SocketAddr) -> bool,
        data: &[u8],
        to: SocketAddr,
    ) {
        if !send(data, to) {
            self.stats.send_errors += 1;
        }
    }

    fn is_member(&self, from: SocketAddr, room: RoomId, cookie: &Cookie) -> bool {
        self.members
            .get(&from)
            .is_some_and(|m| m.room == room && m.token.matches(cookie))
    }

    fn challenge(&mut self, from: SocketAddr, room: RoomId, now: Instant) -> (ControlKind, Cookie) {
        self.stats.challenges += 1;
        (
            ControlKind::Challenge,
            self.cookie(from, room, self.period(now)),
        )
    }

    /// A keepalive of a member, or the echo of a challenge that makes one.
    fn confirm(
        &mut self,
        from: SocketAddr,
        room: RoomId,
        cookie: Cookie,
        now: Instant,
    ) -> (ControlKind, Cookie) {
        if self.is_member(from, room, &cookie) {
            if let Some(member) = self.members.get_mut(&from) {
                member.last_seen = now;
            }
            return (ControlKind::Joined, cookie);
        }
        if !self.cookie_valid(from, room, &cookie, now) {
            // Whoever is at `from` may start again (its cookie is stale, or the relay restarted).
            self.stats.bad_cookie += 1;
            return self.challenge(from, room, now);
        }
        match self.admit(from, room, cookie, now) {
            Ok(()) => (ControlKind::Joined, cookie),
            Err(why) => {
                self.stats.refused += 1;
                if matches!(why, Refusal::SourceQuota | Refusal::RateLimited) {
                    self.stats.source_limited += 1;
                }
                (ControlKind::Refused(why), cookie)
            }
        }
    }

    /// Makes `from` (whose address the cookie proved) a member of `room`, within the quotas.
    fn admit(
        &mut self,
        from: SocketAddr,
        room: RoomId,
        token: Cookie,
        now: Instant,
    ) -> Result<(), Refusal> {
        if let Some(member) = self.members.get_mut(&from)
            && member.room == room
        {
            member.token = token;
            member.last_seen = now;
            return Ok(());
        }
        let moving = self.members.contains_key(&from);
        let members_in_room = self.rooms.get(&room).map_or(0, Vec::len);
        if members_in_room == 0 && self.rooms.len() >= self.config.max_rooms {
            return Err(Refusal::RelayFull);
        }
        if members_in_room >= self.config.max_members {
            return Err(Refusal::RoomFull);
        }
        let max_sources = self.config.max_rooms * self.config.max_members;
        if !self.sources.contains_key(&from.ip()) && self.sources.len() >= max_sources {
            return Err(Refusal::RelayFull);
        }
        let source = self.sources.entry(from.ip()).or_insert(Source {
            members: 0,
            joins: Bucket::full(self.config.join_burst, now),
        });
        if !moving && source.members >= self.config.max_members_per_source {
            return Err(Refusal::SourceQuota);
        }
        if !source
            .joins
            .take(now, self.config.joins_per_second, self.config.join_burst)
        {
            return Err(Refusal::RateLimited);
        }
        // A member moving rooms keeps its rate budget.
        let bucket = self
            .members
            .get(&from)
            .map_or(Bucket::full(self.config.burst, now), |m| m.bucket);
        self.remove(from);
        self.rooms.entry(room).or_default().push(from);
        self.members.insert(
            from,
            Member {
                room,
                token,
                last_seen: now,
                bucket,
            },
        );
        if let Some(source) = self.sources.get_mut(&from.ip()) {
            source.members += 1;
        }
        self.stats.joins += 1;
        Ok(())
    }

    fn remove(&mut self, addr: SocketAddr) {
        let Some(member) = self.members.remove(&addr) else {
            return;
        };
        if let Some(list) = self.rooms.get_mut(&member.room) {
            list.retain(|&a| a != addr);
            if list.is_empty() {
                self.rooms.remove(&member.room);
            }
        }
        if let Some(source) = self.sources.get_mut(&addr.ip()) {
            source.members = source.members.saturating_sub(1);
        }
    }

    /// Forgets members without a keepalive for longer than the idle timeout, and sources
    /// with no members whose join budget has refilled (forgetting them loses nothing).
    pub fn expire(&mut self, now: Instant) {
        let timeout = self.config.idle_timeout;
        let stale: Vec<SocketAddr> = self
            .members
            .iter()
            .filter(|(_, m)| now.saturating_duration_since(m.last_seen) > timeout)
            .map(|(&a, _)| a)
            .collect();
        for addr in stale {
            self.remove(addr);
            self.stats.expired += 1;
        }
        let refill = Duration::from_secs_f64(
            (self.config.join_burst / self.config.joins_per_second.max(1e-3)).min(3600.0),
        );
        self.sources
            .retain(|_, s| s.members > 0 || now.saturating_duration_since(s.joins.at) < refill);
    }

    fn period(&self, now: Instant) -> u64 {
        now.saturating_duration_since(self.start).as_secs() / COOKIE_PERIOD.as_secs()
    }

    fn keyed(&self, from: SocketAddr, room: RoomId, period: u64) -> Hmac<Sha256> {
        let mut mac = self.mac.clone();
        match from.ip() {
            IpAddr::V4(ip) => {
                mac.update(&[4]);
                mac.update(&ip.octets());
            }
            IpAddr::V6(ip) => {
                mac.update(&[6]);
                mac.update(&ip.octets());
            }
        }
        mac.update(&from.port().to_be_bytes());
        mac.update(&room.0);
        mac.update(&period.to_be_bytes());
        mac
    }

    fn cookie(&self, from: SocketAddr, room: RoomId, period: u64) -> Cookie {
        let mut cookie = Cookie::NONE;
        cookie
            .0
            .copy_from_slice(&self.keyed(from, room, period).finalize().into_bytes()[..16]);
        cookie
    }

    fn cookie_valid(&self, from: SocketAddr, room: RoomId, cookie: &Cookie, now: Instant) -> bool {
        let period = self.period(now);
        [Some(period), period.checked_sub(1)]
            .into_iter()
            .flatten()
            .any(|p| {
                self.keyed(from, room, p)
                    .verify_truncated_left(&cookie.0)
                    .is_ok()
            })
    }
}

/// How often members whose keepalives stopped are looked for.
const EXPIRE_EVERY: Duration = Duration::from_secs(1);
/// How long the socket thread waits at most for a datagram before it looks at whether to stop.
const POLL: Duration = Duration::from_millis(50);

/// The core as the socket [`Driver`] runs it: what it sends queued for the socket, its members'
/// expiry as its timeout.
struct Driven {
    core: RelayCore,
    outbox: VecDeque<Transmit>,
    next_expiry: Instant,
}

impl SansIo for Driven {
    // One byte over the largest datagram forwarded: one that fills the buffer was cut short
    // by the socket and is dropped, not forwarded or parsed truncated.
    const BUFFER: usize = MAX_DATAGRAM + 1;

    fn handle_datagram(&mut self, data: &[u8], from: SocketAddr, now: Instant) {
        if data.len() > MAX_DATAGRAM {
            self.core.stats.datagrams += 1;
            self.core.stats.malformed += 1;
            return;
        }
        let outbox = &mut self.outbox;
        // Counted as sent here; [`SansIo::transmitted`] takes back those the socket refused.
        self.core.handle(data, from, now, |data, to| {
            let kind = match classify(data) {
                DatagramKind::Control => TransmitKind::Control,
                DatagramKind::Rtcp => TransmitKind::Rtcp,
                DatagramKind::Rtp | DatagramKind::Unknown => TransmitKind::Rtp,
            };
            outbox.push_back(Transmit {
                to,
                data: data.to_vec(),
                kind,
            });
            true
        });
    }

    fn poll_timeout(&self) -> Instant {
        self.next_expiry
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.core.expire(now);
        self.next_expiry = now + EXPIRE_EVERY;
    }

    fn poll_transmit(&mut self) -> Option<Transmit> {
        self.outbox.pop_front()
    }

    fn transmitted(&mut self, transmit: Transmit, sent: bool) {
        if !sent {
            if transmit.kind != TransmitKind::Control {
                self.core.stats.copies = self.core.stats.copies.saturating_sub(1);
            }
            self.core.stats.send_errors += 1;
        }
    }
}

/// A relay serving on its socket thread (the [`Driver`] every link stands on) until dropped.
pub struct Relay {
    addr: SocketAddr,
    driver: Driver<Driven>,
}

impl std::fmt::Debug for Relay {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Relay").field("addr", &self.addr).finish()
    }
}

impl Relay {
    pub fn start(bind: SocketAddr, config: RelayConfig) -> Result<Self, NetError> {
        let socket = UdpSocket::bind(bind)
            .map_err(|e| NetError::io(format!("cannot listen on {bind}"), e))?;
        let addr = socket
            .local_addr()
            .map_err(|e| NetError::io("local address", e))?;
        let now = Instant::now();
        let driven = Driven {
            core: RelayCore::new(config, now),
            outbox: VecDeque::new(),
            next_expiry: now + EXPIRE_EVERY,
        };
        let driver = Driver::start(socket, driven, "lipcall-relay", POLL)
            .map_err(|e| NetError::io("cannot start the relay thread", e))?;
        Ok(Self { addr, driver })
    }

    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    pub fn stats(&self) -> RelayStats {
        self.driver.access(|driven| driven.core.stats())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SECRET: [u8; 64] = [42; 64];

    /// Distinct source hosts, as the core sees them (no socket is involved).
    fn host(host: u8, port: u16) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, host], port))
    }

    fn addr(port: u16) -> SocketAddr {
        host(1, port)
    }

    fn rtp() -> [u8; 14] {
        [0x80u8, 110, 0, 1, 0, 0, 0, 0, 0, 0, 0, 9, 1, 2]
    }

    fn request(kind: ControlKind, room: &str, cookie: Cookie) -> [u8; control::LEN] {
        Control::new(kind, RoomId::from_name(room), cookie).encode()
    }

    /// Every datagram the core sends for one input: (datagram, to).
    fn exchange(
        core: &mut RelayCore,
        data: &[u8],
        from: SocketAddr,
        now: Instant,
    ) -> Vec<(Vec<u8>, SocketAddr)> {
        let mut out = Vec::new();
        core.handle(data, from, now, |d, to| {
            out.push((d.to_vec(), to));
            true
        });
        out
    }

    /// The single control answer to `from`.
    fn answer(core: &mut RelayCore, data: &[u8], from: SocketAddr, now: Instant) -> Control {
        let out = exchange(core, data, from, now);
        assert_eq!(out.len(), 1, "{out:?}");
        assert_eq!(out[0].1, from);
        Control::decode(&out[0].0).unwrap()
    }

    /// Join, echo the cookie: the member's token, or why it was refused.
    fn join(
        core: &mut RelayCore,
        room: &str,
        from: SocketAddr,
        now: Instant,
    ) -> Result<Cookie, Refusal> {
        let challenge = answer(
            core,
            &request(ControlKind::Join, room, Cookie::NONE),
            from,
            now,
        );
        assert_eq!(challenge.kind, ControlKind::Challenge);
        let confirm = request(ControlKind::Confirm, room, challenge.cookie);
        let reply = answer(core, &confirm, from, now);
        assert_eq!(reply.cookie, challenge.cookie);
        match reply.kind {
            ControlKind::Joined => Ok(challenge.cookie),
            ControlKind::Refused(why) => Err(why),
            other => panic!("answer {other:?}"),
        }
    }

    fn copies_to(core: &mut RelayCore, from: SocketAddr, now: Instant) -> Vec<SocketAddr> {
        let mut to: Vec<SocketAddr> = exchange(core, &rtp(), from, now)
            .into_iter()
            .map(|(_, to)| to)
            .collect();
        to.sort();
        to
    }

    #[test]
    fn forwards_within_a_room_only() {
        let now = Instant::now();
        let mut core = RelayCore::with_secret(RelayConfig::default(), SECRET, now);
        for (port, room) in [(1, "a"), (2, "a"), (3, "a"), (4, "b")] {
            join(&mut core, room, host(port as u8, port), now).unwrap();
        }
        assert_eq!(
            copies_to(&mut core, host(1, 1), now),
            [host(2, 2), host(3, 3)]
        );
        core.handle(&rtp(), addr(9), now, |_, _| panic!("stranger forwarded"));
        assert_eq!(core.stats().unknown_source, 1);
        core.handle(&[0xff; 30], host(1, 1), now, |_, _| {
            panic!("garbage forwarded")
        });
        assert_eq!(core.stats().malformed, 1);
    }

    #[test]
    fn a_join_costs_no_state_until_its_cookie_comes_back_from_its_address() {
        let now = Instant::now();
        let mut core = RelayCore::with_secret(RelayConfig::default(), SECRET, now);
        let member = addr(1);
        join(&mut core, "a", member, now).unwrap();
        // A forged join in the name of an uninvolved address: it is sent one cookie, the
        // size of the join, and nothing else.
        let victim = host(7, 5000);
        for _ in 0..100 {
            let challenge = answer(
                &mut core,
                &request(ControlKind::Join, "a", Cookie::NONE),
                victim,
                now,
            );
            assert_eq!(challenge.kind, ControlKind::Challenge);
        }
        assert_eq!(core.stats().members, 1);
        assert!(copies_to(&mut core, member, now).is_empty());
        // Guessed cookies, and a real one taken to another address or room, make no member.
        let real = join(&mut core, "a", addr(2), now).unwrap();
        for (cookie, room) in [(Cookie([9; 16]), "a"), (real, "a"), (real, "b")] {
            let reply = answer(
                &mut core,
                &request(ControlKind::Confirm, room, cookie),
                victim,
                now,
            );
            assert_eq!(reply.kind, ControlKind::Challenge);
        }
        let stolen = answer(
            &mut core,
            &request(ControlKind::Confirm, "b", real),
            addr(2),
            now,
        );
        assert_eq!(stolen.kind, ControlKind::Challenge);
        assert_eq!(core.stats().members, 2);
        assert_eq!(core.stats().bad_cookie, 4);
        assert_eq!(copies_to(&mut core, member, now), [addr(2)]);
    }

    #[test]
    fn a_leave_without_the_members_cookie_removes_nobody() {
        let now = Instant::now();
        let mut core = RelayCore::with_secret(RelayConfig::default(), SECRET, now);
        let alice = join(&mut core, "a", addr(1), now).unwrap();
        let bob = join(&mut core, "a", addr(2), now).unwrap();
        for cookie in [Cookie::NONE, Cookie([9; 16]), alice] {
            let out = exchange(
                &mut core,
                &request(ControlKind::Leave, "a", cookie),
                addr(2),
                now,
            );
            assert!(out.is_empty());
        }
        assert_eq!(core.stats().bad_cookie, 3);
        assert_eq!(copies_to(&mut core, addr(1), now), [addr(2)]);
        assert!(
            exchange(
                &mut core,
                &request(ControlKind::Leave, "a", bob),
                addr(2),
                now
            )
            .is_empty()
        );
        assert_eq!(core.stats().leaves, 1);
        assert!(copies_to(&mut core, addr(1), now).is_empty());
    }

    #[test]
    fn one_source_cannot_fill_a_room_or_the_relay_for_others() {
        let now = Instant::now();
        let config = RelayConfig::default();
        let mut core = RelayCore::with_secret(config, SECRET, now);
        let attacker = 2;
        let mut admitted = 0;
        for port in 0..16 {
            match join(&mut core, "a", host(attacker, 1000 + port), now) {
                Ok(_) => admitted += 1,
                Err(why) => assert_eq!(why, Refusal::SourceQuota),
            }
        }
        assert_eq!(admitted, config.max_members_per_source);
        // Every other room it tries is refused too.
        for port in 0..1024 {
            let room = format!("room {port}");
            assert!(join(&mut core, &room, host(attacker, 3000 + port), now).is_err());
        }
        assert_eq!(core.stats().rooms, 1);
        assert_eq!(core.stats().source_limited, 12 + 1024);
        // Callers from elsewhere still find places.
        for h in 3..6 {
            join(&mut core, "a", host(h, 4000), now).unwrap();
            join(&mut core, &format!("own {h}"), host(h, 4001), now).unwrap();
        }
        assert_eq!(core.stats().members, 4 + 6);
    }

    #[test]
    fn rooms_and_joins_are_bounded_and_media_rate_limited() {
        let now = Instant::now();
        let config = RelayConfig {
            max_rooms: 2,
            max_members: 2,
            ..Default::default()
        };
        let mut core = RelayCore::with_secret(config, SECRET, now);
        let answers: Vec<Result<Cookie, Refusal>> =
            [(1, "a"), (2, "a"), (3, "a"), (4, "b"), (5, "c")]
                .into_iter()
                .map(|(h, room)| join(&mut core, room, host(h, 1), now))
                .collect();
        assert!(answers[0].is_ok() && answers[1].is_ok() && answers[3].is_ok());
        assert_eq!(answers[2], Err(Refusal::RoomFull));
        assert_eq!(answers[4], Err(Refusal::RelayFull));
        let mut forwarded = 0;
        for _ in 0..1000 {
            core.handle(&rtp(), host(1, 1), now, |_, _| {
                forwarded += 1;
                true
            });
        }
        assert_eq!(forwarded as f64, config.burst);
        assert_eq!(core.stats().rate_limited, 1000 - config.burst as u64);

        // Joins per source: the burst, then the sustained rate.
        let config = RelayConfig {
            max_members_per_source: 100,
            ..Default::default()
        };
        let mut core = RelayCore::with_secret(config, SECRET, now);
        let tries = config.join_burst as u16 + 4;
        let limited = (0..tries)
            .filter(|&port| join(&mut core, "r0", addr(port), now) == Err(Refusal::RateLimited))
            .count();
        assert_eq!(limited, 4);
        assert_eq!(core.stats().members, config.join_burst as usize);
        let later = now + Duration::from_secs_f64(1.0 / config.joins_per_second);
        assert!(join(&mut core, "r0", addr(100), later).is_ok());
    }

    #[test]
    fn keepalives_need_the_token_and_silent_members_expire() {
        let now = Instant::now();
        let config = RelayConfig::default();
        let mut core = RelayCore::with_secret(config, SECRET, now);
        let alice = join(&mut core, "a", addr(1), now).unwrap();
        let bob = join(&mut core, "a", addr(2), now).unwrap();
        // Alice keeps alive for three idle timeouts; forged keepalives in Bob's name, and his
        // own media, do not hold his place.
        let step = config.idle_timeout / 3;
        let mut t = now;
        for _ in 0..9 {
            t += step;
            let kept = answer(
                &mut core,
                &request(ControlKind::Confirm, "a", alice),
                addr(1),
                t,
            );
            assert_eq!(kept.kind, ControlKind::Joined);
            let forged = answer(
                &mut core,
                &request(ControlKind::Confirm, "a", Cookie([1; 16])),
                addr(2),
                t,
            );
            assert_eq!(forged.kind, ControlKind::Challenge);
            core.handle(&rtp(), addr(2), t, |_, _| true);
            core.expire(t);
        }
        assert_eq!(core.stats().members, 1);
        assert_eq!(core.stats().expired, 1);
        // Bob's token died with his membership once its period is over: he starts again.
        let stale = answer(
            &mut core,
            &request(ControlKind::Confirm, "a", bob),
            addr(2),
            t,
        );
        assert_eq!(stale.kind, ControlKind::Challenge);
        join(&mut core, "a", addr(2), t).unwrap();
        core.expire(t + config.idle_timeout + Duration::from_secs(1));
        assert_eq!(core.stats().members, 0);
        assert_eq!(core.stats().rooms, 0);
        assert!(core.sources.is_empty() || core.sources.values().all(|s| s.members == 0));
        core.expire(t + Duration::from_secs(3600));
        assert!(core.sources.is_empty());
    }

    #[test]
    fn a_cookie_is_good_for_one_to_two_periods() {
        let now = Instant::now();
        let mut core = RelayCore::with_secret(RelayConfig::default(), SECRET, now);
        let challenge = answer(
            &mut core,
            &request(ControlKind::Join, "a", Cookie::NONE),
            addr(1),
            now,
        );
        let confirm = request(ControlKind::Confirm, "a", challenge.cookie);
        let late = now + COOKIE_PERIOD * 2;
        assert_eq!(
            answer(&mut core, &confirm, addr(1), late).kind,
            ControlKind::Challenge
        );
        let in_time = now + COOKIE_PERIOD + COOKIE_PERIOD / 2;
        assert_eq!(
            answer(&mut core, &confirm, addr(1), in_time).kind,
            ControlKind::Joined
        );
        // Another relay (another secret) does not take it.
        let mut other = RelayCore::new(RelayConfig::default(), now);
        assert_eq!(
            answer(&mut other, &confirm, addr(1), now).kind,
            ControlKind::Challenge
        );
    }

    #[test]
    fn an_outdated_client_is_refused_in_its_own_format() {
        let now = Instant::now();
        let mut core = RelayCore::with_secret(RelayConfig::default(), SECRET, now);
        let mut v1_join = [0u8; 22];
        v1_join[..4].copy_from_slice(b"LPCR");
        v1_join[4] = 1;
        v1_join[5] = 1;
        v1_join[6..].copy_from_slice(&RoomId::from_name("a").0);
        let out = exchange(&mut core, &v1_join, addr(1), now);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].0.len(), 22);
        assert_eq!(out[0].0[5], 4, "version 1's Refused");
        let stats = core.stats();
        assert_eq!((stats.outdated, stats.refused, stats.members), (1, 1, 0));
    }
}
