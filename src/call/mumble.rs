//! A channel on a Mumble server as a call's [`Link`]: each user who speaks there (a Mumble
//! session id) is a peer with the user's name, received through the same jitter buffer and
//! Opus decoder as every other transport ([`crate::net::mumble`]). The app's join runs on a
//! thread of its own (TLS and the server's answer take a moment; the 20 ms tick never waits
//! for it); the command line waits for it by its deadline and takes the connection over.

use std::sync::atomic::AtomicBool;
use std::sync::{Arc, OnceLock};
use std::thread::JoinHandle;
use std::time::Instant;

use super::link::{JoinWait, Link, LinkEvent, wait_for_join};
use crate::net::mumble::MumbleError;
use crate::net::mumble::client::ClientEvent;
use crate::net::mumble::connection::{ConnectConfig, Connection, Notice, Remote};
use crate::net::mumble::events::describe_unlisted;
use crate::net::mumble::identity::Trust;
use crate::net::transport::{PeerFrame, PeerId, PeerInfo};

/// Whether a call address names a Mumble server (`mumble://HOST[:PORT][/CHANNEL]`).
pub fn is_mumble_url(address: &str) -> bool {
    address.trim().starts_with("mumble://")
}

/// The server (`HOST[:PORT]`) and channel of a `mumble://` address.
pub fn parse_mumble_url(address: &str) -> Option<(String, Option<String>)> {
    let rest = address.trim().strip_prefix("mumble://")?;
    let (server, channel) = match rest.split_once('/') {
        Some((s, c)) => (s, Some(c.trim_end_matches('/'))),
        None => (rest, None),
    };
    // user@host: the name comes from elsewhere.
    let server = server.rsplit_once('@').map_or(server, |(_, h)| h);
    if server.is_empty() {
        return None;
    }
    Some((
        server.to_string(),
        channel.filter(|c| !c.is_empty()).map(str::to_string),
    ))
}

type Joining = JoinHandle<Result<Connection, MumbleError>>;

enum Stage {
    Joining(Option<Joining>),
    In(Box<Connection>),
    /// The join failed, or we left.
    Gone,
}

/// What the app asks of a Mumble call beyond [`Link`]: moving between channels, self-mute,
/// the channels and users, the certificate. Cheap to clone; empty until joined.
#[derive(Clone, Default)]
pub struct MumbleHandle(Arc<OnceLock<Joined>>);

struct Joined {
    remote: Remote,
    fingerprint: String,
    trust: Trust,
}

impl MumbleHandle {
    /// On the server yet.
    pub fn joined(&self) -> bool {
        self.0.get().is_some()
    }

    /// The server certificate's SHA-256 fingerprint and how it stands, once joined.
    pub fn fingerprint(&self) -> Option<(&str, &Trust)> {
        self.0.get().map(|j| (j.fingerprint.as_str(), &j.trust))
    }

    /// The connection's remote controls, once joined.
    pub fn remote(&self) -> Option<&Remote> {
        self.0.get().map(|j| &j.remote)
    }
}

/// Our membership of a Mumble server's channel, from the join on.
pub struct MumbleLink {
    stage: Stage,
    place: String,
    /// Someone spoke at some point.
    heard: bool,
    /// The call is over once in: why (removed, untrusted).
    ended: Option<String>,
    handle: MumbleHandle,
}

impl MumbleLink {
    /// Starts joining on a thread of its own; [`Link::poll`] says how it went.
    pub fn join(config: ConnectConfig, place: String) -> std::io::Result<Self> {
        let thread = std::thread::Builder::new()
            .name("mumble-join".into())
            .spawn(move || Connection::connect(config))?;
        Ok(Self::new(Stage::Joining(Some(thread)), place))
    }

    /// Around a connection already joined.
    pub fn joined(connection: Connection, place: String) -> Self {
        let mut link = Self::new(Stage::Joining(None), place);
        link.enter(connection);
        link
    }

    fn new(stage: Stage, place: String) -> Self {
        Self {
            stage,
            place,
            heard: false,
            ended: None,
            handle: MumbleHandle::default(),
        }
    }

    fn enter(&mut self, connection: Connection) {
        let (print, trust) = connection.fingerprint();
        let joined = Joined {
            remote: connection.remote(),
            fingerprint: print.to_string(),
            trust: trust.clone(),
        };
        if self.handle.0.set(joined).is_err() {
            tracing::debug!("a Mumble link joined twice");
        }
        self.stage = Stage::In(Box::new(connection));
    }

    /// What only Mumble has, for whoever drives this link.
    pub fn handle(&self) -> MumbleHandle {
        self.handle.clone()
    }

    /// The connection, once joined.
    pub fn connection(&self) -> Option<&Connection> {
        match &self.stage {
            Stage::In(connection) => Some(connection),
            _ => None,
        }
    }

    pub fn place(&self) -> &str {
        &self.place
    }

    /// Why the call ended once in (removed, the server no longer the one trusted), if it did.
    pub fn ended(&self) -> Option<&str> {
        self.ended.as_deref()
    }

    /// The join's outcome once its thread is done (in, or gone); none before.
    fn join_finished(&mut self) -> Option<Result<(), MumbleError>> {
        let Stage::Joining(thread) = &mut self.stage else {
            return None;
        };
        if !thread.as_ref().is_some_and(JoinHandle::is_finished) {
            return None;
        }
        let joined = match thread.take().map(JoinHandle::join) {
            Some(Ok(joined)) => joined,
            _ => Err(MumbleError::Io(std::io::Error::other(
                "the join stopped unexpectedly",
            ))),
        };
        Some(match joined {
            Ok(connection) => {
                self.enter(connection);
                Ok(())
            }
            Err(e) => {
                self.stage = Stage::Gone;
                Err(e)
            }
        })
    }

    /// The join's outcome once its thread is done, as news.
    fn follow_join(&mut self) -> Option<LinkEvent> {
        Some(match self.join_finished()? {
            Ok(()) => LinkEvent::Joined {
                place: self.place.clone(),
                id: self
                    .connection()
                    .and_then(Connection::session)
                    .map_or_else(|| "-".into(), |s| s.to_string()),
            },
            Err(e) => LinkEvent::Failed(e.to_string()),
        })
    }

    /// Waits for the join until it is done, `stop` is set or `until` passes, whichever comes
    /// first. A join given up goes on on its thread until its own timeouts end it.
    pub fn wait_joined(
        &mut self,
        stop: &AtomicBool,
        until: Option<Instant>,
    ) -> JoinWait<(), MumbleError> {
        wait_for_join(stop, until, || match self.stage {
            Stage::Joining(_) => self.join_finished(),
            Stage::In(_) => Some(Ok(())),
            Stage::Gone => Some(Err(MumbleError::NotConnected)),
        })
    }

    /// The connection once joined, taken out of the link (the command line's send).
    pub fn into_connection(self) -> Option<Connection> {
        match self.stage {
            Stage::In(connection) => Some(*connection),
            _ => None,
        }
    }

    fn event(&mut self, notice: Notice) -> Option<LinkEvent> {
        Some(match notice {
            Notice::Client(ClientEvent::UserJoined { session, name }) => LinkEvent::PeerJoined {
                id: session.to_string(),
                name,
            },
            Notice::Client(ClientEvent::UserLeft { session, name }) => LinkEvent::PeerLeft {
                id: session.to_string(),
                name,
            },
            Notice::Lost(reason) => LinkEvent::Lost { reason },
            Notice::RejoinFailed { reason, .. } => LinkEvent::RejoinFailed { reason },
            Notice::Rejoined(session) => LinkEvent::Rejoined {
                id: session.to_string(),
            },
            Notice::Client(ClientEvent::Removed(reason)) => {
                self.end(format!("the Mumble server removed us: {reason}"))
            }
            Notice::Untrusted(reason) => self.end(format!("{reason}; not reconnecting")),
            Notice::Client(ClientEvent::Synced { .. }) => return None,
            Notice::Client(ClientEvent::Rejected(reason)) => {
                LinkEvent::Refusal(format!("the server refused us: {reason}"))
            }
            Notice::Client(ClientEvent::Denied(reason)) => {
                LinkEvent::Refusal(format!("the server refused: {reason}"))
            }
            Notice::Client(ClientEvent::Text { from, message }) => {
                LinkEvent::Note(format!("{from} says: {message}"))
            }
            Notice::Client(ClientEvent::Unlisted {
                joined,
                left,
                messages,
            }) => LinkEvent::Note(describe_unlisted(joined, left, messages)),
            Notice::Client(ClientEvent::UdpWorking(working)) => LinkEvent::Note(if working {
                "voice goes by UDP".into()
            } else {
                "voice goes through the TLS tunnel (UDP not working)".into()
            }),
        })
    }

    fn end(&mut self, reason: String) -> LinkEvent {
        self.ended = Some(reason.clone());
        LinkEvent::Over { reason }
    }
}

impl Link for MumbleLink {
    fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) {
        if let Some(c) = self.connection() {
            c.pull(now, out);
        }
        self.heard |= !out.is_empty();
    }

    fn peers(&self) -> Vec<PeerInfo> {
        let Some(c) = self.connection() else {
            return Vec::new();
        };
        let server = c.address();
        c.speakers()
            .into_iter()
            .map(|(session, name, receiver, left)| PeerInfo {
                id: PeerId::Mumble(session),
                addr: server,
                cname: None,
                name: Some(name),
                receiver,
                rtt_ms: None,
                their_loss: None,
                said_bye: left,
                ended: left,
            })
            .collect()
    }

    fn silent_members(&self) -> Vec<PeerInfo> {
        let Some(c) = self.connection() else {
            return Vec::new();
        };
        let members = c.members();
        let Some(ours) = members.iter().find(|m| m.us).map(|m| m.channel) else {
            return Vec::new();
        };
        let spoke: Vec<u32> = c.speakers().iter().map(|s| s.0).collect();
        members
            .into_iter()
            .filter(|m| !m.us && m.channel == ours && !spoke.contains(&m.session))
            .map(|m| PeerInfo {
                id: PeerId::Mumble(m.session),
                addr: c.address(),
                cname: None,
                name: Some(m.name),
                receiver: Default::default(),
                rtt_ms: None,
                their_loss: None,
                said_bye: false,
                ended: false,
            })
            .collect()
    }

    /// Everyone who spoke has left, or the call is over.
    fn all_left(&self) -> bool {
        self.over()
            || (self.heard
                && self
                    .connection()
                    .is_some_and(|c| c.speakers().iter().all(|s| s.3)))
    }

    /// Removed, the server no longer the one trusted, the join failed, or left.
    fn over(&self) -> bool {
        self.ended.is_some() || matches!(self.stage, Stage::Gone)
    }

    fn send_audio(&mut self, payload: &[u8], ticks: u32) {
        if let Some(c) = self.connection()
            && let Err(e) = c.send_voice(payload, ticks)
        {
            tracing::debug!("send to Mumble: {e}");
        }
    }

    fn skip_frames(&mut self, frames: u32) {
        if let Some(c) = self.connection() {
            c.skip_frames(frames);
        }
    }

    fn unknown_payload(&self) -> u64 {
        self.connection().map_or(0, |c| c.stats().other_codec)
    }

    /// Disconnects. A join still running finishes on its own thread, and its connection
    /// closes as it is dropped there.
    fn leave(&mut self) {
        if let Stage::In(mut connection) = std::mem::replace(&mut self.stage, Stage::Gone) {
            connection.close();
        }
    }

    fn poll(&mut self) -> Vec<LinkEvent> {
        let mut events: Vec<LinkEvent> = self.follow_join().into_iter().collect();
        let notices = match self.connection() {
            Some(c) => c.poll(),
            None => Vec::new(),
        };
        events.extend(notices.into_iter().filter_map(|n| self.event(n)));
        events
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mumble_addresses_are_read() {
        assert!(is_mumble_url("mumble://127.0.0.1"));
        assert!(!is_mumble_url("127.0.0.1:64738"));
        assert_eq!(
            parse_mumble_url("mumble://h.example:1234/Lobby"),
            Some(("h.example:1234".into(), Some("Lobby".into())))
        );
        assert_eq!(
            parse_mumble_url("mumble://ann@h.example/"),
            Some(("h.example".into(), None))
        );
        assert_eq!(parse_mumble_url("mumble:///x"), None);
    }
}
