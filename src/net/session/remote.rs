//! One remote peer as the session keeps it, and the limits on peers and on what is kept for
//! sources that are not peers yet.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use super::{PeerId, PeerInfo};
use crate::net::peer::PeerReceiver;
use crate::net::rtcp::HeardReports;

/// Packets a peer's media must have brought before it is confirmed.
pub(super) const CONFIRM_PACKETS: u64 = 5;
/// An unconfirmed peer without media for this long is forgotten.
pub(super) const UNCONFIRMED_TIMEOUT: Duration = Duration::from_secs(2);
/// A confirmed peer without media for this long may make room for a new one.
pub(super) const IDLE_EVICT: Duration = Duration::from_secs(5);
/// Packets in sequence from a new address before a quiet peer moves there.
pub(super) const MOVE_PACKETS: u32 = 3;
/// Start hints (SRs sent before a stream's first packet) kept for peers not yet created.
pub(super) const PENDING_STARTS: usize = 8;
/// Names (SDES sent before a stream's first packet, as every sender's first RTCP is) kept for
/// peers not yet created: without them a caller stays nameless until its next report.
pub(super) const PENDING_NAMES: usize = 8;

/// SDES of a source that is not a peer yet: (SSRC, where from, CNAME, NAME, when).
pub(super) type PendingNames = (u32, SocketAddr, Option<String>, Option<String>, Instant);

pub(super) struct Peer {
    pub(super) receiver: PeerReceiver,
    /// Where its media comes from: RTCP and RTP from elsewhere are ignored.
    pub(super) addr: SocketAddr,
    pub(super) cname: Option<String>,
    pub(super) name: Option<String>,
    pub(super) last_heard: Instant,
    /// The last media packet from `addr`.
    pub(super) last_media: Instant,
    /// Media packets filed.
    pub(super) media: u64,
    /// Another address continuing this peer's sequence: (address, its next sequence number,
    /// packets so far).
    pub(super) candidate: Option<(SocketAddr, u16, u32)>,
    pub(super) reports: HeardReports,
    pub(super) said_bye: bool,
}

impl Peer {
    pub(super) fn confirmed(&self) -> bool {
        self.media >= CONFIRM_PACKETS
    }

    /// Whether a packet from `from`, not the pinned address, shows the peer has moved there:
    /// its pinned address is quiet and `from` sent `MOVE_PACKETS` in a row continuing the
    /// peer's sequence. Packets from the pinned address cancel a candidate.
    pub(super) fn moved_to(&mut self, from: SocketAddr, seq: u16) -> bool {
        let count = match self.candidate {
            Some((addr, next, count)) if addr == from && next == seq => count + 1,
            _ => {
                let continues = self
                    .receiver
                    .highest_sequence()
                    .is_some_and(|h| (1..=16).contains(&seq.wrapping_sub(h)));
                if !continues {
                    return false;
                }
                1
            }
        };
        self.candidate = Some((from, seq.wrapping_add(1), count));
        count >= MOVE_PACKETS
    }

    pub(super) fn info(&self, ssrc: u32) -> PeerInfo {
        let receiver = self.receiver.stats();
        PeerInfo {
            id: PeerId::Ssrc(ssrc),
            addr: self.addr,
            cname: self.cname.clone(),
            name: self.name.clone(),
            ended: self.said_bye && receiver.jitter.buffered_frames == 0,
            receiver,
            rtt_ms: self.reports.rtt_ms,
            their_loss: self.reports.their_loss(),
            said_bye: self.said_bye,
        }
    }
}
