//! What the media side knows of each subscribed publisher (a feed), and its counters.

use std::collections::{HashMap, VecDeque};
use std::net::SocketAddr;
use std::time::Instant;

use crate::net::peer::{PeerReceiver, ReceiverStats};
use crate::net::transport::{PeerFrame, PeerId, PeerInfo};

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

/// Publishers that left and played out, kept (without their decoders) for the summary; the
/// oldest go first, so that a room of churning publishers holds no more than this.
const DEPARTED_KEPT: usize = 64;

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

/// The next 20 ms of every feed in `feeds` that is playing; those that left and played out go
/// to `departed`.
pub(super) fn pull(
    feeds: &mut HashMap<String, Feed>,
    departed: &mut VecDeque<FeedInfo>,
    now: Instant,
    out: &mut Vec<PeerFrame>,
) {
    let mut played_out = Vec::new();
    for (id, feed) in feeds.iter_mut() {
        let frame = feed.ssrc.and_then(|ssrc| {
            feed.receiver.pull(now).map(|frame| PeerFrame {
                peer: PeerId::Janus(ssrc),
                frame,
            })
        });
        match frame {
            Some(frame) => out.push(frame),
            None if feed.left => played_out.push(id.clone()),
            None => {}
        }
    }
    for id in played_out {
        if let Some(feed) = feeds.remove(&id) {
            if departed.len() == DEPARTED_KEPT {
                departed.pop_front();
            }
            departed.push_back(feed.info(id));
        }
    }
}

/// Every feed playing, then those gone (the last [`DEPARTED_KEPT`]).
pub(super) fn infos(feeds: &HashMap<String, Feed>, departed: &VecDeque<FeedInfo>) -> Vec<FeedInfo> {
    let mut out: Vec<FeedInfo> = feeds.iter().map(|(id, f)| f.info(id.clone())).collect();
    out.sort_by(|a, b| a.feed.cmp(&b.feed));
    out.extend(departed.iter().cloned());
    out
}
