//! What a negotiated two-party call (SIP) adds to the session's rules ([`NegotiatedCall`]):
//! one remote stream, taken over by another only after a silence; the payload types the
//! description agreed, RFC 4733 events counted; nothing sent while the peer holds the call;
//! an empty keepalive after a long silence of ours. Its sources are the session's
//! [`super::latch::Latch::Fixed`] rule, its RTCP goes to the port the description named (or
//! where the peer's believed reports come from).

use std::time::{Duration, Instant};

use super::NegotiatedCall;
use super::TransmitKind;
use super::latch::Named;
use super::negotiated::CallMedia;
use super::protocol::SessionCore;
use crate::codec::any::{Codec, PayloadMap};
use crate::net::rtcp::HeardReports;
use crate::net::rtp::Rtp;

/// A new stream replaces the call's current one only after the current one has been silent
/// this long: a stray or echoed second stream on the port never cuts into the call.
pub const STREAM_HANDOVER: Duration = Duration::from_millis(200);
/// RFC 6263's default: a call that sent nothing for this long sends an empty datagram.
pub const CALL_KEEPALIVE: Duration = Duration::from_secs(15);

impl SessionCore {
    /// Whether a negotiated call takes the media `packet` (always, in other sessions): of an
    /// agreed audio type, and of the call's stream or one taking over from a silent one.
    pub(super) fn call_takes(&mut self, packet: &Rtp<'_>, now: Instant) -> bool {
        let Some(call) = &self.call else {
            return true;
        };
        let pt = packet.header.payload_type;
        if Some(pt) == call.config.events {
            self.stats.events_in += 1;
            return false;
        }
        if !call.config.audio_types.contains(&pt) {
            self.stats.unknown_payload += 1;
            return false;
        }
        let ssrc = packet.header.ssrc;
        if self.peers.contains_key(&ssrc) {
            return true;
        }
        let talking = self
            .peers
            .values()
            .any(|p| now.saturating_duration_since(p.last_media) < STREAM_HANDOVER);
        if talking {
            self.stats.other_stream += 1;
            return false;
        }
        // The peer restarted its sender (or another took over after a silence): a fresh
        // timeline.
        self.peers.clear();
        true
    }

    /// A negotiated call that sent nothing for its keepalive interval sends an empty
    /// datagram (RFC 6263 4.1): RTP stacks drop it as too short, and under SRTP it carries no
    /// key stream.
    pub(super) fn keep_call_alive(&mut self, now: Instant) {
        let Some(call) = self.call.as_mut().filter(|_| !self.left) else {
            return;
        };
        let Some(every) = call.config.keepalive else {
            return;
        };
        if now.saturating_duration_since(call.last_sent) < every {
            return;
        }
        call.last_sent = now;
        self.stats.keepalives += 1;
        let mut data = self.spare.pop().unwrap_or_default();
        data.clear();
        self.send_all(data, TransmitKind::Rtp);
    }

    /// The peer of a negotiated call described its media again (a re-INVITE: hold, resume,
    /// another address, another codec of the agreed ones to send in).
    pub fn renegotiate(
        &mut self,
        named: Named,
        call: NegotiatedCall,
        codec: Codec,
        payloads: PayloadMap,
    ) {
        self.rename_peer(named);
        self.config.payloads = payloads;
        if let Some(payload_type) = self.config.payloads.payload_type(codec)
            && (codec != self.config.codec || payload_type != self.stream.payload_type())
        {
            self.stream.set_payload(payload_type, codec.frame_ticks());
            self.config.codec = codec;
        }
        match self.call.as_mut() {
            Some(media) => media.config = call,
            None => self.call = Some(CallMedia::new(call, self.epoch)),
        }
    }

    /// What the peer of a negotiated call said in its reports (the loss it sees of ours, the
    /// round trip); nothing before it sent.
    pub fn heard(&self) -> HeardReports {
        self.peers
            .values()
            .next()
            .map(|p| p.reports)
            .unwrap_or_default()
    }
}
