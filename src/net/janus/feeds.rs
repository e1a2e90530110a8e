//! What the media side knows of each subscribed publisher (a feed), and its counters.

use std::net::SocketAddr;

use crate::net::peer::{PeerReceiver, ReceiverStats};
use crate::net::transport::{PeerId, PeerInfo};

/// What the owner knows of one subscribed publisher.
#[derive(Debug, Clone, PartialEq)]
pub struct FeedInfo {
    pub feed: String,
    pub name: String,
    /// The SSRC its packets arrive with (Janus's, for this subscription).
    pub ssrc: Option<u32>,
    pub connected: bool,
    /// It left the room (or stopped publishing).
    pub left: bool,
    pub receiver: ReceiverStats,
}

impl FeedInfo {
    /// The feed as a peer of the call, as a lipcall session describes its peers (its media
    /// comes from the Janus `server`); `None` before its first packet.
    pub fn peer_info(&self, server: SocketAddr) -> Option<PeerInfo> {
        Some(PeerInfo {
            id: PeerId::Janus(self.ssrc?),
            addr: server,
            cname: None,
            name: Some(self.name.clone()),
            receiver: self.receiver,
            rtt_ms: None,
            their_loss: None,
            said_bye: self.left,
            ended: self.left,
        })
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MediaStats {
    pub datagrams: u64,
    /// Datagrams no connection accepted.
    pub unmatched: u64,
    pub sent: u64,
    /// Datagrams the socket refused, and Opus packets str0m refused.
    pub send_errors: u64,
    /// Opus packets handed to str0m for sending.
    pub published: u64,
    pub publisher_connected: bool,
    /// A connection failed (ICE or DTLS): its reason.
    pub failed: Option<&'static str>,
}

pub(super) struct Feed {
    pub name: String,
    pub receiver: PeerReceiver,
    pub ssrc: Option<u32>,
    pub connected: bool,
    pub left: bool,
}

impl Feed {
    pub fn info(&self, feed: String) -> FeedInfo {
        FeedInfo {
            feed,
            name: self.name.clone(),
            ssrc: self.ssrc,
            connected: self.connected,
            left: self.left,
            receiver: self.receiver.stats(),
        }
    }
}
