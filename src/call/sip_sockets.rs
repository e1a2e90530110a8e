//! A SIP call's media sockets: RTP and RTCP bound side by side, and with a STUN server the
//! addresses it sees them at, which the SDP then gives. Asking STUN blocks (its DNS, then up to
//! [`stun::ASK_WAIT`]), so the app does it on a look-up's thread.

use std::net::{SocketAddr, UdpSocket};

use crate::net::sip::agent::SipError;
use crate::net::stun;

/// A call's RTP and RTCP sockets, and the addresses its SDP gives for them.
#[derive(Debug)]
pub struct MediaSockets {
    pub(super) rtp: UdpSocket,
    pub(super) rtcp: UdpSocket,
    pub(super) addr: SocketAddr,
    pub(super) rtcp_addr: SocketAddr,
}

/// RTP on a free port of `bind`'s address (RTCP on the port above where it is free, another
/// else), and with a `stun` server (HOST:PORT) the addresses it sees them at: blocks while
/// STUN is asked (its DNS, then up to [`stun::ASK_WAIT`]).
pub fn bind_media(bind: SocketAddr, stun: Option<&str>) -> Result<MediaSockets, SipError> {
    let rtp_bind = SocketAddr::new(bind.ip(), 0);
    let cannot = |why: String| SipError::Bind {
        addr: rtp_bind,
        why,
    };
    let rtp = UdpSocket::bind(rtp_bind).map_err(|e| cannot(e.to_string()))?;
    let local = rtp.local_addr().map_err(|e| cannot(e.to_string()))?;
    let rtcp = local
        .port()
        .checked_add(1)
        .and_then(|port| UdpSocket::bind(SocketAddr::new(local.ip(), port)).ok())
        .map_or_else(|| UdpSocket::bind(rtp_bind), Ok)
        .map_err(|e| cannot(e.to_string()))?;
    let local_rtcp = rtcp.local_addr().map_err(|e| cannot(e.to_string()))?;
    let (addr, rtcp_addr) = match stun {
        Some(server) => media_addresses([(&rtp, local), (&rtcp, local_rtcp)], server),
        None => (local, local_rtcp),
    };
    Ok(MediaSockets {
        rtp,
        rtcp,
        addr,
        rtcp_addr,
    })
}

/// Where peers are to send our media (RTP, RTCP): the addresses `server` (STUN) sees our
/// sockets at, behind a NAT, both asked at once; a socket's own address where it cannot tell.
fn media_addresses(
    [(rtp, local_rtp), (rtcp, local_rtcp)]: [(&UdpSocket, SocketAddr); 2],
    server: &str,
) -> (SocketAddr, SocketAddr) {
    let server = match stun::resolve_server(server, local_rtp) {
        Ok(server) => server,
        Err(e) => {
            tracing::warn!("{e}: the SDP gives the local media address");
            return (local_rtp, local_rtcp);
        }
    };
    let asked = stun::reflexive_addresses(&[rtp, rtcp], server, stun::ASK_WAIT);
    let outside =
        |local: SocketAddr, asked: Option<&Result<SocketAddr, stun::StunError>>| match asked {
            Some(Ok(public)) => {
                tracing::info!("STUN server {server}: our media address outside is {public}");
                *public
            }
            Some(Err(e)) => {
                tracing::warn!("{e}: the SDP gives the local media address");
                local
            }
            None => local,
        };
    (
        outside(local_rtp, asked.first()),
        outside(local_rtcp, asked.get(1)),
    )
}
