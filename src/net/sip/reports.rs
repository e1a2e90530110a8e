//! The RTCP of one SIP call (RFC 3550 6): our reports, an SR while we send (our packet and
//! octet counts, NTP and RTP time on the call's clock) or an RR, each with a block about the
//! peer's stream and our SDES CNAME, every 5 s spread 0.5-1.5x, and BYE at the end; and the
//! peer's reports, which tell the loss and jitter it sees of our stream and the round trip.
//!
//! Where RTCP may come from is the call's [`crate::net::session::latch::FixedSources`] rule
//! (`super::media`): until the peer's first report is believed, only from the RTCP address its
//! SDP gave, from the IP its SIP comes from, or from the IP the call's RTP was latched to; that
//! report fixes where ours go (symmetric RTCP, RFC 4961). Reports by another SSRC than the
//! peer's stream are not taken.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use crate::net::rtcp::{
    self, HeardReports, NtpClock, Outgoing, ReportBlock, ReportTimer, RtcpError, RtcpItem,
    SenderInfo, system_draw,
};
use crate::net::rtp::RtpStream;

/// RFC 3550 6.2's minimum interval, which is the interval of a two-party voice call.
pub const REPORT_INTERVAL: Duration = Duration::from_secs(5);

/// Our side of a call's RTCP, and what the peer's reports said.
#[derive(Debug, Clone)]
pub(super) struct CallRtcp {
    timer: ReportTimer,
    clock: NtpClock,
    cname: String,
    /// Our stream's packet count at the report before the last and at the last: more since
    /// the first makes the next one an SR (RFC 3550 6.4).
    packets_at_reports: [u32; 2],
    heard: HeardReports,
    peer_cname: Option<String>,
    said_bye: bool,
}

/// What one of the peer's compound packets held.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Taken {
    /// A report or SDES of the peer's.
    Peer,
    /// Reports or SDES of another source only: not the call's.
    Stranger,
    /// Neither (an APP packet, our own reports coming back).
    Nothing,
}

impl CallRtcp {
    /// The RTCP of a call whose stream is `ssrc`, sent from `local`, starting at `now`.
    pub(super) fn new(ssrc: u32, local: SocketAddr, now: Instant) -> Self {
        Self {
            timer: ReportTimer::new(REPORT_INTERVAL, now, system_draw),
            clock: NtpClock::new(now),
            cname: rtcp::cname(ssrc, local),
            packets_at_reports: [0; 2],
            heard: HeardReports::default(),
            peer_cname: None,
            said_bye: false,
        }
    }

    pub(super) fn heard(&self) -> HeardReports {
        self.heard
    }

    pub(super) fn peer_cname(&self) -> Option<&str> {
        self.peer_cname.as_deref()
    }

    /// Reads the peer's compound packet (in the clear), about our stream `ours` and sent by
    /// the peer's `peer` (its RTP's SSRC, once known), that came at `arrival`.
    pub(super) fn take(
        &mut self,
        data: &[u8],
        ours: u32,
        peer: Option<u32>,
        arrival: Instant,
    ) -> Result<Taken, RtcpError> {
        let mut taken = Taken::Nothing;
        // Whether an item by `ssrc` is the peer's, noting what the packet held.
        let mut seen = |ssrc: u32| {
            if ssrc == ours {
                return false;
            }
            if peer.is_none_or(|p| p == ssrc) {
                taken = Taken::Peer;
                return true;
            }
            if taken == Taken::Nothing {
                taken = Taken::Stranger;
            }
            false
        };
        for item in rtcp::parse(data)? {
            match item {
                RtcpItem::Report {
                    reporter,
                    sender,
                    blocks,
                } if seen(reporter) => {
                    let arrival_ntp = self.clock.at(arrival);
                    self.heard
                        .take(sender.as_ref(), &blocks, ours, arrival, arrival_ntp);
                }
                RtcpItem::Names {
                    ssrc,
                    cname: Some(cname),
                    ..
                } if seen(ssrc) => self.peer_cname = Some(cname),
                RtcpItem::Names { ssrc, .. } => {
                    seen(ssrc);
                }
                _ => {}
            }
        }
        Ok(taken)
    }

    /// Whether the periodic report is due at `now` (none after BYE).
    pub(super) fn due(&mut self, now: Instant) -> bool {
        !self.said_bye && self.timer.due(now)
    }

    /// Whether BYE is still to be said (once), as the call ends.
    pub(super) fn bye(&mut self) -> bool {
        !std::mem::replace(&mut self.said_bye, true)
    }

    /// A compound packet in the clear: an SR if `stream` sent since the report before the
    /// last, or ever where it is the BYE (which marks where the stream ends); an RR else; with
    /// a block about the peer's stream where one was `received` (its SSRC, and
    /// what the jitter buffer counted), our CNAME, and BYE where `bye`.
    pub(super) fn report(
        &mut self,
        stream: &RtpStream,
        received: Option<(u32, (u8, u32, u32, u32))>,
        bye: bool,
        now: Instant,
    ) -> Result<Vec<u8>, RtcpError> {
        let [before_last, last] = self.packets_at_reports;
        let sent = stream.packets_sent != before_last || (bye && stream.packets_sent > 0);
        self.packets_at_reports = [last, stream.packets_sent];
        let sender = sent.then(|| SenderInfo::of(stream, self.clock.at(now)));
        let block = received
            .map(|(ssrc, reception)| ReportBlock::about(ssrc, reception, self.heard.last_sr, now));
        let mut out = Vec::new();
        rtcp::build(
            &Outgoing {
                ssrc: stream.ssrc,
                sender,
                blocks: block.as_slice(),
                cname: &self.cname,
                name: None,
                note: None,
                bye,
                bye_reason: None,
            },
            &mut out,
        )?;
        Ok(out)
    }
}
