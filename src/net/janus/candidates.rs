//! The addresses we offer Janus's ICE: our host addresses, the one a STUN server sees from
//! outside a NAT (a server-reflexive candidate), and a TURN server's relay (a relayed one).

use std::net::{IpAddr, SocketAddr, UdpSocket};
use std::time::Instant;

use super::JanusError;
use crate::net::host_port::HostPort;
use crate::net::stun::{self, STUN_PORT};
use crate::net::turn::{TurnClient, TurnConfig};

/// The servers that take a call across NATs, as the user gives them.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct IceServers {
    /// A STUN server, HOST:PORT.
    pub stun: Option<String>,
    pub turn: Option<TurnServer>,
    /// Offer the TURN relay's address only: all media goes through the relay, and the peer
    /// never learns our own addresses.
    pub relay_only: bool,
}

/// A TURN server and the long-term credentials it gave us.
#[derive(Clone, PartialEq, Eq)]
pub struct TurnServer {
    /// HOST:PORT, or `turn:HOST:PORT`.
    pub server: String,
    pub username: String,
    pub password: String,
}

impl std::fmt::Debug for TurnServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TurnServer")
            .field("server", &self.server)
            .field("username", &self.username)
            .finish_non_exhaustive()
    }
}

/// A TURN client for `turn`, asked from our media `port`, and the local address it asks from
/// (the base of its relayed candidate).
pub fn turn_client(
    turn: &TurnServer,
    port: u16,
    family: SocketAddr,
    now: Instant,
) -> Result<(TurnClient, SocketAddr), JanusError> {
    let name = turn.server.trim();
    let name = name.strip_prefix("turn:").unwrap_or(name);
    let server = HostPort::parse(name)
        .and_then(|h| h.resolve_like(STUN_PORT, family))
        .map_err(|e| JanusError::Media(format!("TURN server: {e}")))?;
    let base = SocketAddr::new(local_ip_towards(server.ip())?, port);
    let config = TurnConfig {
        server,
        username: turn.username.clone(),
        password: turn.password.clone(),
    };
    Ok((TurnClient::new(config, now), base))
}

/// The addresses we offer as host candidates for a Janus at `janus`: the one the kernel would
/// reach it from and, when that is loopback, the one towards the rest of the network. Janus
/// (libnice) never gathers loopback candidates, so even a Janus on 127.0.0.1 offers only the
/// machine's own interface addresses; the media still never leaves the machine.
pub fn host_ips(janus: IpAddr) -> Result<Vec<IpAddr>, JanusError> {
    let first = local_ip_towards(janus)?;
    let mut ips = vec![first];
    if first.is_loopback() {
        // A documentation address (RFC 5737, RFC 3849): only the route to it is looked up.
        let outside: IpAddr = if first.is_ipv4() {
            [203, 0, 113, 1].into()
        } else {
            "2001:db8::1".parse().unwrap_or(first)
        };
        if let Ok(ip) = local_ip_towards(outside)
            && !ip.is_loopback()
        {
            ips.push(ip);
        }
    }
    Ok(ips)
}

/// The local address to reach `remote` from.
pub fn local_ip_towards(remote: IpAddr) -> Result<IpAddr, JanusError> {
    let bind: SocketAddr = if remote.is_ipv4() {
        ([0, 0, 0, 0], 0).into()
    } else {
        (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
    };
    let probe = UdpSocket::bind(bind).map_err(|e| JanusError::Media(format!("UDP: {e}")))?;
    probe
        .connect((remote, 9))
        .map_err(|e| JanusError::Media(format!("no route to {remote}: {e}")))?;
    probe
        .local_addr()
        .map(|a| a.ip())
        .map_err(|e| JanusError::Media(format!("UDP: {e}")))
}

/// Our address outside the NAT and its local base, from `server`; none (said) when the server
/// cannot tell or sees a local address (no NAT on the way).
pub fn reflexive(
    socket: &UdpSocket,
    server: &str,
    port: u16,
    local: &[SocketAddr],
) -> Option<(SocketAddr, SocketAddr)> {
    let family = local.first().copied()?;
    match stun::ask(socket, server, family) {
        Ok((server, public)) => {
            let base = local_ip_towards(server.ip())
                .map(|ip| SocketAddr::new(ip, port))
                .unwrap_or(family);
            tracing::info!("STUN server {server}: our address outside is {public}");
            (!local.contains(&public)).then_some((public, base))
        }
        Err(e) => {
            tracing::warn!("{e}: offering local addresses only");
            None
        }
    }
}
