//! `HOST[:PORT]` as users and servers write it, read one way everywhere: a name, an IPv4
//! address or an IPv6 address (in brackets when a port follows), and an optional port that
//! each protocol defaults (0, "any free port", where we listen: the wire's addresses are
//! checked apart, by `net::addr`). Looking a name up is a separate, explicit step.

use std::fmt;
use std::net::{IpAddr, Ipv6Addr, SocketAddr, ToSocketAddrs};

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AddressError {
    #[error("{text:?}: {why} (expected HOST[:PORT], an IPv6 address in brackets: [::1]:5060)")]
    Malformed { text: String, why: &'static str },
    #[error("cannot look up {host}: {why}")]
    Unresolved { host: String, why: String },
}

/// A host and, where one was written, its port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HostPort {
    /// The name or address, without brackets.
    pub host: String,
    pub port: Option<u16>,
}

impl HostPort {
    /// Reads `HOST`, `HOST:PORT`, `[IPV6]`, `[IPV6]:PORT` or a bare IPv6 address (which takes
    /// no port: `::1:5060` is the address `::1:5060`).
    pub fn parse(text: &str) -> Result<Self, AddressError> {
        let trimmed = text.trim();
        let bad = |why| AddressError::Malformed {
            text: text.to_owned(),
            why,
        };
        if trimmed.is_empty() {
            return Err(bad("no host"));
        }
        if let Some(rest) = trimmed.strip_prefix('[') {
            let (inside, after) = rest.split_once(']').ok_or(bad("no closing bracket"))?;
            inside
                .parse::<Ipv6Addr>()
                .map_err(|_| bad("not an IPv6 address in the brackets"))?;
            let port = match after {
                "" => None,
                _ => Some(
                    parse_port(after.strip_prefix(':').ok_or(bad("junk after ]"))?)
                        .ok_or(bad("the port is not a number from 0 to 65535"))?,
                ),
            };
            return Ok(Self {
                host: inside.to_owned(),
                port,
            });
        }
        if trimmed.parse::<Ipv6Addr>().is_ok() {
            return Ok(Self {
                host: trimmed.to_owned(),
                port: None,
            });
        }
        let (host, port) = match trimmed.split_once(':') {
            Some((_, after)) if after.contains(':') => {
                return Err(bad("more than one ':' (an IPv6 address needs brackets)"));
            }
            Some((host, port)) => (
                host,
                Some(parse_port(port).ok_or(bad("the port is not a number from 0 to 65535"))?),
            ),
            None => (trimmed, None),
        };
        if host.is_empty() {
            return Err(bad("no host"));
        }
        if host
            .chars()
            .any(|c| !(c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_')))
        {
            return Err(bad(
                "a host name has letters, digits, '.', '-' and '_' only",
            ));
        }
        Ok(Self {
            host: host.to_owned(),
            port,
        })
    }

    /// The port written, or the protocol's `default`.
    pub fn port_or(&self, default: u16) -> u16 {
        self.port.unwrap_or(default)
    }

    /// The host as an IP address, where it is one (no lookup).
    pub fn ip(&self) -> Option<IpAddr> {
        self.host.parse().ok()
    }

    /// Every address the host has, with the port written or `default` (a name is looked up,
    /// which may take as long as the system's resolver does).
    pub fn resolve_all(&self, default: u16) -> Result<Vec<SocketAddr>, AddressError> {
        let port = self.port_or(default);
        if let Some(ip) = self.ip() {
            return Ok(vec![SocketAddr::new(ip, port)]);
        }
        let unresolved = |why: String| AddressError::Unresolved {
            host: self.host.clone(),
            why,
        };
        let addrs: Vec<SocketAddr> = (self.host.as_str(), port)
            .to_socket_addrs()
            .map_err(|e| unresolved(e.to_string()))?
            .collect();
        if addrs.is_empty() {
            return Err(unresolved("no address".into()));
        }
        Ok(addrs)
    }

    /// The first address of the host (see [`HostPort::resolve_all`]).
    pub fn resolve(&self, default: u16) -> Result<SocketAddr, AddressError> {
        Ok(self.resolve_all(default)?[0])
    }

    /// The first address of the host in the family of `like` (the socket it is reached from).
    pub fn resolve_like(&self, default: u16, like: SocketAddr) -> Result<SocketAddr, AddressError> {
        self.resolve_all(default)?
            .into_iter()
            .find(|a| a.is_ipv4() == like.is_ipv4())
            .ok_or_else(|| AddressError::Unresolved {
                host: self.host.clone(),
                why: format!(
                    "no {} address",
                    if like.is_ipv4() { "IPv4" } else { "IPv6" }
                ),
            })
    }
}

/// The address of `text`, which must name its port (a peer's, a relay's, a port to listen
/// on: no protocol default applies).
pub fn resolve_with_port(text: &str) -> Result<SocketAddr, AddressError> {
    let target = HostPort::parse(text)?;
    match target.port {
        Some(port) => target.resolve(port),
        None => Err(AddressError::Malformed {
            text: text.to_owned(),
            why: "no port",
        }),
    }
}

/// As written to be read back: brackets around an IPv6 address.
impl fmt::Display for HostPort {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.host.contains(':'), self.port) {
            (true, Some(port)) => write!(f, "[{}]:{port}", self.host),
            (true, None) => write!(f, "[{}]", self.host),
            (false, Some(port)) => write!(f, "{}:{port}", self.host),
            (false, None) => f.write_str(&self.host),
        }
    }
}

fn parse_port(text: &str) -> Option<u16> {
    if text.is_empty() || !text.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    text.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn hp(text: &str) -> (String, Option<u16>) {
        let parsed = HostPort::parse(text).unwrap();
        (parsed.host, parsed.port)
    }

    #[test]
    fn names_addresses_and_ports_are_read() {
        assert_eq!(hp("example.org"), ("example.org".into(), None));
        assert_eq!(hp(" example.org:5061 "), ("example.org".into(), Some(5061)));
        assert_eq!(hp("127.0.0.1:5004"), ("127.0.0.1".into(), Some(5004)));
        assert_eq!(hp("[::1]:5060"), ("::1".into(), Some(5060)));
        assert_eq!(hp("[fe80::1]"), ("fe80::1".into(), None));
        assert_eq!(hp("::1"), ("::1".into(), None));
        assert_eq!(hp("2001:db8::5:5060"), ("2001:db8::5:5060".into(), None));
    }

    #[test]
    fn malformed_text_is_a_clear_error() {
        for (text, why) in [
            ("", "no host"),
            (":5060", "no host"),
            ("host:", "port"),
            ("host:65536", "port"),
            ("host:+80", "port"),
            ("host:5060x", "port"),
            ("[::1", "bracket"),
            ("[::1]5060", "junk"),
            ("[nothost]:1", "IPv6"),
            ("a:b:c", "brackets"),
            ("bad host:1", "letters"),
        ] {
            let e = HostPort::parse(text).unwrap_err().to_string();
            assert!(e.contains(why), "{text:?}: {e}");
            assert!(e.contains("HOST[:PORT]"), "{e}");
        }
    }

    #[test]
    fn the_default_port_fills_in_and_addresses_need_no_lookup() {
        let a = HostPort::parse("127.0.0.1").unwrap();
        assert_eq!(a.resolve(5060).unwrap(), "127.0.0.1:5060".parse().unwrap());
        let b = HostPort::parse("[::1]:7000").unwrap();
        assert_eq!(b.resolve(5060).unwrap(), "[::1]:7000".parse().unwrap());
        assert!(
            resolve_with_port("127.0.0.1")
                .unwrap_err()
                .to_string()
                .contains("no port")
        );
        assert_eq!(
            resolve_with_port("localhost:5004").map(|a| a.port()),
            Ok(5004)
        );
        let like: SocketAddr = "[::1]:1".parse().unwrap();
        assert!(
            a.resolve_like(5060, like)
                .unwrap_err()
                .to_string()
                .contains("IPv6")
        );
    }

    proptest! {
        #[test]
        fn any_text_is_read_or_refused_and_what_is_read_reads_back(text in "\\PC{0,30}") {
            if let Ok(parsed) = HostPort::parse(&text) {
                prop_assert!(!parsed.host.is_empty());
                prop_assert_eq!(HostPort::parse(&parsed.to_string()).unwrap(), parsed);
            }
        }
    }
}
