//! Where a Janus is: its API's URL, over HTTP(S) or its WebSocket transport (ws, wss).

use std::net::SocketAddr;

use super::JanusError;
use crate::net::host_port::HostPort;

/// How the API is reached.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Transport {
    /// Requests are POSTs, events come by long poll (`http://`, `https://`).
    Http,
    /// One WebSocket carries requests and events (`ws://`, `wss://`).
    WebSocket,
}

/// A Janus API URL, taken apart.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct JanusUrl {
    pub transport: Transport,
    pub tls: bool,
    pub host: String,
    pub port: u16,
}

const SCHEMES: [(&str, Transport, bool, u16); 4] = [
    ("http://", Transport::Http, false, 80),
    ("https://", Transport::Http, true, 443),
    ("ws://", Transport::WebSocket, false, 80),
    ("wss://", Transport::WebSocket, true, 443),
];

/// Whether an address names a Janus server (any of its transports).
pub fn is_janus_url(address: &str) -> bool {
    let a = address.trim().to_ascii_lowercase();
    SCHEMES.iter().any(|(scheme, ..)| a.starts_with(scheme))
}

impl JanusUrl {
    pub fn parse(url: &str) -> Result<Self, JanusError> {
        let bad = |reason: &str| JanusError::Http {
            url: url.to_string(),
            reason: reason.to_string(),
        };
        let trimmed = url.trim();
        let lower = trimmed.to_ascii_lowercase();
        let (scheme, transport, tls, default_port) = SCHEMES
            .iter()
            .find(|(scheme, ..)| lower.starts_with(scheme))
            .ok_or_else(|| {
                bad("expected http(s)://HOST:PORT/janus or ws(s)://HOST:PORT (Janus's API)")
            })?;
        let authority = trimmed[scheme.len()..]
            .split(['/', '?'])
            .next()
            .unwrap_or_default();
        let authority = HostPort::parse(authority).map_err(|e| bad(&e.to_string()))?;
        let port = authority.port_or(*default_port);
        Ok(Self {
            transport: *transport,
            tls: *tls,
            host: authority.host,
            port,
        })
    }
}

/// Where the Janus server of an API URL is.
pub fn server_addr(url: &str) -> Result<SocketAddr, JanusError> {
    let parsed = JanusUrl::parse(url)?;
    HostPort {
        host: parsed.host,
        port: Some(parsed.port),
    }
    .resolve(parsed.port)
    .map_err(|e| JanusError::Http {
        url: url.to_string(),
        reason: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn host_port(url: &str) -> (String, u16) {
        let u = JanusUrl::parse(url).unwrap();
        (u.host, u.port)
    }

    #[test]
    fn janus_urls_name_their_host_and_transport() {
        assert_eq!(
            host_port("http://127.0.0.1:8088/janus"),
            ("127.0.0.1".into(), 8088)
        );
        assert_eq!(
            host_port("http://janus.example/janus"),
            ("janus.example".into(), 80)
        );
        assert_eq!(host_port("https://janus.example/janus").1, 443);
        assert_eq!(host_port("wss://janus.example").1, 443);
        assert_eq!(host_port("ws://[::1]:8188"), ("::1".into(), 8188));
        let u = JanusUrl::parse("WSS://x:8989/").unwrap();
        assert_eq!((u.transport, u.tls), (Transport::WebSocket, true));
        assert!(JanusUrl::parse("ftp://x/janus").is_err());
        assert!(JanusUrl::parse("http://:80/janus").is_err());
        assert!(JanusUrl::parse("http://x:port/janus").is_err());
    }

    #[test]
    fn the_server_address_comes_from_the_url() {
        assert_eq!(
            server_addr("http://127.0.0.1:8088/janus").unwrap(),
            SocketAddr::from(([127, 0, 0, 1], 8088))
        );
        assert_eq!(
            server_addr("https://127.0.0.1/janus").unwrap(),
            SocketAddr::from(([127, 0, 0, 1], 443))
        );
        assert_eq!(
            server_addr("ws://[::1]:8188").unwrap(),
            "[::1]:8188".parse().unwrap()
        );
        let e = server_addr("127.0.0.1:8089").unwrap_err();
        assert!(e.to_string().contains("expected http(s)://"), "{e}");
    }

    #[test]
    fn janus_urls_are_told_from_peer_addresses() {
        assert!(is_janus_url("http://127.0.0.1:8088/janus"));
        assert!(is_janus_url(" https://janus.example/janus"));
        assert!(is_janus_url("wss://janus.example:8989"));
        assert!(!is_janus_url("127.0.0.1:5004"));
        assert!(!is_janus_url("relay.example:5004"));
    }
}
