//! A channel on a Mumble server as a call's [`Link`]: each user who speaks there (a Mumble
//! session id) is a peer with the user's name, received through the same jitter buffer and
//! Opus decoder as every other transport ([`crate::net::mumble`]).

use std::net::SocketAddr;
use std::time::Instant;

use super::link::{Link, LinkEvent};
use crate::net::mumble::client::ClientEvent;
use crate::net::mumble::connection::{Connection, Notice};
use crate::net::mumble::events::describe_unlisted;
use crate::net::session::{PeerFrame, PeerInfo};

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

/// Our membership of a Mumble server's channel.
pub struct MumbleLink {
    connection: Connection,
    /// The server's address, shown as every speaker's.
    server: SocketAddr,
    place: String,
    /// Someone spoke at some point.
    heard: bool,
    /// What the server said that is no [`LinkEvent`] (refusals, text messages, UDP state).
    notes: Vec<String>,
    /// The server removed us: why (the call is over).
    removed: Option<String>,
    /// The server came back with another certificate: why (the call is over).
    untrusted: Option<String>,
}

impl MumbleLink {
    /// Around a connection already joined.
    pub fn joined(connection: Connection, place: String) -> Self {
        let server = connection.address();
        Self {
            connection,
            server,
            place,
            heard: false,
            notes: Vec::new(),
            removed: None,
            untrusted: None,
        }
    }

    pub fn connection(&self) -> &Connection {
        &self.connection
    }

    pub fn place(&self) -> &str {
        &self.place
    }

    /// Why the server removed us, if it did.
    pub fn removed(&self) -> Option<&str> {
        self.removed.as_deref()
    }

    /// Why the call ended on a server that is no longer the one trusted, if it did.
    pub fn untrusted(&self) -> Option<&str> {
        self.untrusted.as_deref()
    }

    /// What the server said since the last call that no [`LinkEvent`] carries.
    pub fn take_notes(&mut self) -> Vec<String> {
        std::mem::take(&mut self.notes)
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
                self.removed = Some(reason.clone());
                LinkEvent::Failed(format!("the Mumble server removed us: {reason}"))
            }
            Notice::Untrusted(reason) => {
                let reason = format!("{reason}; not reconnecting");
                self.untrusted = Some(reason.clone());
                LinkEvent::Failed(reason)
            }
            Notice::Client(ClientEvent::Synced { .. }) => return None,
            Notice::Client(ClientEvent::Rejected(reason)) => {
                self.notes.push(format!("the server refused us: {reason}"));
                return None;
            }
            Notice::Client(ClientEvent::Denied(reason)) => {
                self.notes.push(format!("the server refused: {reason}"));
                return None;
            }
            Notice::Client(ClientEvent::Text { from, message }) => {
                self.notes.push(format!("{from} says: {message}"));
                return None;
            }
            Notice::Client(ClientEvent::Unlisted {
                joined,
                left,
                messages,
            }) => {
                self.notes.push(describe_unlisted(joined, left, messages));
                return None;
            }
            Notice::Client(ClientEvent::UdpWorking(working)) => {
                self.notes.push(if working {
                    "voice goes by UDP".into()
                } else {
                    "voice goes through the TLS tunnel (UDP not working)".into()
                });
                return None;
            }
        })
    }
}

impl Link for MumbleLink {
    fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) {
        self.connection.pull(now, out);
        self.heard |= !out.is_empty();
    }

    fn peers(&self) -> Vec<PeerInfo> {
        self.connection
            .speakers()
            .into_iter()
            .map(|(session, name, receiver, left)| PeerInfo {
                ssrc: session,
                addr: self.server,
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
        let members = self.connection.members();
        let Some(ours) = members.iter().find(|m| m.us).map(|m| m.channel) else {
            return Vec::new();
        };
        let spoke: Vec<u32> = self.connection.speakers().iter().map(|s| s.0).collect();
        members
            .into_iter()
            .filter(|m| !m.us && m.channel == ours && !spoke.contains(&m.session))
            .map(|m| PeerInfo {
                ssrc: m.session,
                addr: self.server,
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

    /// Everyone who spoke has left, or we were removed.
    fn all_left(&self) -> bool {
        self.over() || (self.heard && self.connection.speakers().iter().all(|s| s.3))
    }

    /// Removed, or the server is no longer the one trusted.
    fn over(&self) -> bool {
        self.removed.is_some() || self.untrusted.is_some()
    }

    fn send_frames(&mut self, payload: &[u8], frames: u32) {
        if let Err(e) = self.connection.send_voice(payload, frames) {
            tracing::debug!("send to Mumble: {e}");
        }
    }

    fn skip_frames(&mut self, frames: u32) {
        self.connection.skip_frames(frames);
    }

    fn unknown_payload(&self) -> u64 {
        self.connection.stats().other_codec
    }

    fn leave(&mut self) {
        self.connection.close();
    }

    fn poll(&mut self) -> Vec<LinkEvent> {
        let notices = self.connection.poll();
        notices.into_iter().filter_map(|n| self.event(n)).collect()
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
