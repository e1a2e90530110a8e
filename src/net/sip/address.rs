//! Where a SIP address points: the host of a `sip:` URI, its IP address, and the local address
//! our SIP and RTP sockets take to reach it (what our Contact and SDP then name).

use std::net::{IpAddr, SocketAddr};

use super::error::SipError;
use crate::net::host_port::HostPort;
use crate::net::janus::candidates::local_ip_towards;

/// SIP's port where an address gives none (RFC 3261, UDP and TCP).
pub const SIP_PORT: u16 = 5060;

/// The `HOST[:PORT]` of `sip:USER@HOST[:PORT];params`.
pub fn host_port(uri: &str) -> &str {
    let trimmed = uri.trim();
    let bare = trimmed
        .strip_prefix("sips:")
        .or_else(|| trimmed.strip_prefix("sip:"))
        .unwrap_or(trimmed);
    let after_user = bare.rsplit_once('@').map_or(bare, |(_, h)| h);
    after_user.split([';', '?']).next().unwrap_or(after_user)
}

/// The IP address of `HOST[:PORT]` (SIP's default port when none is given).
pub fn resolve_host(host: &str) -> Result<IpAddr, SipError> {
    let unreachable = |why: String| SipError::Unresolved {
        host: host.to_owned(),
        why,
    };
    HostPort::parse(host)
        .and_then(|h| h.resolve(SIP_PORT))
        .map(|a| a.ip())
        .map_err(|e| unreachable(e.to_string()))
}

/// A free port on the local address that routes to `address` (a registrar's `HOST[:PORT]`, or
/// the `sip:` URI called).
pub fn bind_towards(address: &str) -> Result<SocketAddr, SipError> {
    let host = host_port(address);
    let ip = resolve_host(host)?;
    let local = local_ip_towards(ip).map_err(|e| SipError::Unresolved {
        host: host.to_owned(),
        why: e.to_string(),
    })?;
    Ok(SocketAddr::new(local, 0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_host_of_a_sip_address() {
        assert_eq!(host_port("sip:bob@127.0.0.1:5070"), "127.0.0.1:5070");
        assert_eq!(host_port("bob@pbx.example;transport=udp"), "pbx.example");
        assert_eq!(host_port("sip:127.0.0.1"), "127.0.0.1");
        assert_eq!(
            host_port("sips:bob@pbx.example:5061;transport=tls"),
            "pbx.example:5061"
        );
        assert!(resolve_host("127.0.0.1").is_ok());
        assert!(resolve_host("127.0.0.1:5070").is_ok());
        assert_eq!(
            bind_towards("sip:x@127.0.0.1:5070").map(|a| a.ip()),
            Ok(IpAddr::from([127, 0, 0, 1]))
        );
        assert!(matches!(
            resolve_host("no such host.invalid"),
            Err(SipError::Unresolved { .. })
        ));
    }
}
