//! What a Mumble client is configured with and what it reports, and how much of a server's
//! news is said one by one.

use std::time::{Duration, Instant};

use super::messages::RejectType;
use crate::net::jitter::JitterConfig;

/// Pieces of news (someone coming into our channel or leaving it, a message, a refusal) said
/// one by one in a [`NEWS_WINDOW`]; beyond them a server's news is counted, and the counts said
/// once a window ([`ClientEvent::Unlisted`]).
pub const NEWS_PER_WINDOW: u32 = 40;
pub const NEWS_WINDOW: Duration = Duration::from_secs(10);

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
    /// News beyond [`NEWS_PER_WINDOW`], not said one by one: how many came into our channel,
    /// left it, and how many messages and refusals there were, since the last such count.
    Unlisted {
        joined: u64,
        left: u64,
        messages: u64,
    },
}

/// [`ClientEvent::Unlisted`]'s counts in words.
pub fn describe_unlisted(joined: u64, left: u64, messages: u64) -> String {
    let parts: Vec<String> = [
        (joined, "more came into the channel"),
        (left, "more left it"),
        (messages, "more messages or refusals"),
    ]
    .iter()
    .filter(|(n, _)| *n > 0)
    .map(|(n, what)| format!("{n} {what}"))
    .collect();
    format!(
        "the server's news came too fast to list one by one: {}",
        parts.join(", ")
    )
}

/// What kind of news a [`NewsBudget`] is asked about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum News {
    Joined,
    Left,
    Message,
}

/// How much news is said one by one: [`NEWS_PER_WINDOW`] pieces a window, the rest counted.
#[derive(Debug, Default)]
pub(super) struct NewsBudget {
    window: Option<Instant>,
    said: u32,
    summed_up: bool,
    joined: u64,
    left: u64,
    messages: u64,
}

impl NewsBudget {
    fn roll(&mut self, now: Instant) {
        if self.window.is_none_or(|w| now >= w + NEWS_WINDOW) {
            self.window = Some(now);
            self.said = 0;
            self.summed_up = false;
        }
    }

    /// Whether a piece of news is said now (else it is counted).
    pub(super) fn say(&mut self, news: News, now: Instant) -> bool {
        self.roll(now);
        if self.said < NEWS_PER_WINDOW {
            self.said += 1;
            return true;
        }
        match news {
            News::Joined => self.joined += 1,
            News::Left => self.left += 1,
            News::Message => self.messages += 1,
        }
        false
    }

    /// The counts of what was not said, at most once a window.
    pub(super) fn unlisted(&mut self, now: Instant) -> Option<ClientEvent> {
        self.roll(now);
        if self.summed_up || self.joined + self.left + self.messages == 0 {
            return None;
        }
        self.summed_up = true;
        Some(ClientEvent::Unlisted {
            joined: std::mem::take(&mut self.joined),
            left: std::mem::take(&mut self.left),
            messages: std::mem::take(&mut self.messages),
        })
    }
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
    /// Users, channels and speakers beyond the client's caps, not kept (voice of a speaker
    /// beyond them is dropped).
    pub over_cap: u64,
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
        Some(RejectType::WrongServerPw) => {
            "wrong server password (set LIPCALL_MUMBLE_PASSWORD or give --password-file)"
        }
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
