//! Our address as seen from outside a NAT: a STUN Binding request (RFC 8489) from the media
//! socket, for ICE's server-reflexive candidate. Messages are built and read with
//! `ezk-stun-types`; what is asked, retried and believed is decided here.

use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use ezk_stun_types::attributes::{ErrorCode, MappedAddress, XorMappedAddress};
use ezk_stun_types::{Class, Message, MessageBuilder, Method, TransactionId};

use crate::net::addr::{OddAddress, media_target};
use crate::net::host_port::HostPort;

/// RFC 8489 6.2.1's first retransmission timeout; each retry doubles it.
const FIRST_RTO: Duration = Duration::from_millis(250);
/// How long a call waits for the STUN server before going on with its local address.
pub const ASK_WAIT: Duration = Duration::from_millis(1500);

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
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

/// Asks `server` from `socket` what address our datagrams come from, retrying as RFC 8489
/// does until `wait` has passed. Other datagrams arriving meanwhile are dropped: ask before
/// the socket carries media.
pub fn reflexive_address(
    socket: &UdpSocket,
    server: SocketAddr,
    wait: Duration,
) -> Result<SocketAddr, StunError> {
    let io = |e: std::io::Error| StunError::Io(e.to_string());
    let before = socket.read_timeout().map_err(io)?;
    let start = Instant::now();
    let deadline = start + wait;
    let (id, request) = binding_request();
    let mut rto = FIRST_RTO;
    let mut buf = [0u8; 1500];
    let answer = 'asking: loop {
        socket.send_to(&request, server).map_err(io)?;
        let resend = (Instant::now() + rto).min(deadline);
        rto *= 2;
        loop {
            let now = Instant::now();
            if now >= deadline {
                break 'asking Err(StunError::NoAnswer {
                    server,
                    waited: wait,
                });
            }
            if now >= resend {
                continue 'asking;
            }
            socket.set_read_timeout(Some(resend - now)).map_err(io)?;
            match socket.recv_from(&mut buf) {
                Ok((n, from)) if from == server => {
                    if let Some(answer) = read_answer(&buf[..n], id, server) {
                        break 'asking answer;
                    }
                }
                Ok(_) => {}
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                // An ICMP port unreachable from an earlier try: keep asking until the deadline.
                Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {}
                Err(e) => break 'asking Err(io(e)),
            }
        }
    };
    socket.set_read_timeout(before).map_err(io)?;
    answer
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
