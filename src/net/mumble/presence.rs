//! Who is where on the server: its channels, its users (each with the channel they are in and
//! whether they muted themselves), the events of people coming into and leaving our channel,
//! and our own state as others see it (our channel, our self-mute).
//!
//! The tables have caps ([`MAX_USERS`], [`MAX_CHANNELS`]); a removed user is forgotten at once.
//! Who came into our channel and who left is not queued per message but worked out when the
//! owner asks ([`ClientCore::report_presence`]): a server moving us back and forth between two
//! crowded channels costs one comparison per report, whatever it sent in between.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use super::client::ClientCore;
use super::events::{Channel, ClientEvent, Member, News};
use super::messages::{ChannelState, MessageType, UserState};
use crate::net::janus::messages::display_name;
use crate::net::peer::ReceiverStats;

/// The least time between two self-mute changes told to the server.
pub const SELF_MUTE_EVERY: Duration = Duration::from_millis(1100);
/// The most users kept (murmur's default is 100 users a server); others are not listed.
pub const MAX_USERS: usize = 10_000;
/// The most channels kept.
pub const MAX_CHANNELS: usize = 10_000;

impl ClientCore {
    pub(super) fn channel_state(&mut self, c: ChannelState) {
        let Some(id) = c.channel_id else {
            self.stats.malformed += 1;
            return;
        };
        if !self.channels.contains_key(&id) && self.channels.len() >= MAX_CHANNELS {
            self.stats.over_cap += 1;
            return;
        }
        let entry = self.channels.entry(id).or_insert(Channel {
            id,
            parent: None,
            name: String::new(),
        });
        if let Some(name) = c.name {
            entry.name = display_name(&name);
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
        let is_new = !self.users.contains_key(&session);
        if is_new && self.users.len() >= MAX_USERS {
            self.stats.over_cap += 1;
            return;
        }
        if is_new {
            self.speakers.reissued(session);
        }
        let user = self.users.entry(session).or_default();
        if let Some(name) = u.name {
            user.name = display_name(&name);
        }
        if let Some(channel) = u.channel_id {
            user.channel = channel;
        }
        if let Some(muted) = u.self_mute {
            user.self_mute = muted;
        }
        self.presence_changed = true;
    }

    pub(super) fn user_left(&mut self, session: u32, now: Instant) {
        if self.users.remove(&session).is_some() {
            self.presence_changed = true;
        }
        self.speakers.leave(session, now);
    }

    /// Who came into our channel and who left it since the last report, as events: the users
    /// there now against those reported. Beyond the news budget they are counted, and the
    /// counts said once a window.
    pub fn report_presence(&mut self, now: Instant) {
        if self.presence_changed && self.session.is_some() {
            self.presence_changed = false;
            let own = self.own_channel();
            let ours = self.session;
            let here: BTreeMap<u32, &str> = self
                .users
                .iter()
                .filter(|&(&s, u)| Some(s) != ours && u.channel == own)
                .map(|(&s, u)| (s, u.name.as_str()))
                .collect();
            let left: Vec<u32> = self
                .reported
                .keys()
                .filter(|s| !here.contains_key(s))
                .copied()
                .collect();
            let joined: Vec<(u32, String)> = here
                .iter()
                .filter(|(s, _)| !self.reported.contains_key(s))
                .map(|(&s, &name)| (s, name.to_string()))
                .collect();
            for session in left {
                let name = self.reported.remove(&session).unwrap_or_default();
                if self.news.say(News::Left, now) {
                    self.events
                        .push_back(ClientEvent::UserLeft { session, name });
                }
            }
            for (session, name) in joined {
                self.reported.insert(session, name.clone());
                if self.news.say(News::Joined, now) {
                    self.events
                        .push_back(ClientEvent::UserJoined { session, name });
                }
            }
        }
        if let Some(counts) = self.news.unlisted(now) {
            self.events.push_back(counts);
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
        let away = |s: u32| self.users.get(&s).is_none_or(|u| u.channel != own);
        let (departed, _) = self.speakers.departed();
        let earlier = departed
            .iter()
            .map(|(s, name, stats)| (*s, name.clone(), *stats, true));
        let live = self.speakers.live().map(|(s, speaker)| {
            let left = speaker.left.is_some() || away(s);
            (s, speaker.name.clone(), speaker.stats(), left)
        });
        let let_go = self.users.iter().filter_map(|(&s, u)| {
            let heard = u.heard.as_deref()?;
            Some((s, u.name.clone(), *heard, away(s)))
        });
        earlier.chain(live).chain(let_go).collect()
    }

    /// Speakers who left and are no longer listed by [`Self::speakers`].
    pub fn speakers_unlisted(&self) -> u64 {
        self.speakers.departed().1
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
