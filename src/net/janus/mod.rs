//! Rooms on a Janus WebRTC server (its VideoRoom plugin), beside lipcall's own relay.
//!
//! Janus forwards each publisher's Opus stream to every subscriber unmixed, so each remote
//! speaker stays a peer of its own with its own lip sync. The media is WebRTC: ICE, DTLS-SRTP
//! and RTCP through str0m, which is sans-I/O and driven by our own UDP thread
//! ([`media`]), offering the addresses [`candidates`] gathers. Signalling is Janus's API over HTTP(S) or its WebSocket ([`http`], `ws`),
//! at a URL [`url`] takes apart, carrying the VideoRoom requests
//! ([`messages`]); [`room`] puts the two together.
//!
//! DTLS-SRTP is hop by hop: Janus decrypts every stream it forwards and could read it, unlike
//! lipcall's end-to-end SRTP rooms, whose relay cannot.

pub mod candidates;
mod events;
pub mod feeds;
pub mod http;
pub mod media;
pub mod messages;
pub mod room;
pub mod url;
mod ws;

/// Everything a Janus room can fail with.
#[derive(Debug, thiserror::Error)]
pub enum JanusError {
    #[error("cannot reach Janus at {url}: {reason}")]
    Http { url: String, reason: String },
    #[error("{url} answers, but not as Janus does ({reason}): is it Janus's HTTP API?")]
    NotJanus { url: String, reason: String },
    #[error("Janus error {code}: {reason}")]
    Janus { code: i64, reason: String },
    #[error("Janus VideoRoom error {code}: {reason}")]
    Plugin { code: i64, reason: String },
    #[error(
        "this Janus numbers its rooms (its VideoRoom has string_ids = false), so the room \
         {room:?} cannot be named: give a positive number, e.g. --room 1234 (Janus said: {reason})"
    )]
    RoomIds { room: String, reason: String },
    #[error("unexpected answer from Janus: {0}")]
    Protocol(String),
    #[error("{0}")]
    Timeout(String),
    #[error("lost the Janus session: {0}")]
    Lost(String),
    #[error("WebRTC: {0}")]
    Media(String),
}
