//! Direct callers of the listening session, both ways: each caller heard is sent the
//! microphone back, from the listening socket to the address its packets come from (so a
//! caller behind a NAT hears us too), in the codec it sends; Leave hangs up on them and keeps
//! them out for a while ([`crate::net::session::Blocked`]), across the sessions that follow, until the user calls one.
//!
//! Every caller heard is answered, up to [`MAX_ANSWERED`]: the listening app already plays
//! them all and shows them all as in the call, so each of them hears the one they called.

use std::net::SocketAddr;

use super::{DEMO_NAME, Worker};
use crate::codec::any::{Codec, EncoderSettings, FrameEncoder};
use crate::codec::opus::codec::Bandwidth;
use crate::net::session::MAX_ANSWERED;
use crate::net::transport::PeerInfo;

/// The band an answer in Opus codes: the settings' first choice (the engine is not told the
/// caller's; every band is decoded at the other end).
const ANSWER_BAND: Bandwidth = Bandwidth::Fullband;

/// The callers of a listening session to send back to: heard, not gone, not the demo; the
/// codec of the first one.
pub(super) fn callers(infos: &[PeerInfo]) -> (Vec<SocketAddr>, Option<Codec>) {
    let heard: Vec<&PeerInfo> = infos
        .iter()
        .filter(|i| i.name.as_deref() != Some(DEMO_NAME) && !i.ended && !i.said_bye)
        .collect();
    let mut to: Vec<SocketAddr> = Vec::with_capacity(MAX_ANSWERED);
    for info in &heard {
        if to.len() < MAX_ANSWERED && !to.contains(&info.addr) {
            to.push(info.addr);
        }
    }
    (to, heard.first().and_then(|i| i.receiver.codec))
}

impl Worker {
    /// Sends the microphone to the listening session's callers (none while a call is placed:
    /// that call's session has its destinations).
    pub(super) fn answer_callers(&mut self) {
        if self.in_call {
            self.answered.clear();
            return;
        }
        let Some(session) = self.link.session() else {
            return;
        };
        // Its own peers: the link may have changed since the caller's look (a call ended).
        let (to, codec) = callers(&session.peers());
        if to == self.answered {
            return;
        }
        let sent = session.answer(&to, codec.unwrap_or_else(|| session.codec()));
        // A fresh encoder as answering starts: the one kept is the idle default's or the last
        // call's, at their band.
        let starts = self.answered.is_empty() && !to.is_empty();
        if starts || (!to.is_empty() && self.encoder.codec() != sent) {
            match FrameEncoder::new(sent, &EncoderSettings::wideband(ANSWER_BAND)) {
                Ok(encoder) => self.encoder = encoder,
                Err(e) => {
                    tracing::warn!("cannot answer in {sent}: {e}");
                    session.answer(&[], sent);
                    self.answered.clear();
                    return;
                }
            }
        }
        if to.is_empty() {
            tracing::info!("no caller to answer: listening only");
        } else {
            tracing::info!("answering {to:?} in {sent}");
        }
        self.answered = to;
    }

    /// Leave with callers of the listening session: each is told BYE and kept out for a
    /// while; the session goes on listening for others.
    pub(super) fn hang_up_on_callers(&mut self) {
        if let Some(session) = self.link.session() {
            let mut callers: Vec<SocketAddr> = session
                .peers()
                .iter()
                .filter(|i| i.name.as_deref() != Some(DEMO_NAME))
                .map(|i| i.addr)
                .collect();
            callers.sort_unstable();
            callers.dedup();
            for addr in callers {
                tracing::info!("hung up on {addr}: kept out for a while");
                session.hang_up_on(addr);
            }
            session.answer(&[], session.codec());
        }
        self.answered.clear();
    }

    /// The callers kept out by the listening session that a call replaces, but `to`, the
    /// address the user calls.
    pub(super) fn keep_blocks_but(&mut self, to: Option<SocketAddr>) {
        if self.in_call {
            return;
        }
        if let Some(session) = self.link.session() {
            let mut blocked = session.blocked();
            if let Some(to) = to {
                blocked.lift(to);
            }
            self.blocked = blocked;
        }
    }

    /// The next listening session keeps out whom the last one did.
    pub(super) fn hand_on_blocks(&mut self) {
        let blocked = std::mem::take(&mut self.blocked);
        if let Some(session) = self.link.session()
            && !blocked.is_empty()
        {
            session.keep_blocked(blocked);
        }
    }
}
