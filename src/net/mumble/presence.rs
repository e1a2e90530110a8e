//! Who is where on the server: its channels, its users (each with the channel they are in and
//! whether they muted themselves), the events of people coming into and leaving our channel,
//! and our own state as others see it (our channel, our self-mute).

use std::time::{Duration, Instant};

use super::client::ClientCore;
use super::events::{Channel, ClientEvent, Member};
use super::messages::{ChannelState, MessageType, UserState};
use crate::net::peer::ReceiverStats;

/// The least time between two self-mute changes told to the server.
pub const SELF_MUTE_EVERY: Duration = Duration::from_millis(1100);

impl ClientCore {
    pub(super) fn channel_state(&mut self, c: ChannelState) {
        let Some(id) = c.channel_id else {
            self.stats.malformed += 1;
            return;
        };
        let entry = self.channels.entry(id).or_insert(Channel {
            id,
            parent: None,
            name: String::new(),
        });
        if let Some(name) = c.name {
            entry.name = name;
        }
        if c.parent.is_some() {
            entry.parent = c.parent;
        }
    }

    pub(super) fn own_channel(&self) -> u32 {
        self.session
            .and_then(|s| self.users.get(&s))
            .map_or(0, |u| u.channel)
    }

    pub(super) fn channel_name(&self, id: u32) -> String {
        self.channels
            .get(&id)
            .map_or_else(|| format!("channel {id}"), |c| c.name.clone())
    }

    pub(super) fn user_state(&mut self, u: UserState, _now: Instant) {
        let Some(session) = u.session else {
            self.stats.malformed += 1;
            return;
        };
        let own = self.own_channel();
        let is_new = self.users.get(&session).is_none_or(|u| u.gone);
        let user = self.users.entry(session).or_default();
        user.gone = false;
        let was_in = !is_new && user.channel == own;
        if let Some(name) = u.name {
            user.name = name;
        }
        if let Some(channel) = u.channel_id {
            user.channel = channel;
        } else if is_new {
            user.channel = 0;
        }
        if let Some(muted) = u.self_mute {
            user.self_mute = muted;
        } else if is_new {
            user.self_mute = false;
        }
        let (name, channel) = (user.name.clone(), user.channel);
        let Some(ours) = self.session else {
            // Still joining: who is there is told once we know which user we are.
            return;
        };
        if session == ours {
            if channel != own {
                self.moved(own, channel);
            }
            return;
        }
        let is_in = channel == own;
        if is_in && !was_in {
            self.events
                .push_back(ClientEvent::UserJoined { session, name });
        } else if was_in && !is_in {
            self.events
                .push_back(ClientEvent::UserLeft { session, name });
        }
    }

    /// We moved from channel `from` to `to`: those there joined us, those left behind left.
    fn moved(&mut self, from: u32, to: u32) {
        let ours = self.session;
        for (&session, user) in &self.users {
            if Some(session) == ours || user.gone {
                continue;
            }
            let name = user.name.clone();
            if user.channel == from {
                self.events
                    .push_back(ClientEvent::UserLeft { session, name });
            } else if user.channel == to {
                self.events
                    .push_back(ClientEvent::UserJoined { session, name });
            }
        }
    }

    /// Everyone in our channel once we know who we are.
    pub(super) fn present(&mut self) {
        let own = self.own_channel();
        let ours = self.session;
        for (&session, user) in &self.users {
            if Some(session) != ours && !user.gone && user.channel == own {
                self.events.push_back(ClientEvent::UserJoined {
                    session,
                    name: user.name.clone(),
                });
            }
        }
    }

    pub(super) fn user_left(&mut self, session: u32) {
        if let Some(user) = self.users.get_mut(&session) {
            user.gone = true;
            let name = user.name.clone();
            if Some(session) != self.session {
                self.events
                    .push_back(ClientEvent::UserLeft { session, name });
            }
        }
    }

    /// The name of the channel we are in, once joined.
    pub fn current_channel(&self) -> Option<String> {
        self.session?;
        Some(self.channel_name(self.own_channel()))
    }

    pub fn channels(&self) -> Vec<Channel> {
        self.channels.values().cloned().collect()
    }

    /// Moves us to channel `id` (and back there after a reconnect).
    pub fn join_channel(&mut self, id: u32) {
        if let Some(c) = self.channels.get(&id) {
            self.config.channel = Some(c.name.clone());
        }
        if let Some(session) = self.session {
            self.push(
                MessageType::UserState,
                &UserState {
                    session: Some(session),
                    channel_id: Some(id),
                    ..Default::default()
                },
            );
        }
    }

    /// Every user who has spoken (on this connection and earlier ones): session, name,
    /// reception, whether they left.
    pub fn speakers(&self) -> Vec<(u32, String, ReceiverStats, bool)> {
        let own = self.own_channel();
        let earlier = self
            .departed
            .iter()
            .map(|(s, name, stats)| (*s, name.clone(), *stats, true));
        let now = self.users.iter().filter_map(|(&s, u)| {
            let stats = u.stats()?;
            Some((s, u.name.clone(), stats, u.gone || u.channel != own))
        });
        earlier.chain(now).collect()
    }

    /// The name of a user we know.
    pub fn user_name(&self, session: u32) -> Option<&str> {
        self.users.get(&session).map(|u| u.name.as_str())
    }

    /// Says to the server whether we muted ourselves (Mumble's self-mute, shown to everyone);
    /// said again after a reconnect. Only a change is sent, and changes are paced: a server
    /// drops state changes that come faster than its message limit (murmur's default: a burst
    /// of 5, then one a second), and push-to-talk changes it with every press, so what goes
    /// out is the latest state, at most once every [`SELF_MUTE_EVERY`] ([`Self::wake`] sends
    /// one held back).
    pub fn set_self_mute(&mut self, muted: bool, now: Instant) {
        self.self_mute = Some(muted);
        self.tell_self_mute(now, false);
    }

    /// Tells the server our self-mute if it was told otherwise (or, `again`, whatever it was
    /// told: after a reconnect), unless it was told within [`SELF_MUTE_EVERY`].
    pub(super) fn tell_self_mute(&mut self, now: Instant, again: bool) {
        let (Some(session), Some(muted)) = (self.session, self.self_mute) else {
            return;
        };
        if !again
            && let Some((told, at)) = self.self_mute_told
            && (told == muted || now < at + SELF_MUTE_EVERY)
        {
            return;
        }
        self.push(
            MessageType::UserState,
            &UserState {
                session: Some(session),
                self_mute: Some(muted),
                ..Default::default()
            },
        );
        self.self_mute_told = Some((muted, now));
    }

    /// When a self-mute change held back is due.
    pub(super) fn self_mute_due(&self) -> Option<Instant> {
        let (muted, (told, at)) = (self.self_mute?, self.self_mute_told?);
        (muted != told).then_some(at + SELF_MUTE_EVERY)
    }

    /// Everyone on the server now (ourselves included), in session order.
    pub fn members(&self) -> Vec<Member> {
        self.users
            .iter()
            .filter(|(_, u)| !u.gone)
            .map(|(&session, u)| Member {
                session,
                name: u.name.clone(),
                channel: u.channel,
                self_mute: u.self_mute,
                us: Some(session) == self.session,
            })
            .collect()
    }
}
