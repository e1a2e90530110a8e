//! The RTP of one SIP call: a [`Session`] configured for what SDP negotiated
//! ([`session_config`]), on the sockets our SDP named, driven by the same socket thread as
//! every session. The call's rules are the session's for a negotiated call
//! ([`NegotiatedCall`]): the payload types SDP agreed, one remote stream into the same
//! per-peer receiver (jitter buffer, decoder, features) as every other call, our own stream
//! out, RFC 4733 DTMF, hold, a keepalive, and RTCP reports both ways.
//!
//! Where RTP and RTCP may come from is the session's [`Latch::Fixed`] rule: anyone can send
//! datagrams to our port, and plain RTP proves nothing about its sender, so before the peer's
//! first packet only those from the address its SDP named are taken, or from any port of the
//! IP its SIP messages come from ([`Negotiated::signalling_peer`]: a symmetric-RTP peer
//! behind a NAT whose SDP gives its private address sends from the NAT's address, the same as
//! its SIP, and whoever holds that IP could move the media with a re-INVITE anyway); under
//! SRTP any authenticated one. The first packet taken fixes the source for the rest of the
//! call (a re-INVITE naming a new address opens it again); everything else is dropped,
//! counted and said in a warning naming the source, rate-limited. A peer behind a NAT reached
//! through a proxy, whose SDP address neither sends nor is the NAT's, is not heard: that takes
//! a media relay (the PBX's, rtpengine).

use std::net::{SocketAddr, UdpSocket};
use std::time::Duration;

use super::sdp::{Negotiated, SdesKey};
use crate::net::NetError;
use crate::net::session::latch::{Latch, Named};
use crate::net::session::{CALL_KEEPALIVE, NegotiatedCall, Session, SessionConfig, SessionCore};
use crate::net::srtp::MasterKey;

/// A call's peer silent this long (no RTP, no RTCP: not even on hold) is forgotten.
const PEER_TIMEOUT: Duration = Duration::from_secs(600);

/// The addresses a call's description named.
fn named(negotiated: &Negotiated) -> Named {
    Named {
        rtp: negotiated.remote,
        rtcp: negotiated.rtcp,
        signalling: negotiated.signalling_peer,
    }
}

/// What the call's session adds to a session's rules.
fn call(negotiated: &Negotiated) -> NegotiatedCall {
    NegotiatedCall {
        audio_types: negotiated.audio_types.clone(),
        events: negotiated.events,
        held: !negotiated.direction.reversed().sends(),
        keepalive: Some(CALL_KEEPALIVE),
    }
}

/// The session of a call as `negotiated`, our SRTP key `ours` where SRTP was agreed, bound
/// at `local`.
pub fn session_config(
    negotiated: &Negotiated,
    ours: &SdesKey,
    local: SocketAddr,
) -> Result<SessionConfig, NetError> {
    let mut config = SessionConfig::new(local);
    if let Some(theirs) = &negotiated.srtp {
        config.key = Some(MasterKey::from_bytes(&ours.0)?);
        config.peer_key = Some(MasterKey::from_bytes(&theirs.key.0)?);
    }
    config.latch = Latch::Fixed(named(negotiated));
    config.codec = negotiated.codec;
    config.payloads = negotiated.payloads.clone();
    config.max_peers = 1;
    config.peer_timeout = PEER_TIMEOUT;
    config.call = Some(call(negotiated));
    Ok(config)
}

/// Starts the call's media on `socket` (the one whose address our SDP gave), and its RTCP on
/// `rtcp` (where the SDP gave one and RTCP is not multiplexed; on `socket` else).
pub fn start(
    socket: UdpSocket,
    rtcp: Option<UdpSocket>,
    negotiated: &Negotiated,
    ours: &SdesKey,
) -> Result<Session, NetError> {
    let local = socket
        .local_addr()
        .map_err(|e| NetError::io("local address", e))?;
    let rtcp = rtcp.filter(|_| !negotiated.rtcp_mux);
    Session::on_sockets(socket, rtcp, session_config(negotiated, ours, local)?)
}

/// A new offer or answer in the same call (a re-INVITE: hold, resume, another address or
/// codec) after `previous`.
pub fn renegotiate(core: &mut SessionCore, previous: &Negotiated, negotiated: &Negotiated) {
    let mut addresses = named(negotiated);
    // An old-style hold (c=0.0.0.0): nothing goes there, and the source stays as it was.
    if negotiated.remote.ip().is_unspecified() {
        addresses.rtp = previous.remote;
        addresses.rtcp = previous.rtcp;
    }
    core.renegotiate(
        addresses,
        call(negotiated),
        negotiated.codec,
        negotiated.payloads.clone(),
    );
}

#[cfg(test)]
mod tests;
