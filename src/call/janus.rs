//! A room on a Janus server as a call's [`Link`]: VideoRoom signalling and WebRTC media
//! ([`crate::net::janus`]). The app's join (HTTP signalling, ICE and DTLS take a second or
//! more) runs on its own thread so that the 20 ms tick never waits for it; the command line
//! waits for it by its deadline.

use std::net::SocketAddr;
use std::sync::atomic::AtomicBool;
use std::thread::JoinHandle;
use std::time::Instant;

use super::link::{JoinWait, Link, LinkEvent, wait_for_join};
use crate::net::janus::JanusError;
use crate::net::janus::room::{Member, Notice, RoomConfig, server_addr};
use crate::net::transport::{PeerFrame, PeerInfo};

/// RTP ticks of one 20 ms frame on WebRTC's 48 kHz Opus clock.
const OPUS_TICKS_PER_FRAME: u32 = 960;

pub use crate::net::janus::url::is_janus_url;

type Joining = JoinHandle<Result<(Member, Vec<Notice>), JanusError>>;

enum RoomState {
    Joining(Option<Joining>),
    In(Box<Member>),
    Failed,
}

/// Why a join could not even start.
#[derive(Debug, thiserror::Error)]
pub enum JoinError {
    #[error(transparent)]
    Janus(#[from] JanusError),
    #[error("cannot start the join's thread: {0}")]
    Thread(#[from] std::io::Error),
}

/// How waiting for a Janus join ended.
pub type JanusJoinWait = JoinWait<Vec<Notice>, JanusError>;

/// Our membership of a Janus VideoRoom, from the first request on.
pub struct JanusLink {
    state: RoomState,
    /// Where the server is, shown as every publisher's address.
    server: SocketAddr,
    place: String,
    /// Someone published at some point.
    heard: bool,
}

impl JanusLink {
    /// Starts joining (publishing our microphone, subscribing to everyone else).
    pub fn join(config: RoomConfig) -> Result<Self, JoinError> {
        Self::start(config, true)
    }

    /// Starts joining on a thread of its own, publishing when `publish`. The server's host is
    /// looked up here first, which takes as long as the resolver does: the app's engine looks
    /// it up off its worker and calls [`JanusLink::start_at`].
    pub fn start(config: RoomConfig, publish: bool) -> Result<Self, JoinError> {
        let server = server_addr(config.url.trim())?;
        Self::start_at(config, publish, server)
    }

    /// [`JanusLink::start`] with the server's address already found.
    pub fn start_at(
        config: RoomConfig,
        publish: bool,
        server: SocketAddr,
    ) -> Result<Self, JoinError> {
        let place = format!("Janus room {:?} on {}", config.room, config.url);
        let handle = std::thread::Builder::new()
            .name("janus-join".into())
            .spawn(move || Member::join(config, publish))?;
        Ok(Self {
            state: RoomState::Joining(Some(handle)),
            server,
            place,
            heard: false,
        })
    }

    /// The room and server, for the call's status.
    pub fn place(&self) -> &str {
        &self.place
    }

    /// Follows the join, then the room (publishers coming and going, a lost and rejoined
    /// session).
    fn follow(&mut self) -> Vec<LinkEvent> {
        match &mut self.state {
            RoomState::Joining(_) => match self.join_finished() {
                None => Vec::new(),
                Some(Ok(notices)) => {
                    let mut news = vec![LinkEvent::Joined {
                        place: self.place.clone(),
                        id: self
                            .member()
                            .and_then(Member::id)
                            .unwrap_or_else(|| "-".into()),
                    }];
                    news.extend(notices.into_iter().map(LinkEvent::from));
                    news
                }
                Some(Err(e)) => vec![LinkEvent::Failed(describe_janus_error(&e))],
            },
            RoomState::In(member) => member.poll().into_iter().map(LinkEvent::from).collect(),
            RoomState::Failed => Vec::new(),
        }
    }

    /// The join's outcome once its thread is done (in the room, or failed); none before.
    fn join_finished(&mut self) -> Option<Result<Vec<Notice>, JanusError>> {
        let RoomState::Joining(handle) = &mut self.state else {
            return None;
        };
        if !handle.as_ref().is_some_and(JoinHandle::is_finished) {
            return None;
        }
        let joined = match handle.take().map(JoinHandle::join) {
            Some(Ok(joined)) => joined,
            _ => Err(JanusError::Protocol("the join stopped unexpectedly".into())),
        };
        match joined {
            Ok((member, notices)) => {
                self.state = RoomState::In(Box::new(member));
                Some(Ok(notices))
            }
            Err(e) => {
                self.state = RoomState::Failed;
                Some(Err(e))
            }
        }
    }

    /// Waits for the join until it is done, `stop` is set or `until` passes, whichever comes
    /// first: a Janus that never answers holds neither a signal nor a deadline. A join given
    /// up goes on on its thread; its session times out on the server.
    pub fn wait_joined(&mut self, stop: &AtomicBool, until: Option<Instant>) -> JanusJoinWait {
        wait_for_join(stop, until, || match self.join_finished() {
            None if !matches!(self.state, RoomState::Joining(_)) => {
                Some(Err(JanusError::Protocol("not joining".into())))
            }
            finished => finished,
        })
    }

    /// Our membership once joined, taken out of the link (the command line's send).
    pub fn into_member(self) -> Option<Member> {
        match self.state {
            RoomState::In(member) => Some(*member),
            _ => None,
        }
    }

    /// Our membership, once joined.
    pub fn member(&self) -> Option<&Member> {
        match &self.state {
            RoomState::In(member) => Some(member),
            _ => None,
        }
    }

    /// Leaves the room; `Err` where Janus did not confirm it.
    pub fn hang_up(&mut self) -> Result<(), JanusError> {
        match std::mem::replace(&mut self.state, RoomState::Failed) {
            RoomState::In(member) => member.leave(),
            // A join still running finishes on its own thread; its session times out on the
            // server. Joining it here would stall the tick for as long as the join takes.
            RoomState::Joining(_) | RoomState::Failed => Ok(()),
        }
    }

    fn feed_infos(&self) -> Vec<PeerInfo> {
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

/// A join's failure, with what to do about a pin.
pub fn describe_janus_error(e: &JanusError) -> String {
    match e {
        JanusError::Plugin { code, reason } if *code == 433 || reason.contains("pin") => {
            format!("{e}: the room has a pin, give it as the passphrase")
        }
        _ => e.to_string(),
    }
}

impl Link for JanusLink {
    fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) {
        if let Some(m) = self.member() {
            m.pull(now, out);
        }
        self.heard |= !out.is_empty();
    }

    fn peers(&self) -> Vec<PeerInfo> {
        self.feed_infos()
    }

    fn all_left(&self) -> bool {
        self.member()
            .is_some_and(|m| self.heard && m.in_room() && m.feeds().iter().all(|f| f.left))
    }

    fn send_audio(&mut self, payload: &[u8], ticks: u32) {
        if let Some(m) = self.member()
            && let Err(e) = m.send(payload, ticks)
        {
            tracing::debug!("send to Janus: {e}");
        }
    }

    fn skip_frames(&mut self, frames: u32) {
        if let Some(m) = self.member() {
            m.skip(frames * OPUS_TICKS_PER_FRAME);
        }
    }

    fn unknown_payload(&self) -> u64 {
        self.member()
            .map(|m| m.feeds().iter().map(|f| f.receiver.unknown_payload).sum())
            .unwrap_or(0)
    }

    fn leave(&mut self) {
        if let Err(e) = self.hang_up() {
            tracing::warn!("leaving the Janus room: {e}");
        }
    }

    fn poll(&mut self) -> Vec<LinkEvent> {
        self.follow()
    }
}

/// A room's notice as any link says it.
impl From<Notice> for LinkEvent {
    fn from(notice: Notice) -> Self {
        match notice {
            Notice::Joined { feed, name } => LinkEvent::PeerJoined { id: feed, name },
            Notice::Left { feed, name } => LinkEvent::PeerLeft { id: feed, name },
            Notice::Lost { reason } => LinkEvent::Lost { reason },
            Notice::RejoinFailed { reason } => LinkEvent::RejoinFailed { reason },
            Notice::Rejoined { id } => LinkEvent::Rejoined { id },
            Notice::Skipped { feed, name, reason } => LinkEvent::PeerSkipped {
                id: feed,
                name,
                reason,
            },
        }
    }
}
