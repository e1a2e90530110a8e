//! What every link reports about its remote peers, whatever carries them.

use std::net::SocketAddr;

use crate::net::peer::{PlayedFrame, ReceiverStats};

/// What the session knows about one remote peer.
#[derive(Debug, Clone, PartialEq)]
pub struct PeerInfo {
    pub ssrc: u32,
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
    pub ssrc: u32,
    pub frame: PlayedFrame,
}
