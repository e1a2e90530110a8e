//! The addresses we offer Janus's ICE: our host addresses, and the one a STUN server sees
//! from outside a NAT (a server-reflexive candidate).

use std::net::{IpAddr, SocketAddr, UdpSocket};
use std::time::Duration;

use super::JanusError;
use crate::net::stun;

/// How long a join waits for the STUN server before offering local addresses only.
const STUN_WAIT: Duration = Duration::from_millis(1500);

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
    let asked = stun::resolve_server(server, family).and_then(|server| {
        stun::reflexive_address(socket, server, STUN_WAIT).map(|public| (server, public))
    });
    match asked {
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
