//! Whether an address a peer or a server gave us (SDP's `c=` and `m=` lines, a STUN mapped
//! address, a TURN relayed address) is one host we can send media to from our socket. The
//! unspecified address, broadcast, multicast, port 0 and the other address family are refused
//! here, once for every link, instead of sending there without a word.

use std::net::{IpAddr, SocketAddr};

#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum OddAddress {
    #[error("{0} is the unspecified address, no host")]
    Unspecified(SocketAddr),
    #[error("{0} is the broadcast address, no single host")]
    Broadcast(SocketAddr),
    #[error("{0} is a multicast address, no single host")]
    Multicast(SocketAddr),
    #[error("{0} has port 0")]
    NoPort(SocketAddr),
    #[error("{addr} is of another address family than our socket's {local}")]
    OtherFamily { addr: SocketAddr, local: SocketAddr },
}

/// `addr`, if media can be sent there from a socket bound to `local` (only its family counts).
pub fn media_target(addr: SocketAddr, local: SocketAddr) -> Result<SocketAddr, OddAddress> {
    if addr.is_ipv4() != local.is_ipv4() {
        return Err(OddAddress::OtherFamily { addr, local });
    }
    // An IPv4 address written in IPv6 (::ffff:a.b.c.d) is judged as the IPv4 address it is.
    let ip = match addr.ip() {
        IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(IpAddr::V6(v6), IpAddr::V4),
        v4 => v4,
    };
    if ip.is_unspecified() {
        return Err(OddAddress::Unspecified(addr));
    }
    if matches!(ip, IpAddr::V4(v4) if v4.is_broadcast()) {
        return Err(OddAddress::Broadcast(addr));
    }
    if ip.is_multicast() {
        return Err(OddAddress::Multicast(addr));
    }
    if addr.port() == 0 {
        return Err(OddAddress::NoPort(addr));
    }
    Ok(addr)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn judged(addr: &str, local: &str) -> Result<SocketAddr, OddAddress> {
        media_target(addr.parse().unwrap(), local.parse().unwrap())
    }

    /// The kind of refusal, as its message starts after the address.
    fn kind(addr: &str, local: &str) -> String {
        match judged(addr, local) {
            Ok(_) => "host".into(),
            Err(e) => e.to_string().replacen(addr, "", 1),
        }
    }

    #[test]
    fn hosts_pass_and_odd_addresses_are_named() {
        let (v4, v6) = ("127.0.0.1:5000", "[::1]:5000");
        for host in ["127.0.0.1:4000", "192.168.1.7:4000", "203.0.113.9:1"] {
            assert_eq!(judged(host, v4), Ok(host.parse().unwrap()));
        }
        for (addr, local, expected) in [
            ("[2001:db8::1]:4000", v6, "host"),
            ("0.0.0.0:4000", v4, " is the unspecified address, no host"),
            ("[::]:4000", v6, " is the unspecified address, no host"),
            (
                "255.255.255.255:4000",
                v4,
                " is the broadcast address, no single host",
            ),
            (
                "224.0.0.1:4000",
                v4,
                " is a multicast address, no single host",
            ),
            (
                "239.1.2.3:4000",
                v4,
                " is a multicast address, no single host",
            ),
            (
                "[ff02::1]:4000",
                v6,
                " is a multicast address, no single host",
            ),
            (
                "[::ffff:224.0.0.1]:4000",
                v6,
                " is a multicast address, no single host",
            ),
            ("10.0.0.1:0", v4, " has port 0"),
            (
                "[::1]:4000",
                v4,
                " is of another address family than our socket's 127.0.0.1:5000",
            ),
            (
                "127.0.0.1:4000",
                v6,
                " is of another address family than our socket's [::1]:5000",
            ),
        ] {
            assert_eq!(kind(addr, local), expected, "{addr} from {local}");
        }
    }
}
