//! Direct callers of the listening session, both ways: each caller the user answered
//! ([`Consent`]) is sent the microphone back, from the listening socket to the address its
//! packets come from (so a caller behind a NAT hears us too), in the codec it sends; Decline
//! and Leave hang up on them and keep them out for a while ([`crate::net::session::Blocked`]),
//! across the sessions that follow, until the user calls one.

use std::net::SocketAddr;

use super::consent::Consent;
use super::{CallPhase, DEMO_NAME, Worker, lock};
use crate::codec::any::{Codec, EncoderSettings, FrameEncoder};
use crate::codec::opus::codec::Bandwidth;
use crate::net::session::MAX_ANSWERED;
use crate::net::transport::PeerInfo;

/// The band an answer in Opus codes: the settings' first choice (the engine is not told the
/// caller's; every band is decoded at the other end).
const ANSWER_BAND: Bandwidth = Bandwidth::Fullband;

/// The callers of a listening session to send back to: heard, not gone, not the demo, and
/// answered by the user; the codec of the first one.
pub(super) fn callers(infos: &[PeerInfo], consent: &Consent) -> (Vec<SocketAddr>, Option<Codec>) {
    let answered: Vec<&PeerInfo> = infos
        .iter()
        .filter(|i| i.name.as_deref() != Some(DEMO_NAME) && !i.ended && !i.said_bye)
        .filter(|i| consent.is_answered(i.addr))
        .collect();
    let mut to: Vec<SocketAddr> = Vec::with_capacity(MAX_ANSWERED);
    for info in &answered {
        if to.len() < MAX_ANSWERED && !to.contains(&info.addr) {
            to.push(info.addr);
        }
    }
    (to, answered.first().and_then(|i| i.receiver.codec))
}

impl Worker {
    /// Sends the microphone to the listening session's callers (none while a call is placed:
    /// that call's session has its destinations).
    pub(super) fn answer_callers(&mut self) {
        if self.in_call {
            self.answered.clear();
            self.consent.clear();
            return;
        }
        let Some(session) = self.link.session() else {
            return;
        };
        // Its own peers: the link may have changed since the caller's look (a call ended).
        let (to, codec) = callers(&session.peers(), &self.consent);
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
        self.consent.clear();
    }

    /// The user answers the direct caller at `addr`: our microphone goes to it from now on.
    pub(super) fn answer_caller(&mut self, addr: SocketAddr) -> anyhow::Result<()> {
        if self.in_call {
            anyhow::bail!("{addr} cannot be answered during another call");
        }
        if !self.consent.answer(addr) {
            anyhow::bail!("{addr} not answered: {MAX_ANSWERED} callers already are");
        }
        tracing::info!("the user answered {addr}");
        self.answer_callers();
        Ok(())
    }

    /// The user declines the direct caller at `addr`: told BYE and kept out for a while, as
    /// Leave does to every caller.
    pub(super) fn decline_caller(&mut self, addr: SocketAddr) {
        self.consent.forget(addr);
        if self.in_call {
            return;
        }
        if let Some(session) = self.link.session() {
            tracing::info!("declined {addr}: kept out for a while");
            session.hang_up_on(addr);
        }
        self.answer_callers();
        let mut s = lock(&self.shared);
        if let CallPhase::Ringing { from, caller } = &s.call.phase
            && *caller == Some(addr)
        {
            s.call.phase = CallPhase::Ended {
                by: format!("you declined {from}"),
            };
        }
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
