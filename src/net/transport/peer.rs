//! What every link reports about its remote peers, whatever carries them.

use std::fmt;
use std::net::SocketAddr;

use crate::net::peer::{PlayedFrame, ReceiverStats};

/// Who a remote peer is, in the terms of the transport that carries it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum PeerId {
    /// An RTP stream's SSRC: a peer of lipcall's own session, the other end of a SIP call.
    Ssrc(u32),
    /// A user's session on a Mumble server.
    Mumble(u32),
    /// A Janus publisher, by the SSRC of its stream as Janus forwards it.
    Janus(u32),
}

impl PeerId {
    /// The number within its kind (a peer's file names, its living face's seed).
    pub fn number(self) -> u32 {
        match self {
            PeerId::Ssrc(n) | PeerId::Mumble(n) | PeerId::Janus(n) => n,
        }
    }
}

impl fmt::Display for PeerId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PeerId::Ssrc(ssrc) | PeerId::Janus(ssrc) => write!(f, "ssrc={ssrc:08x}"),
            PeerId::Mumble(session) => write!(f, "session={session}"),
        }
    }
}

/// What a link knows about one remote peer.
#[derive(Debug, Clone, PartialEq)]
pub struct PeerInfo {
    pub id: PeerId,
    pub addr: SocketAddr,
    pub cname: Option<String>,
    pub name: Option<String>,
    pub receiver: ReceiverStats,
    /// Round trip from the peer's last report about us.
    pub rtt_ms: Option<f64>,
    /// Share of our packets the peer reported lost (last report, 0..1).
    pub their_loss: Option<f64>,
    pub said_bye: bool,
    pub ended: bool,
}

/// One peer's frame in a pull.
#[derive(Debug, Clone, PartialEq)]
pub struct PeerFrame {
    pub peer: PeerId,
    pub frame: PlayedFrame,
}
