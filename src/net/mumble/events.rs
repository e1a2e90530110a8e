//! What a Mumble client is configured with and what it reports.

use super::messages::RejectType;
use crate::net::jitter::JitterConfig;

#[derive(Debug, Clone)]
pub struct ClientConfig {
    pub name: String,
    pub password: Option<String>,
    /// The channel to move to after joining (the server's default channel otherwise).
    pub channel: Option<String>,
    pub jitter: JitterConfig,
    /// Never use UDP for voice: everything through the TLS stream.
    pub tcp_only: bool,
}

/// What happened, for the owner to show.
#[derive(Debug, Clone, PartialEq)]
pub enum ClientEvent {
    /// Joined as `session`, in `channel`.
    Synced {
        session: u32,
        channel: String,
        welcome: String,
    },
    /// The server turned us down; the connection is over.
    Rejected(String),
    /// The server removed us after the join (kicked, banned, or our name connected again from
    /// this address); the connection is over and not rejoined.
    Removed(String),
    /// Someone is in our channel (or came into it).
    UserJoined {
        session: u32,
        name: String,
    },
    /// Someone left our channel (or the server).
    UserLeft {
        session: u32,
        name: String,
    },
    /// The server refused something we asked (a channel move, ...).
    Denied(String),
    Text {
        from: String,
        message: String,
    },
    /// Voice now goes by UDP (`true`) or through the TLS tunnel.
    UdpWorking(bool),
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ClientStats {
    pub udp_received: u64,
    pub tunnel_received: u64,
    pub udp_sent: u64,
    pub tunnel_sent: u64,
    /// Datagrams that did not decrypt (bad tag, replay, no key yet).
    pub decrypt_failed: u64,
    /// Voice packets or control messages that did not parse.
    pub malformed: u64,
    /// Voice in a codec other than Opus (CELT, Speex), dropped.
    pub other_codec: u64,
    /// Fresh nonces asked of the server.
    pub resyncs: u64,
}

/// A channel of the server.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Channel {
    pub id: u32,
    pub parent: Option<u32>,
    pub name: String,
}

pub(super) fn describe_reject(kind: Option<i32>, reason: Option<&str>) -> String {
    let what = match kind.and_then(|k| RejectType::try_from(k).ok()) {
        Some(RejectType::WrongServerPw) => "wrong server password (give it with --password)",
        Some(RejectType::WrongUserPw) => "wrong password for this registered name",
        Some(RejectType::UsernameInUse) => "the name is in use: pick another with --name",
        Some(RejectType::InvalidUsername) => "the server does not accept this name",
        Some(RejectType::ServerFull) => "the server is full",
        Some(RejectType::WrongVersion) => "the server refuses our protocol version",
        Some(RejectType::NoCertificate) => "the server wants a registered certificate",
        Some(RejectType::AuthenticatorFail) => "the server's authenticator failed",
        Some(RejectType::None) | None => "refused",
    };
    match reason.filter(|r| !r.is_empty()) {
        Some(r) => format!("{what} ({r})"),
        None => what.to_string(),
    }
}

/// A user on the server, as the UI lists them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Member {
    pub session: u32,
    pub name: String,
    /// The channel they are in.
    pub channel: u32,
    /// They muted themselves.
    pub self_mute: bool,
    /// This is us.
    pub us: bool,
}
