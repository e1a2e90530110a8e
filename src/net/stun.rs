//! Our address as seen from outside a NAT: a STUN Binding request (RFC 8489) from the media
//! socket, for ICE's server-reflexive candidate. Messages are built and read with
//! `ezk-stun-types`; what is asked, retried and believed is decided here, by a sans-I/O
//! [`StunTransaction`] (bytes out, datagrams and timeouts in, an outcome) that a socket's
//! owner drives. [`reflexive_address`] drives one on a blocking socket for those that may wait.

use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use ezk_stun_types::attributes::{ErrorCode, MappedAddress, XorMappedAddress};
use ezk_stun_types::{Class, Message, MessageBuilder, Method, TransactionId};

use crate::net::addr::{OddAddress, media_target};
use crate::net::host_port::HostPort;

/// RFC 8489 6.2.1's first retransmission timeout; each retry doubles it, up to
/// [`LONGEST_RTO`].
const FIRST_RTO: Duration = Duration::from_millis(250);
const LONGEST_RTO: Duration = Duration::from_secs(2);
/// Requests sent at most (RFC 8489's Rc); after the last the answer is awaited until the
/// transaction's deadline.
const MOST_SENDS: u32 = 7;
/// How long a call waits for the STUN server before going on with its local address.
pub const ASK_WAIT: Duration = Duration::from_millis(1500);

#[derive(Debug, Clone, thiserror::Error, PartialEq, Eq)]
pub enum StunError {
    #[error("STUN server {0:?}: give it as HOST[:PORT] (e.g. stun.example.org:3478)")]
    BadServer(String),
    #[error("STUN server {0:?} does not resolve to an address of the media socket's family")]
    Unresolved(String),
    #[error("STUN server {server} did not answer within {waited:?}")]
    NoAnswer {
        server: SocketAddr,
        waited: Duration,
    },
    #[error("STUN server {server} refused the request: {code} {reason}")]
    Refused {
        server: SocketAddr,
        code: u32,
        reason: String,
    },
    #[error("STUN server {0} answered without an address")]
    NoAddress(SocketAddr),
    #[error("STUN server {server} answered an address we cannot be reached at: {why}")]
    OddAddress { server: SocketAddr, why: OddAddress },
    #[error("STUN on the media socket: {0}")]
    Io(String),
}

/// STUN's and TURN's port where a server's address gives none (RFC 8489).
pub const STUN_PORT: u16 = 3478;

/// Resolves `HOST[:PORT]` (or `stun:HOST[:PORT]`) to an address of the family of `like` (the
/// socket it is asked from).
pub fn resolve_server(server: &str, like: SocketAddr) -> Result<SocketAddr, StunError> {
    let server = server.trim();
    let server = server.strip_prefix("stun:").unwrap_or(server);
    HostPort::parse(server)
        .map_err(|_| StunError::BadServer(server.to_string()))?
        .resolve_like(STUN_PORT, like)
        .map_err(|_| StunError::Unresolved(server.to_string()))
}

/// Asks the server named `server` (HOST:PORT) from `socket`, whose address is `local`, what
/// address our datagrams come from, waiting [`ASK_WAIT`] at most: the server and that address.
pub fn ask(
    socket: &UdpSocket,
    server: &str,
    local: SocketAddr,
) -> Result<(SocketAddr, SocketAddr), StunError> {
    let server = resolve_server(server, local)?;
    reflexive_address(socket, server, ASK_WAIT).map(|public| (server, public))
}

/// A Binding request and the transaction id its answer must carry.
pub fn binding_request() -> (TransactionId, Vec<u8>) {
    let id = TransactionId::random();
    let mut builder = MessageBuilder::new(Class::Request, Method::Binding, id);
    builder.set_len(0);
    (id, builder.finish())
}

/// What a datagram says in answer to transaction `id`: `None` if it is no answer to it (not
/// STUN, another transaction, an indication).
pub fn read_answer(
    datagram: &[u8],
    id: TransactionId,
    server: SocketAddr,
) -> Option<Result<SocketAddr, StunError>> {
    let mut message = Message::parse(datagram.to_vec()).ok()?;
    if message.transaction_id() != id || message.method() != Method::Binding {
        return None;
    }
    match message.class() {
        Class::Success => {
            let xor = message
                .attribute::<XorMappedAddress>()
                .and_then(Result::ok)
                .map(|a| a.0);
            let plain = || {
                message
                    .attribute::<MappedAddress>()
                    .and_then(Result::ok)
                    .map(|a| a.0)
            };
            let mapped = xor.or_else(plain).ok_or(StunError::NoAddress(server));
            // The server sees us over its own family: the address must be of it too.
            Some(mapped.and_then(|mapped| {
                media_target(mapped, server).map_err(|why| StunError::OddAddress { server, why })
            }))
        }
        Class::Error => {
            let (code, reason) = match message.attribute::<ErrorCode>() {
                Some(Ok(e)) => (e.number, e.reason.to_string()),
                _ => (0, "(no error code)".to_string()),
            };
            Some(Err(StunError::Refused {
                server,
                code,
                reason,
            }))
        }
        _ => None,
    }
}

/// When one STUN request (a Binding, a TURN Allocate or Refresh) goes out again, as RFC 8489
/// 6.2.1 says: the timeout doubling from [`FIRST_RTO`] to [`LONGEST_RTO`], [`MOST_SENDS`]
/// sends at most, then waiting out the deadline.
#[derive(Debug, Clone)]
pub struct Retransmit {
    deadline: Instant,
    /// When the request goes out again (none after the last send).
    resend_at: Option<Instant>,
    rto: Duration,
    sends: u32,
}

impl Retransmit {
    /// The first send is at `now`; the request has failed at `now + wait`.
    pub fn new(now: Instant, wait: Duration) -> Self {
        Self {
            deadline: now.checked_add(wait).unwrap_or(now + LONGEST_RTO),
            resend_at: Some(now + FIRST_RTO),
            rto: FIRST_RTO,
            sends: 1,
        }
    }

    /// The next instant something is due: a resend or the deadline.
    pub fn wake(&self) -> Instant {
        self.resend_at
            .map_or(self.deadline, |at| at.min(self.deadline))
    }

    pub fn expired(&self, now: Instant) -> bool {
        now >= self.deadline
    }

    /// Whether the request is to go out again at `now` (the next resend is then scheduled).
    pub fn resend(&mut self, now: Instant) -> bool {
        if self.expired(now) || self.resend_at.is_none_or(|at| at > now) {
            return false;
        }
        self.sends += 1;
        self.rto = (self.rto * 2).min(LONGEST_RTO);
        self.resend_at = (self.sends < MOST_SENDS).then(|| now + self.rto);
        true
    }

    /// Sends so far, the first included.
    pub fn sends(&self) -> u32 {
        self.sends
    }
}

/// One Binding request to one server, retransmitted ([`Retransmit`]) until an answer or the
/// deadline. An address the answer names that media cannot go to (unspecified, broadcast,
/// multicast, another family than the server's) is refused, not believed.
#[derive(Debug)]
pub struct StunTransaction {
    server: SocketAddr,
    id: TransactionId,
    request: Vec<u8>,
    waited: Duration,
    timer: Retransmit,
    /// The request is to go out.
    due: bool,
    outcome: Option<Result<SocketAddr, StunError>>,
}

impl StunTransaction {
    /// Asks `server` from `now`, giving up at `now + wait`; the first request is due at once.
    pub fn new(server: SocketAddr, now: Instant, wait: Duration) -> Self {
        let (id, request) = binding_request();
        Self {
            server,
            id,
            request,
            waited: wait,
            timer: Retransmit::new(now, wait),
            due: true,
            outcome: None,
        }
    }

    pub fn server(&self) -> SocketAddr {
        self.server
    }

    /// The request to send to [`Self::server`], when one is due.
    pub fn poll_transmit(&mut self) -> Option<&[u8]> {
        std::mem::take(&mut self.due).then_some(self.request.as_slice())
    }

    /// Reads a datagram from `from`: true when it was the answer (the transaction is over).
    pub fn handle_datagram(&mut self, datagram: &[u8], from: SocketAddr) -> bool {
        if self.outcome.is_some() || from != self.server {
            return false;
        }
        let Some(answer) = read_answer(datagram, self.id, self.server) else {
            return false;
        };
        self.finish(answer);
        true
    }

    /// When [`Self::handle_timeout`] has something to do; none once it is over.
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.outcome.is_none().then(|| self.timer.wake())
    }

    pub fn handle_timeout(&mut self, now: Instant) {
        if self.outcome.is_some() {
            return;
        }
        if self.timer.expired(now) {
            let server = self.server;
            let waited = self.waited;
            self.finish(Err(StunError::NoAnswer { server, waited }));
            return;
        }
        self.due |= self.timer.resend(now);
    }

    /// The address the server saw us at, or why there is none; `None` while it is asking.
    pub fn outcome(&self) -> Option<&Result<SocketAddr, StunError>> {
        self.outcome.as_ref()
    }

    /// Requests sent so far.
    pub fn sends(&self) -> u32 {
        self.timer.sends() - u32::from(self.due)
    }

    fn finish(&mut self, outcome: Result<SocketAddr, StunError>) {
        self.outcome = Some(outcome);
        self.due = false;
    }
}

/// Asks `server` from `socket` what address our datagrams come from, waiting `wait` at most:
/// a [`StunTransaction`] driven on the socket, blocking its caller. Other datagrams arriving
/// meanwhile are dropped: ask before the socket carries media, off any thread that must not
/// wait.
pub fn reflexive_address(
    socket: &UdpSocket,
    server: SocketAddr,
    wait: Duration,
) -> Result<SocketAddr, StunError> {
    let io = |e: std::io::Error| StunError::Io(e.to_string());
    let before = socket.read_timeout().map_err(io)?;
    let mut transaction = StunTransaction::new(server, Instant::now(), wait);
    let answer = drive(socket, &mut transaction);
    socket.set_read_timeout(before).map_err(io)?;
    answer
}

fn drive(socket: &UdpSocket, transaction: &mut StunTransaction) -> Result<SocketAddr, StunError> {
    let io = |e: std::io::Error| StunError::Io(e.to_string());
    let server = transaction.server();
    let mut buf = [0u8; crate::net::MAX_DATAGRAM];
    loop {
        if let Some(request) = transaction.poll_transmit() {
            socket.send_to(request, server).map_err(io)?;
        }
        let Some(wake) = transaction.poll_timeout() else {
            return transaction
                .outcome()
                .cloned()
                .unwrap_or(Err(StunError::NoAddress(server)));
        };
        let now = Instant::now();
        if wake <= now {
            transaction.handle_timeout(now);
            continue;
        }
        socket.set_read_timeout(Some(wake - now)).map_err(io)?;
        match socket.recv_from(&mut buf) {
            Ok((n, from)) => {
                transaction.handle_datagram(&buf[..n], from);
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            // An ICMP port unreachable from an earlier try: keep asking until the deadline.
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {}
            Err(e) => return Err(io(e)),
        }
    }
}

/// [`reflexive_address`] for several sockets at once (a call's RTP and RTCP), each on a
/// thread of its own: the whole waits `wait` at most, not `wait` per socket.
pub fn reflexive_addresses(
    sockets: &[&UdpSocket],
    server: SocketAddr,
    wait: Duration,
) -> Vec<Result<SocketAddr, StunError>> {
    std::thread::scope(|scope| {
        let asking: Vec<_> = sockets
            .iter()
            .map(|socket| scope.spawn(move || reflexive_address(socket, server, wait)))
            .collect();
        asking
            .into_iter()
            .map(|asked| {
                asked
                    .join()
                    .unwrap_or_else(|_| Err(StunError::Io("the STUN asker panicked".into())))
            })
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn answer(class: Class, id: TransactionId, addr: Option<SocketAddr>) -> Vec<u8> {
        let mut b = MessageBuilder::new(class, Method::Binding, id);
        if let Some(a) = addr {
            b.add_attr(XorMappedAddress(a));
        }
        b.finish()
    }

    #[test]
    fn a_success_answer_gives_the_mapped_address() {
        let server: SocketAddr = "192.0.2.1:3478".parse().unwrap();
        let (id, request) = binding_request();
        let parsed = Message::parse(request).unwrap();
        assert_eq!(
            (parsed.class(), parsed.method()),
            (Class::Request, Method::Binding)
        );
        let public: SocketAddr = "198.51.100.7:40000".parse().unwrap();
        let reply = answer(Class::Success, id, Some(public));
        assert_eq!(read_answer(&reply, id, server), Some(Ok(public)));
        // Another transaction's answer, or one without an address.
        let (other, _) = binding_request();
        assert_eq!(read_answer(&reply, other, server), None);
        let bare = answer(Class::Success, id, None);
        assert_eq!(
            read_answer(&bare, id, server),
            Some(Err(StunError::NoAddress(server)))
        );
        let refused = answer(Class::Error, id, None);
        assert!(matches!(
            read_answer(&refused, id, server),
            Some(Err(StunError::Refused { .. }))
        ));
    }

    /// The instants (ms after the start) at which a transaction nobody answers sends, and when
    /// it gives up.
    fn unanswered(wait: Duration) -> (Vec<u128>, u128, StunTransaction) {
        let start = Instant::now();
        let server: SocketAddr = "192.0.2.1:3478".parse().unwrap();
        let mut t = StunTransaction::new(server, start, wait);
        let mut sent = Vec::new();
        let mut now = start;
        loop {
            while let Some(request) = t.poll_transmit() {
                let parsed = Message::parse(request.to_vec()).unwrap();
                assert_eq!(
                    parsed.transaction_id(),
                    t.id,
                    "a retransmission, not a new request"
                );
                sent.push((now - start).as_millis());
            }
            let Some(wake) = t.poll_timeout() else {
                return (sent, (now - start).as_millis(), t);
            };
            assert!(wake >= now, "a timeout in the past");
            now = wake;
            t.handle_timeout(now);
        }
    }

    #[test]
    fn retransmissions_double_up_to_a_cap_and_stop_at_the_deadline() {
        let (sent, over, t) = unanswered(ASK_WAIT);
        assert_eq!(sent, [0, 250, 750]);
        assert_eq!(over, 1500);
        assert_eq!(
            t.outcome(),
            Some(&Err(StunError::NoAnswer {
                server: t.server(),
                waited: ASK_WAIT
            }))
        );
        assert_eq!(t.sends(), 3);
        // A long wait: the timeout stops doubling at 2 s, and after 7 sends it only waits.
        let (sent, over, t) = unanswered(Duration::from_secs(60));
        assert_eq!(sent, [0, 250, 750, 1750, 3750, 5750, 7750]);
        assert_eq!((over, t.sends()), (60_000, MOST_SENDS));
        // No wait at all: one request, given up on at once.
        let (sent, over, _) = unanswered(Duration::ZERO);
        assert_eq!((sent, over), (vec![0], 0));
    }

    #[test]
    fn only_the_servers_answer_to_this_transaction_ends_it() {
        let now = Instant::now();
        let server: SocketAddr = "192.0.2.1:3478".parse().unwrap();
        let stranger: SocketAddr = "192.0.2.9:3478".parse().unwrap();
        let public: SocketAddr = "198.51.100.7:40000".parse().unwrap();
        let mut t = StunTransaction::new(server, now, ASK_WAIT);
        assert!(t.poll_transmit().is_some());
        let ours = answer(Class::Success, t.id, Some(public));
        let (other, _) = binding_request();
        assert!(!t.handle_datagram(&ours, stranger), "a stranger's answer");
        assert!(!t.handle_datagram(&answer(Class::Success, other, Some(public)), server));
        assert!(!t.handle_datagram(b"not STUN at all", server));
        assert!(t.outcome().is_none());
        assert!(t.handle_datagram(&ours, server));
        assert_eq!(t.outcome(), Some(&Ok(public)));
        assert_eq!((t.poll_timeout(), t.poll_transmit()), (None, None));
        // Over is over: a later answer or timeout changes nothing.
        assert!(!t.handle_datagram(&answer(Class::Error, t.id, None), server));
        t.handle_timeout(now + Duration::from_secs(10));
        assert_eq!(t.outcome(), Some(&Ok(public)));

        let mut refused = StunTransaction::new(server, now, ASK_WAIT);
        assert!(refused.handle_datagram(&answer(Class::Error, refused.id, None), server));
        assert!(matches!(
            refused.outcome(),
            Some(Err(StunError::Refused { .. }))
        ));
    }

    #[test]
    fn odd_mapped_addresses_are_refused_naming_them() {
        let now = Instant::now();
        let server: SocketAddr = "192.0.2.1:3478".parse().unwrap();
        for odd in [
            "0.0.0.0:4000",
            "255.255.255.255:4000",
            "224.0.0.1:4000",
            "[2001:db8::1]:4000",
        ] {
            let mut t = StunTransaction::new(server, now, ASK_WAIT);
            assert!(t.handle_datagram(
                &answer(Class::Success, t.id, Some(odd.parse().unwrap())),
                server
            ));
            let Some(Err(e @ StunError::OddAddress { .. })) = t.outcome() else {
                panic!("{odd}: {:?}", t.outcome());
            };
            assert!(e.to_string().contains(odd), "{e}");
        }
    }

    #[test]
    fn the_rtp_and_rtcp_sockets_are_asked_at_once() {
        let silent = UdpSocket::bind("127.0.0.1:0").unwrap();
        let server = silent.local_addr().unwrap();
        let rtp = UdpSocket::bind("127.0.0.1:0").unwrap();
        let rtcp = UdpSocket::bind("127.0.0.1:0").unwrap();
        let wait = Duration::from_secs(1);
        let start = Instant::now();
        let asked = reflexive_addresses(&[&rtp, &rtcp], server, wait);
        let took = start.elapsed();
        assert_eq!(asked.len(), 2);
        assert!(
            asked
                .iter()
                .all(|a| matches!(a, Err(StunError::NoAnswer { .. }))),
            "{asked:?}"
        );
        // One wait for both, not one after the other (generous under load).
        assert!(took < wait * 2 - Duration::from_millis(200), "{took:?}");
    }

    #[test]
    fn a_server_answering_an_odd_address_is_not_believed() {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        let server = UdpSocket::bind("127.0.0.1:0").unwrap();
        let server_addr = server.local_addr().unwrap();
        let answering = std::thread::spawn(move || {
            let mut buf = [0u8; 1500];
            for mapped in [
                "0.0.0.0:4000",
                "224.0.0.1:4000",
                "[::1]:4000",
                "127.0.0.1:4000",
            ] {
                let (n, from) = server.recv_from(&mut buf).unwrap();
                let request = Message::parse(buf[..n].to_vec()).unwrap();
                let reply = answer(
                    Class::Success,
                    request.transaction_id(),
                    Some(mapped.parse().unwrap()),
                );
                server.send_to(&reply, from).unwrap();
            }
        });
        let wait = Duration::from_secs(5);
        for odd in ["0.0.0.0:4000", "224.0.0.1:4000", "[::1]:4000"] {
            let e = reflexive_address(&socket, server_addr, wait).unwrap_err();
            assert!(matches!(e, StunError::OddAddress { .. }), "{e:?}");
            assert!(e.to_string().contains(odd), "{e}");
        }
        assert_eq!(
            reflexive_address(&socket, server_addr, wait),
            Ok("127.0.0.1:4000".parse().unwrap())
        );
        answering.join().unwrap();
    }

    #[test]
    fn a_silent_server_is_given_up_on_in_time() {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        // A bound socket that never answers.
        let silent = UdpSocket::bind("127.0.0.1:0").unwrap();
        let server = silent.local_addr().unwrap();
        let start = Instant::now();
        let r = reflexive_address(&socket, server, Duration::from_millis(600));
        assert!(matches!(r, Err(StunError::NoAnswer { .. })), "{r:?}");
        assert!(start.elapsed() < Duration::from_secs(2));
        // It asked again before giving up.
        silent
            .set_read_timeout(Some(Duration::from_millis(100)))
            .unwrap();
        let mut buf = [0u8; 100];
        let mut asked = 0;
        while silent.recv_from(&mut buf).is_ok() {
            asked += 1;
        }
        assert!(asked >= 2, "{asked}");
    }

    #[test]
    fn bad_server_names_are_said() {
        let like: SocketAddr = "127.0.0.1:1".parse().unwrap();
        assert!(matches!(
            resolve_server("no such:port", like),
            Err(StunError::BadServer(_))
        ));
        assert_eq!(
            resolve_server("127.0.0.1", like),
            Ok("127.0.0.1:3478".parse().unwrap())
        );
        assert_eq!(
            resolve_server("stun:127.0.0.1:3478", like),
            Ok("127.0.0.1:3478".parse().unwrap())
        );
        assert!(matches!(
            resolve_server("[::1]:3478", like),
            Err(StunError::Unresolved(_))
        ));
    }

    proptest! {
        #[test]
        fn any_datagram_is_read_without_panic(data in proptest::collection::vec(any::<u8>(), 0..200)) {
            let (id, _) = binding_request();
            let _ = read_answer(&data, id, "192.0.2.1:3478".parse().unwrap());
        }
    }
}
