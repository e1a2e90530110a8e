//! One lipcall member of a Janus VideoRoom: joins as a publisher (display name = our name, pin
//! = the room passphrase), creating the room when it does not exist yet, publishes our Opus
//! stream when asked, and subscribes to every other publisher (one subscription each, so a
//! publisher joining or leaving renegotiates nothing else).

use std::collections::HashMap;
use std::net::{SocketAddr, ToSocketAddrs};
use std::time::{Duration, Instant};

use serde_json::Value;

use super::JanusError;
use super::http::Client;
use super::media::{FeedInfo, Media, MediaStats, host_ips};
use super::messages::{self, INVALID_ELEMENT, IdKind, NO_SUCH_ROOM, ROOM_EXISTS, VIDEOROOM};
use crate::net::jitter::JitterConfig;
use crate::net::session::PeerFrame;

#[derive(Debug, Clone)]
pub struct RoomConfig {
    /// Janus's HTTP API, `http://host:8088/janus`.
    pub url: String,
    pub room: String,
    /// Display name in the room.
    pub name: String,
    /// The room's pin (lipcall's room passphrase); a new room gets it.
    pub pin: Option<String>,
    /// Subscribe to the other publishers (a receiver does; a send-only member need not).
    pub subscribe: bool,
    pub jitter: JitterConfig,
}

/// Something that happened in the room, for the user.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Notice {
    Joined {
        feed: String,
        name: String,
    },
    Left {
        feed: String,
        name: String,
    },
    /// The Janus session is gone (Janus restarted or unreachable); rejoining.
    Lost {
        reason: String,
    },
    /// A rejoin attempt failed (said once per distinct reason).
    RejoinFailed {
        reason: String,
    },
    /// In the room again, with this publisher id.
    Rejoined {
        id: String,
    },
}

pub struct Room {
    client: Client,
    media: Media,
    config: RoomConfig,
    handle: u64,
    /// How this server numbers rooms and feeds, and our room as it wants it.
    ids: IdKind,
    room_id: Value,
    id: String,
    private_id: Option<Value>,
    /// Subscription handle per publisher id.
    subscriptions: HashMap<String, (u64, String)>,
}

impl std::fmt::Debug for Room {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Room")
            .field("room", &self.config.room)
            .field("id", &self.id)
            .finish_non_exhaustive()
    }
}

/// The host part of an `http://host:port/path` URL.
fn url_host(url: &str) -> Option<(String, u16)> {
    let rest = url.strip_prefix("http://")?;
    let authority = rest.split('/').next()?;
    match authority.rsplit_once(':') {
        Some((host, port)) if !host.ends_with(']') || host.starts_with('[') => Some((
            host.trim_matches(['[', ']']).to_string(),
            port.parse().ok()?,
        )),
        _ => Some((authority.to_string(), 80)),
    }
}

/// Where the Janus server of an `http://HOST:PORT/janus` URL is.
pub fn server_addr(url: &str) -> Result<SocketAddr, JanusError> {
    let (host, port) = url_host(url).ok_or_else(|| JanusError::Http {
        url: url.to_string(),
        reason: "expected an http://HOST:PORT/janus URL".into(),
    })?;
    (host.as_str(), port)
        .to_socket_addrs()
        .ok()
        .and_then(|mut a| a.next())
        .ok_or_else(|| JanusError::Http {
            url: url.to_string(),
            reason: format!("cannot resolve {host}"),
        })
}

impl Room {
    /// Connects to Janus and joins the room, creating it if it does not exist.
    pub fn join(config: RoomConfig) -> Result<(Self, Vec<Notice>), JanusError> {
        let janus_ip = server_addr(&config.url)?.ip();
        let mut client = Client::connect(&config.url)?;
        let handle = client.attach(VIDEOROOM)?;
        let (ids, room_id, joined) = join_as_numbered(&mut client, handle, &config)?;
        let data = messages::plugin_data(&joined)?;
        let id = messages::id_string(&data["id"])
            .ok_or_else(|| JanusError::Protocol(format!("no publisher id in {data}")))?;
        let private_id = (!data["private_id"].is_null()).then(|| data["private_id"].clone());
        let news = messages::room_news(data);
        let media = Media::start(&host_ips(janus_ip)?, config.jitter)?;
        let mut room = Self {
            client,
            media,
            config,
            handle,
            ids,
            room_id,
            id,
            private_id,
            subscriptions: HashMap::new(),
        };
        let mut notices = Vec::new();
        room.apply(news, &mut notices)?;
        Ok((room, notices))
    }

    /// Our publisher id in the room.
    pub fn id(&self) -> &str {
        &self.id
    }

    /// Publishes our audio: offer, Janus's answer, then ICE and DTLS on the media thread.
    pub fn publish(&mut self) -> Result<(), JanusError> {
        let offer = self.media.publish_offer()?;
        let reply = self.client.call(
            self.handle,
            messages::publish(&self.config.name),
            Some(("offer", &offer)),
        )?;
        let answer = messages::jsep_sdp(&reply, "answer")
            .ok_or_else(|| JanusError::Protocol("Janus answered the publish without SDP".into()))?;
        tracing::debug!("publish offer:\n{offer}\nJanus's answer:\n{answer}");
        self.media.publish_answer(answer)?;
        self.client.trickle_completed(self.handle)
    }

    /// Waits until our published stream is connected (ICE and DTLS done).
    pub fn wait_published(&self, timeout: Duration) -> Result<(), JanusError> {
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            let stats = self.media.stats();
            if stats.publisher_connected {
                return Ok(());
            }
            if let Some(reason) = stats.failed {
                return Err(JanusError::Media(reason.into()));
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let stats = self.media.stats();
        Err(JanusError::Timeout(format!(
            "the WebRTC connection to Janus did not come up within {} s ({} datagrams sent, {} \
             received)",
            timeout.as_secs(),
            stats.sent,
            stats.datagrams
        )))
    }

    pub fn send(&self, payload: &[u8], ticks: u32) -> Result<(), JanusError> {
        self.media.send(payload, ticks)
    }

    /// Moves our stream's clock on by `ticks` without sending (a silent gap).
    pub fn skip(&self, ticks: u32) {
        self.media.skip(ticks);
    }

    /// Follows the room: subscribes to new publishers, lets those who left play out.
    pub fn poll(&mut self) -> Result<Vec<Notice>, JanusError> {
        let mut notices = Vec::new();
        while let Some(event) = self.client.next_event()? {
            if event["janus"] != "event" || event["sender"] != self.handle {
                continue;
            }
            let Ok(data) = messages::plugin_data(&event) else {
                continue;
            };
            let news = messages::room_news(data);
            self.apply(news, &mut notices)?;
        }
        Ok(notices)
    }

    fn apply(
        &mut self,
        news: messages::RoomNews,
        notices: &mut Vec<Notice>,
    ) -> Result<(), JanusError> {
        for gone in news.gone {
            if let Some((handle, name)) = self.subscriptions.remove(&gone) {
                self.media.feed_left(&gone);
                // Janus may have hung it up already; the handle goes either way.
                let _ = self.client.detach(handle);
                notices.push(Notice::Left { feed: gone, name });
            }
        }
        if !self.config.subscribe {
            return Ok(());
        }
        for p in news.publishers {
            if p.id == self.id || self.subscriptions.contains_key(&p.id) {
                continue;
            }
            let handle = self.subscribe(&p.id, &p.display)?;
            self.subscriptions
                .insert(p.id.clone(), (handle, p.display.clone()));
            notices.push(Notice::Joined {
                feed: p.id,
                name: p.display,
            });
        }
        Ok(())
    }

    fn subscribe(&mut self, feed: &str, name: &str) -> Result<u64, JanusError> {
        let feed_id = self.ids.id(feed).ok_or_else(|| {
            JanusError::Protocol(format!(
                "publisher id {feed:?} is not a number in a room numbered by Janus"
            ))
        })?;
        let handle = self.client.attach(VIDEOROOM)?;
        let body = messages::join_subscriber(
            &self.room_id,
            &feed_id,
            self.private_id.as_ref(),
            self.config.pin.as_deref(),
        );
        let attached = self.client.call(handle, body, None)?;
        let offer = messages::jsep_sdp(&attached, "offer").ok_or_else(|| {
            JanusError::Protocol(format!("Janus sent no SDP offer for {name} ({feed})"))
        })?;
        let answer = self.media.subscribe(feed, name, offer)?;
        self.client
            .call(handle, messages::start(), Some(("answer", &answer)))?;
        self.client.trickle_completed(handle)?;
        Ok(handle)
    }

    pub fn pull(&self, now: Instant, out: &mut Vec<PeerFrame>) {
        self.media.pull(now, out);
    }

    pub fn feeds(&self) -> Vec<FeedInfo> {
        self.media.feeds()
    }

    pub fn media_stats(&self) -> MediaStats {
        self.media.stats()
    }

    /// Hangs up (DTLS close, RTCP BYE) and destroys the Janus session, which takes us out of
    /// the room.
    pub fn leave(mut self) -> Result<(), JanusError> {
        self.media.close();
        self.client.destroy()
    }
}

/// Joins `config.room` as a publisher, creating it where it does not exist, with the room id as
/// the server numbers rooms: a number where the room is one and the server takes numbers,
/// else a string; a name on a server that numbers rooms is a clear error.
fn join_as_numbered(
    client: &mut Client,
    handle: u64,
    config: &RoomConfig,
) -> Result<(IdKind, Value, Value), JanusError> {
    let first = IdKind::guess(&config.room);
    let mut ids = first;
    loop {
        let room_id = ids
            .id(&config.room)
            .ok_or_else(|| JanusError::Protocol("empty room id".into()))?;
        match join_or_create(client, handle, config, &room_id) {
            Err(JanusError::Plugin { code, .. })
                if code == INVALID_ELEMENT && ids == IdKind::Numbers =>
            {
                ids = IdKind::Strings;
            }
            Err(JanusError::Plugin { code, reason })
                if code == INVALID_ELEMENT && first == IdKind::Strings =>
            {
                return Err(JanusError::RoomIds {
                    room: config.room.clone(),
                    reason,
                });
            }
            Ok(joined) => return Ok((ids, room_id, joined)),
            Err(e) => return Err(e),
        }
    }
}

fn join_or_create(
    client: &mut Client,
    handle: u64,
    config: &RoomConfig,
    room: &Value,
) -> Result<Value, JanusError> {
    let pin = config.pin.as_deref();
    let join = || messages::join_publisher(room, &config.name, pin);
    match client.call(handle, join(), None) {
        Err(JanusError::Plugin { code, .. }) if code == NO_SUCH_ROOM => {
            match client.request(handle, messages::create_room(room, pin)) {
                Ok(_) => {}
                // Someone else created it in between.
                Err(JanusError::Plugin { code, .. }) if code == ROOM_EXISTS => {}
                Err(e) => return Err(e),
            }
            client.call(handle, join(), None)
        }
        other => other,
    }
}

/// A room membership that outlives its Janus session: when the session is lost (Janus
/// restarted, or unreachable for longer than its session timeout) it says so and rejoins every
/// second until Janus answers, publishing again if it published. Audio sent while away is
/// dropped; the subscriptions are made afresh (new peers, as after a real departure).
pub struct Member {
    config: RoomConfig,
    publish: bool,
    room: Option<Room>,
    retry_at: Instant,
    last_failure: Option<String>,
    /// Packets published in rooms lost since.
    published_before: u64,
}

impl std::fmt::Debug for Member {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Member")
            .field("room", &self.room)
            .finish_non_exhaustive()
    }
}

const REJOIN_EVERY: Duration = Duration::from_secs(1);
const PUBLISH_TIMEOUT: Duration = Duration::from_secs(10);

impl Member {
    /// Joins (and publishes, when `publish`); a first join that fails is an error.
    pub fn join(config: RoomConfig, publish: bool) -> Result<(Self, Vec<Notice>), JanusError> {
        let (room, notices) = Self::enter(&config, publish)?;
        Ok((
            Self {
                config,
                publish,
                room: Some(room),
                retry_at: Instant::now(),
                last_failure: None,
                published_before: 0,
            },
            notices,
        ))
    }

    fn enter(config: &RoomConfig, publish: bool) -> Result<(Room, Vec<Notice>), JanusError> {
        let (mut room, notices) = Room::join(config.clone())?;
        if publish {
            room.publish()?;
            room.wait_published(PUBLISH_TIMEOUT)?;
        }
        Ok((room, notices))
    }

    /// Our publisher id, while in the room.
    pub fn id(&self) -> Option<&str> {
        self.room.as_ref().map(Room::id)
    }

    /// Follows the room; on a lost session, leaves it and rejoins when Janus answers.
    pub fn poll(&mut self) -> Vec<Notice> {
        let mut notices = Vec::new();
        if let Some(room) = &mut self.room {
            match room.poll() {
                Ok(n) => notices = n,
                Err(e) => {
                    notices.push(Notice::Lost {
                        reason: e.to_string(),
                    });
                    if let Some(room) = self.room.take() {
                        self.published_before += room.media_stats().published;
                        let _ = room.leave();
                    }
                    self.retry_at = Instant::now();
                }
            }
        }
        if self.room.is_none() && Instant::now() >= self.retry_at {
            self.retry_at = Instant::now() + REJOIN_EVERY;
            match Self::enter(&self.config, self.publish) {
                Ok((room, n)) => {
                    notices.push(Notice::Rejoined {
                        id: room.id().to_string(),
                    });
                    notices.extend(n);
                    self.room = Some(room);
                    self.last_failure = None;
                }
                Err(e) => {
                    let reason = e.to_string();
                    if self.last_failure.as_ref() != Some(&reason) {
                        notices.push(Notice::RejoinFailed {
                            reason: reason.clone(),
                        });
                        self.last_failure = Some(reason);
                    }
                }
            }
        }
        notices
    }

    /// Sends one Opus payload; dropped while out of the room.
    pub fn send(&self, payload: &[u8], ticks: u32) -> Result<(), JanusError> {
        match &self.room {
            Some(room) => room.send(payload, ticks),
            None => Ok(()),
        }
    }

    /// Moves our stream's clock on by `ticks` without sending (a silent gap).
    pub fn skip(&self, ticks: u32) {
        if let Some(room) = &self.room {
            room.skip(ticks);
        }
    }

    pub fn pull(&self, now: Instant, out: &mut Vec<PeerFrame>) {
        if let Some(room) = &self.room {
            room.pull(now, out);
        }
    }

    /// The publishers of the current session (none while out of the room).
    pub fn feeds(&self) -> Vec<FeedInfo> {
        self.room.as_ref().map(Room::feeds).unwrap_or_default()
    }

    pub fn in_room(&self) -> bool {
        self.room.is_some()
    }

    /// The current session's media counters, `published` counting every session's.
    pub fn media_stats(&self) -> MediaStats {
        let mut stats = self
            .room
            .as_ref()
            .map(Room::media_stats)
            .unwrap_or_default();
        stats.published += self.published_before;
        stats
    }

    pub fn leave(self) -> Result<(), JanusError> {
        match self.room {
            Some(room) => room.leave(),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn janus_urls_name_their_host() {
        assert_eq!(
            url_host("http://127.0.0.1:8088/janus"),
            Some(("127.0.0.1".into(), 8088))
        );
        assert_eq!(
            url_host("http://janus.example/janus"),
            Some(("janus.example".into(), 80))
        );
        assert_eq!(
            url_host("http://[::1]:8088/janus"),
            Some(("::1".into(), 8088))
        );
        assert_eq!(url_host("https://x/janus"), None);
    }

    #[test]
    fn the_server_address_comes_from_the_url() {
        assert_eq!(
            server_addr("http://127.0.0.1:8088/janus").unwrap(),
            SocketAddr::from(([127, 0, 0, 1], 8088))
        );
        assert_eq!(
            server_addr("http://127.0.0.1/janus").unwrap(),
            SocketAddr::from(([127, 0, 0, 1], 80))
        );
        assert_eq!(
            server_addr("http://[::1]:8088/janus").unwrap(),
            "[::1]:8088".parse().unwrap()
        );
        let e = server_addr("https://127.0.0.1:8089/janus").unwrap_err();
        assert!(e.to_string().contains("expected an http://"), "{e}");
    }
}
