//! The worker's link to a call: lipcall's own transport (a direct call, a relay room, or
//! listening while idle) or a room on a Janus server. A Janus join (HTTP signalling, ICE and
//! DTLS) takes a second or more, so it runs on its own thread and the 20 ms tick never waits
//! for it.

use std::net::SocketAddr;
use std::thread::JoinHandle;
use std::time::Instant;

use crate::net::janus::JanusError;
use crate::net::janus::room::{Member, Notice, RoomConfig, server_addr};
use crate::net::session::{PeerFrame, PeerInfo, Session};

/// RTP ticks of one 20 ms frame on WebRTC's 48 kHz Opus clock.
const OPUS_TICKS_PER_FRAME: u32 = 960;

/// Whether a call address names a Janus server (its HTTP API) rather than a lipcall peer or
/// relay (`host:port`).
pub fn is_janus_url(address: &str) -> bool {
    let a = address.trim();
    a.starts_with("http://") || a.starts_with("https://")
}

/// What a Janus room did since the last poll.
#[derive(Debug, Clone, PartialEq)]
pub enum RoomNews {
    /// In the room (`place`, as [`JanusLink::place`] says it) as publisher `id`.
    Joined {
        place: String,
        id: String,
    },
    /// The first join failed: the call is over.
    Failed(String),
    Notice(Notice),
}

type Joining = JoinHandle<Result<(Member, Vec<Notice>), JanusError>>;

enum RoomState {
    Joining(Option<Joining>),
    In(Box<Member>),
    Failed,
}

/// Our membership of a Janus VideoRoom, from the first request on.
pub struct JanusLink {
    state: RoomState,
    /// Where the server is, shown as every publisher's address.
    server: SocketAddr,
    place: String,
}

impl JanusLink {
    /// Starts joining (publishing our microphone, subscribing to everyone else).
    pub fn join(config: RoomConfig) -> anyhow::Result<Self> {
        let server = server_addr(config.url.trim())?;
        let place = format!("Janus room {:?} on {}", config.room, config.url);
        let handle = std::thread::Builder::new()
            .name("janus-join".into())
            .spawn(move || Member::join(config, true))?;
        Ok(Self {
            state: RoomState::Joining(Some(handle)),
            server,
            place,
        })
    }

    /// The room and server, for the call's status.
    pub fn place(&self) -> &str {
        &self.place
    }

    /// Follows the join, then the room (publishers coming and going, a lost and rejoined
    /// session).
    pub fn poll(&mut self) -> Vec<RoomNews> {
        match &mut self.state {
            RoomState::Joining(handle) => {
                if !handle.as_ref().is_some_and(JoinHandle::is_finished) {
                    return Vec::new();
                }
                let joined = handle.take().map(JoinHandle::join);
                match joined {
                    Some(Ok(Ok((member, notices)))) => {
                        let mut news = vec![RoomNews::Joined {
                            place: self.place.clone(),
                            id: member.id().unwrap_or("-").to_owned(),
                        }];
                        news.extend(notices.into_iter().map(RoomNews::Notice));
                        self.state = RoomState::In(Box::new(member));
                        news
                    }
                    Some(Ok(Err(e))) => self.fail(describe_janus_error(&e)),
                    _ => self.fail("the Janus join stopped unexpectedly".into()),
                }
            }
            RoomState::In(member) => member.poll().into_iter().map(RoomNews::Notice).collect(),
            RoomState::Failed => Vec::new(),
        }
    }

    fn fail(&mut self, reason: String) -> Vec<RoomNews> {
        self.state = RoomState::Failed;
        vec![RoomNews::Failed(reason)]
    }

    fn member(&self) -> Option<&Member> {
        match &self.state {
            RoomState::In(member) => Some(member),
            _ => None,
        }
    }

    fn leave(&mut self) {
        match std::mem::replace(&mut self.state, RoomState::Failed) {
            RoomState::In(member) => {
                if let Err(e) = member.leave() {
                    tracing::warn!("leaving the Janus room: {e}");
                }
            }
            // A join still running finishes on its own thread; its session times out on the
            // server. Joining it here would stall the tick for as long as the join takes.
            RoomState::Joining(_) | RoomState::Failed => {}
        }
    }

    fn peers(&self) -> Vec<PeerInfo> {
        let Some(member) = self.member() else {
            return Vec::new();
        };
        member
            .feeds()
            .iter()
            .filter_map(|feed| feed.peer_info(self.server))
            .collect()
    }
}

fn describe_janus_error(e: &JanusError) -> String {
    match e {
        JanusError::Plugin { code, reason } if *code == 433 || reason.contains("pin") => {
            format!("{e}: the room has a pin, give it as the passphrase")
        }
        _ => e.to_string(),
    }
}

/// Where the worker's audio goes and comes from.
pub enum Link {
    /// lipcall's own transport: idle listening, a direct call, or a relay room.
    Session(Session),
    Janus(Box<JanusLink>),
}

impl Link {
    pub fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) {
        match self {
            Link::Session(s) => s.pull(now, out),
            Link::Janus(j) => {
                if let Some(m) = j.member() {
                    m.pull(now, out);
                }
            }
        }
    }

    pub fn peers(&self) -> Vec<PeerInfo> {
        match self {
            Link::Session(s) => s.peers(),
            Link::Janus(j) => j.peers(),
        }
    }

    /// Sends one encoded payload of `frames` 20 ms frames.
    pub fn send_frames(&self, payload: &[u8], frames: u32) {
        match self {
            Link::Session(s) => {
                if let Err(e) = s.send_frames(payload, frames) {
                    tracing::debug!("send: {e}");
                }
            }
            Link::Janus(j) => {
                if let Some(m) = j.member()
                    && let Err(e) = m.send(payload, frames * OPUS_TICKS_PER_FRAME)
                {
                    tracing::debug!("send to Janus: {e}");
                }
            }
        }
    }

    /// Frames not sent (the microphone gate was closed): the stream's clock moves on.
    pub fn skip_frames(&self, frames: u32) {
        match self {
            Link::Session(s) => s.skip_frames(frames),
            Link::Janus(j) => {
                if let Some(m) = j.member() {
                    m.skip(frames * OPUS_TICKS_PER_FRAME);
                }
            }
        }
    }

    pub fn leave(&mut self) {
        match self {
            Link::Session(s) => s.leave(),
            Link::Janus(j) => j.leave(),
        }
    }

    /// RTP packets of payload types nobody mapped, dropped.
    pub fn unknown_payload(&self) -> u64 {
        match self {
            Link::Session(s) => s.stats().unknown_payload,
            Link::Janus(j) => j
                .member()
                .map(|m| m.feeds().iter().map(|f| f.receiver.unknown_payload).sum())
                .unwrap_or(0),
        }
    }

    /// lipcall's own session, where the call runs on one (its relay handshake, its stats).
    pub fn session(&self) -> Option<&Session> {
        match self {
            Link::Session(s) => Some(s),
            Link::Janus(_) => None,
        }
    }

    pub fn local_addr(&self) -> Option<SocketAddr> {
        match self {
            Link::Session(s) => s.local_addr().ok(),
            Link::Janus(_) => None,
        }
    }

    /// News from a Janus room; nothing for lipcall's own transport.
    pub fn poll(&mut self) -> Vec<RoomNews> {
        match self {
            Link::Session(_) => Vec::new(),
            Link::Janus(j) => j.poll(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn janus_urls_are_told_from_peer_addresses() {
        assert!(is_janus_url("http://127.0.0.1:8088/janus"));
        assert!(is_janus_url(" https://janus.example/janus"));
        assert!(!is_janus_url("127.0.0.1:5004"));
        assert!(!is_janus_url("relay.example:5004"));
    }
}
