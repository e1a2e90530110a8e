//! Where the app listens for direct calls when `--listen` does not say: a port kept in the
//! settings (5004 at first; the next free one while it is taken) on all interfaces, so that
//! others can call back at the same address after every call and restart.

use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};

use crate::net::host_port::HostPort;

/// RTP's customary port (RFC 3551): the first choice of a fresh install.
pub const DEFAULT_PORT: u16 = 5004;
/// How many ports above the preferred one are tried while it is taken.
const PORTS_TRIED: u16 = 100;

/// The first port from `preferred` up that is free on all interfaces.
pub fn free_port_from(preferred: u16) -> std::io::Result<u16> {
    let mut last = None;
    for port in (preferred..=u16::MAX).take(usize::from(PORTS_TRIED)) {
        match UdpSocket::bind((Ipv4Addr::UNSPECIFIED, port)) {
            Ok(_) => return Ok(port),
            Err(e) => last = Some(e),
        }
    }
    Err(last.unwrap_or_else(|| std::io::Error::other("no port to try")))
}

/// The addresses others can dial to reach a session bound at `local`: for all interfaces,
/// the one this machine sends from towards the internet (where there is a route) and loopback.
pub fn dialable(local: SocketAddr) -> Vec<SocketAddr> {
    if !local.ip().is_unspecified() {
        return vec![local];
    }
    let mut addrs = Vec::new();
    if let Some(ip) = outward_ip() {
        addrs.push(SocketAddr::new(ip, local.port()));
    }
    addrs.push(SocketAddr::new(Ipv4Addr::LOCALHOST.into(), local.port()));
    addrs
}

/// What a direct call to `host` written without a port is told: the address as it would
/// work, at the port lipcall listens on by default.
pub fn give_the_port(host: &HostPort) -> String {
    let with_port = HostPort {
        host: host.host.clone(),
        port: Some(DEFAULT_PORT),
    };
    format!("give the port: {with_port}")
}

/// Connecting a UDP socket sends nothing: it only asks the routing table for the source
/// address towards a documentation address (RFC 5737).
fn outward_ip() -> Option<IpAddr> {
    let socket = UdpSocket::bind((Ipv4Addr::UNSPECIFIED, 0)).ok()?;
    socket.connect((Ipv4Addr::new(192, 0, 2, 1), 9)).ok()?;
    let ip = socket.local_addr().ok()?.ip();
    (!ip.is_unspecified() && !ip.is_loopback()).then_some(ip)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_address_without_a_port_is_shown_with_one() {
        let v4 = HostPort::parse("127.0.0.1").unwrap();
        assert_eq!(give_the_port(&v4), "give the port: 127.0.0.1:5004");
        let v6 = HostPort::parse("::1").unwrap();
        assert_eq!(give_the_port(&v6), "give the port: [::1]:5004");
    }

    #[test]
    fn a_taken_port_moves_to_a_free_one_above_it() {
        let held = UdpSocket::bind((Ipv4Addr::UNSPECIFIED, 0)).unwrap();
        let taken = held.local_addr().unwrap().port();
        let port = free_port_from(taken).unwrap();
        assert!(
            port > taken && port - taken < PORTS_TRIED,
            "{taken} -> {port}"
        );
    }

    #[test]
    fn all_interfaces_are_dialled_at_loopback_too_and_a_bound_address_as_is() {
        let any = SocketAddr::from(([0, 0, 0, 0], 5004));
        let shown = dialable(any);
        assert!(
            shown.contains(&"127.0.0.1:5004".parse().unwrap()),
            "{shown:?}"
        );
        assert!(
            shown
                .iter()
                .all(|a| a.port() == 5004 && !a.ip().is_unspecified())
        );
        let bound = SocketAddr::from(([127, 0, 0, 1], 7000));
        assert_eq!(dialable(bound), vec![bound]);
    }
}
