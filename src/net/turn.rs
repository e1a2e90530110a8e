//! A TURN client (RFC 8656) over UDP, sans-I/O: an allocation on a TURN server relays our
//! media when no direct path exists (a symmetric NAT, a network that lets UDP out only to the
//! relay). Datagrams from the server and the time go in; datagrams for the server, the relayed
//! address and what peers sent through the relay come out. Messages are built and checked with
//! `ezk-stun-types`; long-term credentials (MD5 key, realm and nonce from the 401), refreshes,
//! permissions and retransmissions are ours.
//!
//! Whatever a server answers, the client asks at a bounded pace: a grant shorter than
//! [`MIN_LIFETIME`] ends the allocation (a server granting 0 s once cost about 48,000
//! Refreshes a second), refreshes come at least half a lifetime apart, and a refused or
//! unanswered Refresh or CreatePermission is retried after a wait that doubles.

use std::collections::{HashMap, VecDeque};
use std::net::{IpAddr, SocketAddr};
use std::time::{Duration, Instant};

use ezk_stun_types::attributes::turn::{
    Data, Lifetime, RequestedTransport, XorPeerAddress, XorRelayedAddress,
};
use ezk_stun_types::attributes::{
    ErrorCode, MessageIntegrity, MessageIntegrityKey, Nonce, Realm, Username,
    long_term_password_md5,
};
use ezk_stun_types::{Class, Message, MessageBuilder, Method, TransactionId};

use crate::net::addr::media_target;
use crate::net::backoff::Backoff;
use crate::net::stun::Retransmit;

/// A request unanswered this long has failed (its retransmissions: [`Retransmit`]).
const REQUEST_TIMEOUT: Duration = Duration::from_secs(8);
/// Permissions last 300 s (RFC 8656 9); renewed this long before.
const PERMISSION_LIFETIME: Duration = Duration::from_secs(300);
const RENEW_BEFORE: Duration = Duration::from_secs(60);
/// A grant shorter than this is a failure: RFC 8656 servers grant 600 s by default.
pub const MIN_LIFETIME: Duration = Duration::from_secs(30);
/// Longer grants are taken as this long (refreshed sooner than the server needs).
const MAX_LIFETIME: Duration = Duration::from_secs(3600);
/// The lifetime asked for, and assumed where an Allocate's answer gives none.
const ASKED_LIFETIME: u32 = 600;
/// The first wait before a failed Refresh or CreatePermission is tried again; doubled on
/// each failure up to [`LONGEST_RETRY`].
const FIRST_RETRY: Duration = Duration::from_secs(5);
const LONGEST_RETRY: Duration = Duration::from_secs(60);
const RETRIES: Backoff = Backoff::new(FIRST_RETRY, LONGEST_RETRY);
/// Peers the relay is asked to let through (permissions held and being retried) at most.
const MOST_PEERS: usize = 32;
/// IANA's protocol number for UDP, the transport we ask the relay for.
const UDP: u8 = 17;

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TurnConfig {
    pub server: SocketAddr,
    pub username: String,
    pub password: String,
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TurnError {
    #[error("TURN server {server} refused the allocation: {code} {reason}")]
    Refused {
        server: SocketAddr,
        code: u32,
        reason: String,
    },
    #[error("TURN server {0} did not answer")]
    NoAnswer(SocketAddr),
    #[error("TURN server {0} asked for credentials twice: wrong user name or password")]
    BadCredentials(SocketAddr),
    #[error(
        "TURN server {server} granted the relay for {seconds} s, under the {} s it must last",
        MIN_LIFETIME.as_secs()
    )]
    ShortLifetime { server: SocketAddr, seconds: u32 },
    #[error("TURN server {0} let the relay expire: its refreshes failed")]
    Expired(SocketAddr),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Request {
    Allocate,
    Refresh { lifetime: u32 },
    Permission(IpAddr),
}

#[derive(Debug)]
struct Pending {
    id: TransactionId,
    request: Request,
    bytes: Vec<u8>,
    timer: Retransmit,
    /// Sent again with fresh credentials once already (a second 401 means they are wrong).
    authenticated_again: bool,
}

/// The realm, nonce and key the server's challenge gave.
#[derive(Debug, Clone)]
struct Credentials {
    realm: String,
    nonce: Vec<u8>,
    key: Vec<u8>,
}

/// One allocation on one TURN server.
#[derive(Debug)]
pub struct TurnClient {
    config: TurnConfig,
    credentials: Option<Credentials>,
    relayed: Option<SocketAddr>,
    /// When the allocation runs out.
    expires: Option<Instant>,
    /// When the next Refresh goes out (none while one is on its way).
    renew_at: Option<Instant>,
    /// The waits before a failed Refresh is tried again.
    refresh_retry: Backoff,
    failed: Option<TurnError>,
    /// Peers the relay lets through, and when each permission runs out.
    permissions: HashMap<IpAddr, Instant>,
    /// Peers whose permission failed: not asked again before the instant, and the waits
    /// after their next failures.
    permission_retry: HashMap<IpAddr, (Instant, Backoff)>,
    pending: Vec<Pending>,
    outbox: VecDeque<Vec<u8>>,
}

impl TurnClient {
    /// Starts asking `config.server` for an allocation.
    pub fn new(config: TurnConfig, now: Instant) -> Self {
        let mut client = Self {
            config,
            credentials: None,
            relayed: None,
            expires: None,
            renew_at: None,
            refresh_retry: RETRIES,
            failed: None,
            permissions: HashMap::new(),
            permission_retry: HashMap::new(),
            pending: Vec::new(),
            outbox: VecDeque::new(),
        };
        client.request(Request::Allocate, now, false);
        client
    }

    pub fn server(&self) -> SocketAddr {
        self.config.server
    }

    /// The address the server relays for us, once allocated.
    pub fn relayed(&self) -> Option<SocketAddr> {
        self.relayed.filter(|_| self.failed.is_none())
    }

    /// Why there is no allocation, once that is known.
    pub fn failed(&self) -> Option<&TurnError> {
        self.failed.as_ref()
    }

    /// A datagram from the server: a response (consumed), or what a peer sent us through the
    /// relay (returned with the peer's address).
    pub fn handle(&mut self, datagram: &[u8], now: Instant) -> Option<(SocketAddr, Vec<u8>)> {
        let mut message = Message::parse(datagram.to_vec()).ok()?;
        match (message.class(), message.method()) {
            (Class::Indication, Method::Data) => {
                let peer = message.attribute::<XorPeerAddress>()?.ok()?.0;
                let data = message.attribute::<Data>()?.ok()?.0.to_vec();
                self.permissions
                    .contains_key(&peer.ip())
                    .then_some((peer, data))
            }
            (Class::Success | Class::Error, _) => {
                let at = self
                    .pending
                    .iter()
                    .position(|p| p.id == message.transaction_id())?;
                if !self.authentic(&mut message) {
                    return None;
                }
                let pending = self.pending.swap_remove(at);
                if message.class() == Class::Success {
                    self.succeeded(pending.request, &mut message, now);
                } else {
                    self.refused(pending, &mut message, now);
                }
                None
            }
            _ => None,
        }
    }

    /// Whether a response carries our key's integrity (when we have a key and it has one).
    fn authentic(&self, message: &mut Message) -> bool {
        let Some(credentials) = &self.credentials else {
            return true;
        };
        let key = MessageIntegrityKey::new(&credentials.key);
        !matches!(
            message.attribute_with::<MessageIntegrity>(key),
            Some(Err(_))
        )
    }

    fn succeeded(&mut self, request: Request, message: &mut Message, now: Instant) {
        let lifetime = message.attribute::<Lifetime>().and_then(Result::ok);
        match request {
            Request::Allocate => {
                let relayed = message
                    .attribute::<XorRelayedAddress>()
                    .and_then(Result::ok)
                    .ok_or_else(|| "no relayed address in its answer".to_owned())
                    .and_then(|a| {
                        media_target(a.0, self.config.server)
                            .map_err(|why| format!("a relayed address peers cannot use: {why}"))
                    });
                match relayed {
                    Ok(relayed) => {
                        self.relayed = Some(relayed);
                        self.granted(lifetime.map_or(ASKED_LIFETIME, |l| l.0), now);
                    }
                    Err(reason) => {
                        self.failed = Some(TurnError::Refused {
                            server: self.config.server,
                            code: 0,
                            reason,
                        })
                    }
                }
            }
            Request::Refresh { .. } => match lifetime {
                Some(l) => self.granted(l.0, now),
                // RFC 8656 answers with the lifetime; without it nothing is known: ask later.
                None => self.refresh_failed(now),
            },
            Request::Permission(ip) => {
                self.permission_retry.remove(&ip);
                self.permissions.insert(ip, now + PERMISSION_LIFETIME);
            }
        }
    }

    /// The allocation lasts `seconds` from `now`: refreshed a minute before it ends, but no
    /// sooner than half of it from now; a grant under [`MIN_LIFETIME`] ends it.
    fn granted(&mut self, seconds: u32, now: Instant) {
        let lifetime = Duration::from_secs(u64::from(seconds));
        if lifetime < MIN_LIFETIME {
            self.lose(TurnError::ShortLifetime {
                server: self.config.server,
                seconds,
            });
            return;
        }
        let lifetime = lifetime.min(MAX_LIFETIME);
        self.expires = Some(now + lifetime);
        self.renew_at = Some(now + lifetime.saturating_sub(RENEW_BEFORE).max(lifetime / 2));
        self.refresh_retry.reset();
    }

    /// The allocation is over (said where it was in use: a refused one is said by its asker).
    fn lose(&mut self, why: TurnError) {
        if self.relayed().is_some() && self.expires.is_some() {
            tracing::warn!("{why}: nothing more goes through the relay");
        }
        self.failed = Some(why);
        self.renew_at = None;
    }

    /// Whether `source` is the relayed address, even of an allocation that has ended: what
    /// was to leave from it must go through the relay or not at all.
    pub fn relays_from(&self, source: SocketAddr) -> bool {
        self.relayed == Some(source)
    }

    /// A Refresh was refused or never answered: tried again after a wait that doubles (the
    /// allocation ends when it expires meanwhile).
    fn refresh_failed(&mut self, now: Instant) {
        self.renew_at = Some(now + self.refresh_retry.next_wait());
    }

    /// A permission was refused or never answered: not asked again for a wait that doubles.
    fn permission_failed(&mut self, ip: IpAddr, now: Instant) {
        let mut retries = self
            .permission_retry
            .remove(&ip)
            .map_or(RETRIES, |(_, retries)| retries);
        let wait = retries.next_wait();
        self.permission_retry.insert(ip, (now + wait, retries));
    }

    fn refused(&mut self, pending: Pending, message: &mut Message, now: Instant) {
        let (code, reason) = match message.attribute::<ErrorCode>() {
            Some(Ok(e)) => (e.number, e.reason.to_string()),
            _ => (0, String::new()),
        };
        // 401: the challenge (realm and nonce); 438: our nonce went stale. Either way ask
        // again with what the server gave, once.
        if matches!(code, 401 | 438) && !pending.authenticated_again {
            let realm = message
                .attribute::<Realm>()
                .and_then(Result::ok)
                .map(|r| r.0.to_string())
                .or_else(|| self.credentials.as_ref().map(|c| c.realm.clone()));
            let nonce = message
                .attribute::<Nonce>()
                .and_then(Result::ok)
                .map(|n| n.0.to_vec());
            if let (Some(realm), Some(nonce)) = (realm, nonce) {
                let key =
                    long_term_password_md5(&self.config.username, &realm, &self.config.password);
                self.credentials = Some(Credentials { realm, nonce, key });
                self.request(pending.request, now, true);
                return;
            }
        }
        match pending.request {
            Request::Allocate if matches!(code, 401 | 438) => {
                self.failed = Some(TurnError::BadCredentials(self.config.server));
            }
            Request::Allocate => {
                self.failed = Some(TurnError::Refused {
                    server: self.config.server,
                    code,
                    reason,
                })
            }
            // 437: the allocation is gone on the server.
            Request::Refresh { .. } if code == 437 => {
                self.lose(TurnError::Refused {
                    server: self.config.server,
                    code,
                    reason,
                });
            }
            Request::Refresh { .. } | Request::Permission(_) => {
                tracing::warn!(
                    "TURN server {} refused a {:?}: {code} {reason}",
                    self.config.server,
                    pending.request
                );
                match pending.request {
                    Request::Permission(ip) => self.permission_failed(ip, now),
                    _ => self.refresh_failed(now),
                }
            }
        }
    }

    /// Sends `data` to `peer` through the relay (asking the relay to let the peer through
    /// first, if it does not yet). False when there is no allocation to send from.
    pub fn send_to(&mut self, peer: SocketAddr, data: &[u8], now: Instant) -> bool {
        if self.relayed().is_none() {
            return false;
        }
        self.permit(peer.ip(), now);
        let mut builder =
            MessageBuilder::new(Class::Indication, Method::Send, TransactionId::random());
        builder.add_attr(XorPeerAddress(peer));
        builder.add_attr(Data::new(data));
        self.outbox.push_back(builder.finish());
        true
    }

    /// Asks for (or renews) a permission for `ip`, unless one is good or on its way, a
    /// failed one waits to be tried again, or [`MOST_PEERS`] others are held.
    fn permit(&mut self, ip: IpAddr, now: Instant) {
        let good = self
            .permissions
            .get(&ip)
            .is_some_and(|&until| until > now + RENEW_BEFORE);
        let asked = self
            .pending
            .iter()
            .any(|p| p.request == Request::Permission(ip));
        let waiting = self
            .permission_retry
            .get(&ip)
            .is_some_and(|&(at, _)| at > now);
        let known = self.permissions.contains_key(&ip) || self.permission_retry.contains_key(&ip);
        let room = known || self.permissions.len() + self.permission_retry.len() < MOST_PEERS;
        if !good && !asked && !waiting && room {
            self.request(Request::Permission(ip), now, false);
        }
    }

    /// Gives a live allocation back (a Refresh with lifetime 0); nothing more is relayed.
    pub fn close(&mut self, now: Instant) {
        if self.relayed.take().is_some() && self.failed.is_none() {
            self.request(Request::Refresh { lifetime: 0 }, now, false);
            // Sent once, not waited for.
            self.pending.clear();
        }
        self.permissions.clear();
    }

    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.outbox.pop_front()
    }

    /// When [`Self::handle_timeout`] has something to do.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let retries = self.pending.iter().map(|p| p.timer.wake());
        let allocation = self
            .relayed()
            .and(self.renew_at.into_iter().chain(self.expires).min());
        // Permissions in use are renewed by sends; the timeout only lets the others lapse.
        let permissions = self.permissions.values().copied();
        retries.chain(allocation).chain(permissions).min()
    }

    pub fn handle_timeout(&mut self, now: Instant) {
        let mut gave_up = Vec::new();
        for p in &mut self.pending {
            if p.timer.expired(now) {
                gave_up.push(p.request);
            } else if p.timer.resend(now) {
                self.outbox.push_back(p.bytes.clone());
            }
        }
        self.pending.retain(|p| !p.timer.expired(now));
        for request in gave_up {
            match request {
                Request::Allocate => self.failed = Some(TurnError::NoAnswer(self.config.server)),
                Request::Refresh { .. } => self.refresh_failed(now),
                Request::Permission(ip) => self.permission_failed(ip, now),
            }
        }
        self.permissions.retain(|_, until| *until > now);
        self.permission_retry
            .retain(|_, (at, _)| *at + LONGEST_RETRY > now);
        if self.relayed().is_none() {
            return;
        }
        if self.expires.is_some_and(|e| e <= now) {
            self.lose(TurnError::Expired(self.config.server));
            return;
        }
        if self.renew_at.is_some_and(|at| at <= now) {
            self.renew_at = None;
            self.request(
                Request::Refresh {
                    lifetime: ASKED_LIFETIME,
                },
                now,
                false,
            );
        }
    }

    /// Sends `request` (with our credentials, once the server has challenged us).
    fn request(&mut self, request: Request, now: Instant, again: bool) {
        let id = TransactionId::random();
        let method = match request {
            Request::Allocate => Method::Allocate,
            Request::Refresh { .. } => Method::Refresh,
            Request::Permission(_) => Method::CreatePermission,
        };
        let mut builder = MessageBuilder::new(Class::Request, method, id);
        match request {
            Request::Allocate => builder.add_attr(RequestedTransport {
                protocol_number: UDP,
            }),
            Request::Refresh { lifetime } => builder.add_attr(Lifetime(lifetime)),
            Request::Permission(ip) => builder.add_attr(XorPeerAddress(SocketAddr::new(ip, 0))),
        }
        if let Some(c) = &self.credentials {
            builder.add_attr(Username::new(&self.config.username));
            builder.add_attr(Realm::new(&c.realm));
            builder.add_attr(Nonce::new(&c.nonce));
            builder.add_attr_with(MessageIntegrity, MessageIntegrityKey::new(&c.key));
        }
        let bytes = builder.finish();
        self.outbox.push_back(bytes.clone());
        self.pending.push(Pending {
            id,
            request,
            bytes,
            timer: Retransmit::new(now, REQUEST_TIMEOUT),
            authenticated_again: again,
        });
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use proptest::prelude::*;

    const SERVER: &str = "192.0.2.10:3478";

    fn client(now: Instant) -> TurnClient {
        TurnClient::new(
            TurnConfig {
                server: SERVER.parse().unwrap(),
                username: "ann".into(),
                password: "secret".into(),
            },
            now,
        )
    }

    /// A server's answer to the request in `request`.
    fn answer(
        request: &[u8],
        class: Class,
        add: impl FnOnce(&mut MessageBuilder),
    ) -> (Method, Vec<u8>) {
        let parsed = Message::parse(request.to_vec()).unwrap();
        let mut b = MessageBuilder::new(class, parsed.method(), parsed.transaction_id());
        add(&mut b);
        (parsed.method(), b.finish())
    }

    /// A server's unauthenticated success answer to an Allocate `request`.
    pub(crate) fn allocated(request: &[u8], relayed: SocketAddr) -> Vec<u8> {
        answer(request, Class::Success, |b| {
            b.add_attr(XorRelayedAddress(relayed));
            b.add_attr(Lifetime(600));
        })
        .1
    }

    #[test]
    fn a_challenged_allocation_is_asked_again_with_the_key_and_relays() {
        let now = Instant::now();
        let mut c = client(now);
        let first = c.poll_transmit().unwrap();
        let (method, challenge) = answer(&first, Class::Error, |b| {
            b.add_attr(ErrorCode {
                number: 401,
                reason: "Unauthorized",
            });
            b.add_attr(Realm::new("lipcall.test"));
            b.add_attr(Nonce::new(b"n0nce"));
        });
        assert_eq!(method, Method::Allocate);
        assert_eq!(c.handle(&challenge, now), None);
        let second = c.poll_transmit().unwrap();
        let mut parsed = Message::parse(second.clone()).unwrap();
        assert_eq!(parsed.attribute::<Username>().unwrap().unwrap().0, "ann");
        let key = long_term_password_md5("ann", "lipcall.test", "secret");
        assert!(matches!(
            parsed.attribute_with::<MessageIntegrity>(MessageIntegrityKey::new(&key)),
            Some(Ok(_))
        ));
        let relayed: SocketAddr = "192.0.2.10:50000".parse().unwrap();
        let (_, ok) = answer(&second, Class::Success, |b| {
            b.add_attr(XorRelayedAddress(relayed));
            b.add_attr(Lifetime(600));
            b.add_attr_with(MessageIntegrity, MessageIntegrityKey::new(&key));
        });
        c.handle(&ok, now);
        assert_eq!(c.relayed(), Some(relayed));

        // Sending asks for a permission, then goes out as a Send indication.
        let peer: SocketAddr = "198.51.100.3:4000".parse().unwrap();
        assert!(c.send_to(peer, b"hello", now));
        let permission = c.poll_transmit().unwrap();
        let send = c.poll_transmit().unwrap();
        let mut s = Message::parse(send).unwrap();
        assert_eq!((s.class(), s.method()), (Class::Indication, Method::Send));
        assert_eq!(s.attribute::<XorPeerAddress>().unwrap().unwrap().0, peer);
        let (method, granted) = answer(&permission, Class::Success, |b| {
            b.add_attr_with(MessageIntegrity, MessageIntegrityKey::new(&key));
        });
        assert_eq!(method, Method::CreatePermission);
        c.handle(&granted, now);

        // What the peer sends comes back out with its address.
        let mut data =
            MessageBuilder::new(Class::Indication, Method::Data, TransactionId::random());
        data.add_attr(XorPeerAddress(peer));
        data.add_attr(Data::new(b"hi back"));
        assert_eq!(
            c.handle(&data.finish(), now),
            Some((peer, b"hi back".to_vec()))
        );

        // Refreshed before it runs out.
        let later = now + Duration::from_secs(560);
        assert!(c.poll_timeout().unwrap() <= later);
        c.handle_timeout(later);
        let refresh = std::iter::from_fn(|| c.poll_transmit())
            .map(|m| Message::parse(m).unwrap())
            .find(|m| m.method() == Method::Refresh);
        assert!(refresh.is_some());
    }

    #[test]
    fn an_odd_relayed_address_fails_the_allocation() {
        let now = Instant::now();
        for odd in ["0.0.0.0:50000", "224.0.0.1:50000", "[2001:db8::1]:50000"] {
            let mut c = client(now);
            let request = c.poll_transmit().unwrap();
            let (_, ok) = answer(&request, Class::Success, |b| {
                b.add_attr(XorRelayedAddress(odd.parse().unwrap()));
            });
            c.handle(&ok, now);
            assert_eq!(c.relayed(), None);
            let failed = c.failed().map(ToString::to_string).unwrap_or_default();
            assert!(failed.contains(odd), "{odd}: {failed:?}");
        }
    }

    #[test]
    fn a_second_challenge_means_wrong_credentials() {
        let now = Instant::now();
        let mut c = client(now);
        for _ in 0..2 {
            let request = c.poll_transmit().unwrap();
            let (_, challenge) = answer(&request, Class::Error, |b| {
                b.add_attr(ErrorCode {
                    number: 401,
                    reason: "Unauthorized",
                });
                b.add_attr(Realm::new("lipcall.test"));
                b.add_attr(Nonce::new(b"n0nce"));
            });
            c.handle(&challenge, now);
        }
        assert_eq!(
            c.failed(),
            Some(&TurnError::BadCredentials(SERVER.parse().unwrap()))
        );
        assert_eq!(c.relayed(), None);
        assert!(!c.send_to("198.51.100.3:4000".parse().unwrap(), b"x", now));
    }

    #[test]
    fn a_silent_server_is_retried_then_given_up() {
        let now = Instant::now();
        let mut c = client(now);
        let mut sent = 0;
        let mut t = now;
        while c.failed().is_none() && t < now + Duration::from_secs(20) {
            while c.poll_transmit().is_some() {
                sent += 1;
            }
            t = c.poll_timeout().unwrap().max(t);
            c.handle_timeout(t);
        }
        assert_eq!(
            c.failed(),
            Some(&TurnError::NoAnswer(SERVER.parse().unwrap()))
        );
        // RFC 8489's Rc: 7 sends, 250 ms apart at first, then doubling to 2 s.
        assert_eq!(sent, 7);
        assert!(t <= now + REQUEST_TIMEOUT + Duration::from_millis(1));
    }

    /// Runs a client for `seconds` of simulated time, sending a datagram for a peer every
    /// 20 ms when `sending`. Each request it sends is answered at once with what `server`
    /// makes of it (none: never answered). The client, and the requests that went out by
    /// method, retransmissions included; a client asking more than 10,000 times is stopped.
    fn simulate(
        seconds: u64,
        sending: bool,
        mut server: impl FnMut(Method, &[u8]) -> Option<Vec<u8>>,
    ) -> (TurnClient, HashMap<Method, usize>) {
        let start = Instant::now();
        let mut c = client(start);
        let peer: SocketAddr = "198.51.100.3:4000".parse().unwrap();
        let end = start + Duration::from_secs(seconds);
        let mut sent: HashMap<Method, usize> = HashMap::new();
        let (mut now, mut next_send) = (start, start);
        while now < end && sent.values().sum::<usize>() <= 10_000 {
            if sending && next_send <= now {
                c.send_to(peer, b"rtp", now);
                next_send = now + Duration::from_millis(20);
            }
            while let Some(out) = c.poll_transmit() {
                let parsed = Message::parse(out.clone()).unwrap();
                if parsed.class() == Class::Request {
                    *sent.entry(parsed.method()).or_default() += 1;
                    if let Some(answer) = server(parsed.method(), &out) {
                        c.handle(&answer, now);
                    }
                }
            }
            let due = c.poll_timeout();
            let next = match (due, sending) {
                (Some(due), true) => due.min(next_send),
                (Some(due), false) => due,
                (None, true) => next_send,
                (None, false) => end,
            };
            now = next.max(now + Duration::from_millis(1)).min(end);
            if due.is_some_and(|due| due <= now) {
                c.handle_timeout(now);
            }
        }
        (c, sent)
    }

    fn granted(request: &[u8], seconds: u32) -> Vec<u8> {
        answer(request, Class::Success, |b| {
            b.add_attr(XorRelayedAddress("192.0.2.10:50000".parse().unwrap()));
            b.add_attr(Lifetime(seconds));
        })
        .1
    }

    fn refused(request: &[u8], number: u32) -> Vec<u8> {
        answer(request, Class::Error, |b| {
            b.add_attr(ErrorCode {
                number,
                reason: "no",
            })
        })
        .1
    }

    fn count(sent: &HashMap<Method, usize>, method: Method) -> usize {
        sent.get(&method).copied().unwrap_or(0)
    }

    #[test]
    fn a_relay_granted_for_0_s_is_a_failure_not_a_storm_of_refreshes() {
        let (c, sent) = simulate(3600, true, |method, r| {
            Some(match method {
                Method::Allocate => granted(r, 0),
                _ => answer(r, Class::Success, |b| b.add_attr(Lifetime(0))).1,
            })
        });
        let server = SERVER.parse().unwrap();
        assert_eq!(
            c.failed(),
            Some(&TurnError::ShortLifetime { server, seconds: 0 })
        );
        assert_eq!(c.relayed(), None);
        assert!(count(&sent, Method::Refresh) < 10, "{sent:?}");
    }

    #[test]
    fn a_refresh_answered_with_0_s_ends_the_relay_after_one_refresh() {
        let (c, sent) = simulate(3600, true, |method, r| {
            Some(match method {
                Method::Allocate => granted(r, 600),
                Method::Refresh => answer(r, Class::Success, |b| b.add_attr(Lifetime(0))).1,
                _ => answer(r, Class::Success, |_| {}).1,
            })
        });
        assert_eq!(count(&sent, Method::Refresh), 1, "{sent:?}");
        assert!(
            matches!(c.failed(), Some(TurnError::ShortLifetime { .. })),
            "{:?}",
            c.failed()
        );
    }

    #[test]
    fn a_short_grant_is_refreshed_at_half_its_lifetime() {
        let (c, sent) = simulate(3600, false, |method, r| {
            Some(match method {
                Method::Allocate => granted(r, 30),
                _ => answer(r, Class::Success, |b| b.add_attr(Lifetime(30))).1,
            })
        });
        // At 15, 30, ... 3585 s, and the relay kept.
        assert_eq!(count(&sent, Method::Refresh), 239, "{sent:?}");
        assert!(c.relayed().is_some(), "{:?}", c.failed());
    }

    #[test]
    fn refused_or_unanswered_refreshes_back_off_until_the_relay_expires() {
        for answered in [true, false] {
            let (c, sent) = simulate(3600, false, |method, r| match method {
                Method::Allocate => Some(granted(r, 600)),
                _ => answered.then(|| refused(r, 500)),
            });
            // Refused: at 540, 545, 555 and 575 s; unanswered: each sent 7 times (RFC 8489's
            // Rc) in the 8 s it is waited for.
            let most = if answered { 4 } else { 4 * 7 };
            assert!(count(&sent, Method::Refresh) <= most, "{sent:?}");
            assert_eq!(
                c.failed(),
                Some(&TurnError::Expired(SERVER.parse().unwrap())),
                "answered: {answered}"
            );
            assert_eq!(c.relayed(), None);
        }
    }

    #[test]
    fn a_refused_permission_is_asked_again_after_a_wait_that_doubles() {
        let (c, sent) = simulate(120, true, |method, r| {
            Some(match method {
                Method::Allocate => granted(r, 600),
                _ => refused(r, 403),
            })
        });
        // At 0, 5, 15, 35 and 75 s, where every send (50 a second) used to ask again.
        assert_eq!(count(&sent, Method::CreatePermission), 5, "{sent:?}");
        assert!(c.relayed().is_some());
    }

    proptest! {
        #[test]
        fn any_datagram_is_handled_without_panic(data in proptest::collection::vec(any::<u8>(), 0..300)) {
            let mut c = client(Instant::now());
            let _ = c.handle(&data, Instant::now());
        }
    }
}
