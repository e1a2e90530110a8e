//! How SIP reaches a server: UDP, TCP or TLS (RFC 3261 18, RFC 5630's `sips:`), read from a
//! `sip:`/`sips:` URI and its `;transport=` parameter; the TLS connector that checks the
//! server's certificate against the system's roots and a `--ca` file; and, where ezk's TLS
//! connection fails (it says only "failed to connect"), one handshake of our own to tell the
//! user why: an untrusted or expired certificate, another name, or no TLS on that port.

use std::net::SocketAddr;
use std::time::Duration;

use ezk_sip_core::Endpoint;
use ezk_sip_core::transport::TpHandle;
use ezk_sip_types::uri::SipUri;
use tokio::net::TcpStream;

use super::error::SipError;

/// SIP over TLS's port where an address gives none (RFC 3261 19.1.2).
pub const SIPS_PORT: u16 = 5061;
/// How long a TCP connection and its TLS handshake may take.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SipTransport {
    #[default]
    Udp,
    Tcp,
    Tls,
}

impl SipTransport {
    /// The transport a `sip:`/`sips:` URI asks for: TLS for `sips:` or `;transport=tls`, TCP
    /// for `;transport=tcp`, UDP else.
    pub fn of_uri(uri: &str) -> Result<Self, SipError> {
        let uri = uri.trim();
        let sips = uri
            .get(..5)
            .is_some_and(|s| s.eq_ignore_ascii_case("sips:"));
        let param = uri
            .split(';')
            .skip(1)
            .filter_map(|p| p.split_once('='))
            .find(|(name, _)| name.trim().eq_ignore_ascii_case("transport"))
            .map(|(_, value)| value.split('?').next().unwrap_or(value).trim());
        match param.map(str::to_ascii_lowercase).as_deref() {
            None if sips => Ok(Self::Tls),
            None | Some("udp") if !sips => Ok(Self::Udp),
            Some("tls") => Ok(Self::Tls),
            Some("tcp") if sips => Ok(Self::Tls),
            Some("tcp") => Ok(Self::Tcp),
            _ => Err(SipError::BadUri(format!(
                "{uri} (transport: udp, tcp or tls; sips: is TLS only)"
            ))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Udp => "UDP",
            Self::Tcp => "TCP",
            Self::Tls => "TLS",
        }
    }

    /// The `;transport=` parameter ezk needs to pick this transport (none for UDP).
    pub fn param(self) -> &'static str {
        match self {
            Self::Udp => "",
            Self::Tcp => ";transport=tcp",
            Self::Tls => ";transport=tls",
        }
    }

    pub fn default_port(self) -> u16 {
        match self {
            Self::Tls => SIPS_PORT,
            Self::Udp | Self::Tcp => super::address::SIP_PORT,
        }
    }

    /// Whether the signalling (and the SDES keys in it) is encrypted.
    pub fn secure(self) -> bool {
        self == Self::Tls
    }
}

/// Whether a call's media is encrypted (SRTP keyed by SDES in the SDP).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SrtpPolicy {
    /// Offered where the signalling is TLS (keys in the clear are no secret); taken whenever
    /// offered.
    #[default]
    Optional,
    /// Offered always; an answer or an offer without it is refused.
    Required,
    /// Plain RTP offered even over TLS; an offer of SRTP is still taken.
    Off,
}

impl SrtpPolicy {
    /// Whether our offer is SRTP, over `transport`.
    pub fn offers(self, transport: SipTransport) -> bool {
        match self {
            Self::Required => true,
            Self::Optional => transport.secure(),
            Self::Off => false,
        }
    }
}

impl std::str::FromStr for SrtpPolicy {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "optional" => Ok(Self::Optional),
            "required" => Ok(Self::Required),
            "off" => Ok(Self::Off),
            _ => Err(format!("{s:?}: optional, required or off")),
        }
    }
}

/// `HOST[:PORT]` with the transport's port where none is given.
pub fn with_port(host: &str, transport: SipTransport) -> String {
    let has_port = match host.rsplit_once(':') {
        // `[v6]:port`, `v4:port`, `name:port`; a bare IPv6 address has colons but no port.
        Some((before, port)) => {
            port.parse::<u16>().is_ok() && (before.ends_with(']') || !before.contains(':'))
        }
        None => false,
    };
    if has_port {
        host.to_owned()
    } else {
        format!("{host}:{}", transport.default_port())
    }
}

/// A TLS connector trusting the system's roots and, with `ca` (PEM), that authority too.
pub fn connector(ca: Option<&[u8]>) -> Result<native_tls::TlsConnector, SipError> {
    let mut builder = native_tls::TlsConnector::builder();
    if let Some(pem) = ca {
        let certificate = native_tls::Certificate::from_pem(pem)
            .map_err(|e| SipError::Tls(format!("--ca is no PEM certificate: {e}")))?;
        builder.add_root_certificate(certificate);
    }
    builder
        .build()
        .map_err(|e| SipError::Tls(format!("cannot set up TLS: {e}")))
}

/// Why a TLS connection to `server` (named `name` in its certificate) fails: one handshake of
/// our own, read as the user needs it.
pub async fn why_tls_fails(
    connector: &native_tls::TlsConnector,
    server: SocketAddr,
    name: &str,
) -> String {
    let attempt = async {
        let stream = TcpStream::connect(server)
            .await
            .map_err(|e| format!("cannot connect: {e}"))?;
        tokio_native_tls::TlsConnector::from(connector.clone())
            .connect(name, stream)
            .await
            .map(drop)
            .map_err(|e| explain_handshake(&e.to_string(), name))
    };
    match tokio::time::timeout(CONNECT_TIMEOUT, attempt).await {
        Err(_) => format!(
            "no TLS handshake within {} s (is it a TLS port?)",
            CONNECT_TIMEOUT.as_secs()
        ),
        Ok(Err(why)) => why,
        Ok(Ok(())) => "the TLS connection was refused after the handshake".to_owned(),
    }
}

/// Opens the TCP or TLS connection to `server`; where TLS fails, says why (the certificate, or
/// no TLS there).
pub async fn connect(
    endpoint: &Endpoint,
    server: &SipUri,
    tls: Option<&native_tls::TlsConnector>,
    kind: SipTransport,
) -> Result<(TpHandle, SocketAddr), SipError> {
    let name = server.host_port.host.to_string();
    let port = server.host_port.port.unwrap_or(kind.default_port());
    let shown = format!("{name}:{port}");
    let connected = tokio::time::timeout(CONNECT_TIMEOUT, endpoint.select_transport(server)).await;
    match connected {
        Ok(Ok(connection)) => Ok(connection),
        Ok(Err(e)) => {
            let why = match (tls, crate::net::host_port::resolve_with_port(&shown)) {
                (Some(tls), Ok(address)) => why_tls_fails(tls, address, &name).await,
                _ => e.to_string(),
            };
            Err(SipError::TlsRefused {
                server: format!("{} to {shown}", kind.name()),
                why,
            })
        }
        Err(_) => Err(SipError::TlsRefused {
            server: format!("{} to {shown}", kind.name()),
            why: format!("no connection within {} s", CONNECT_TIMEOUT.as_secs()),
        }),
    }
}

/// OpenSSL's words for a failed handshake, as the user needs them.
fn explain_handshake(error: &str, name: &str) -> String {
    let lower = error.to_ascii_lowercase();
    let said = |needles: &[&str]| needles.iter().any(|n| lower.contains(n));
    if said(&["certificate has expired"]) {
        "its certificate has expired".to_owned()
    } else if said(&["not yet valid"]) {
        "its certificate is not valid yet".to_owned()
    } else if said(&["hostname mismatch", "ip address mismatch"]) {
        format!("its certificate is not for {name}")
    } else if said(&[
        "unable to get local issuer",
        "self-signed",
        "self signed",
        "unable to verify",
        "certificate verify failed",
    ]) {
        "its certificate is not signed by an authority we trust (give --ca FILE for a \
         private one)"
            .to_owned()
    } else if said(&[
        "wrong version number",
        "packet length too long",
        "unexpected eof",
        "record layer failure",
        "http request",
        "unknown protocol",
    ]) {
        "it does not speak TLS (a plain TCP or UDP service on that port?)".to_owned()
    } else {
        format!("the TLS handshake failed: {error}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_transport_of_a_uri() {
        let of = |u| SipTransport::of_uri(u).unwrap();
        assert_eq!(of("sip:bob@pbx.example"), SipTransport::Udp);
        assert_eq!(of("sips:bob@pbx.example"), SipTransport::Tls);
        assert_eq!(of("sip:bob@h:5061;transport=TLS"), SipTransport::Tls);
        assert_eq!(of("sip:bob@h;transport=tcp"), SipTransport::Tcp);
        assert_eq!(of("sips:bob@h;transport=tcp"), SipTransport::Tls);
        assert_eq!(of("bob@h;user=phone;transport=udp"), SipTransport::Udp);
        assert!(SipTransport::of_uri("sips:bob@h;transport=udp").is_err());
        assert!(SipTransport::of_uri("sip:bob@h;transport=sctp").is_err());
    }

    #[test]
    fn the_default_port_goes_where_none_is_given() {
        assert_eq!(with_port("h", SipTransport::Tls), "h:5061");
        assert_eq!(with_port("h:7000", SipTransport::Tls), "h:7000");
        assert_eq!(with_port("[::1]:7000", SipTransport::Tls), "[::1]:7000");
        assert_eq!(with_port("10.0.0.1", SipTransport::Udp), "10.0.0.1:5060");
    }

    #[test]
    fn handshake_failures_are_named() {
        let named = |e| explain_handshake(e, "pbx.example");
        assert!(named("error:0A000086:SSL routines:tls_post_process_server_certificate:certificate verify failed:../ssl/statem/statem_clnt.c:1889: (certificate has expired)").contains("expired"));
        assert!(named("... (Hostname mismatch)").contains("not for pbx.example"));
        assert!(named("... (unable to get local issuer certificate)").contains("--ca"));
        assert!(
            named("error:0A00010B:SSL routines:ssl3_get_record:wrong version number")
                .contains("does not speak TLS")
        );
    }
}
