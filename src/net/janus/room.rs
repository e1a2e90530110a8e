//! One lipcall member of a Janus VideoRoom: joins as a publisher (display name = our name, pin
//! = the room passphrase), creating the room when it does not exist yet, publishes our Opus
//! stream when asked, and subscribes to every other publisher (one subscription each, so a
//! publisher joining or leaving renegotiates nothing else).
//!
//! The signalling (HTTP requests that take up to seconds each) runs on a thread of its own;
//! the owner's 20 ms tick only pulls media and reads notices, so no Janus, however slow or
//! busy, holds up the audio, `--seconds` or a stop.

use std::collections::{HashMap, HashSet};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serde_json::Value;

use super::JanusError;
use super::candidates::{IceServers, host_ips};
use super::feeds::{FeedInfo, MediaStats};
use super::http::Client;
use super::media::Media;
use super::messages::{
    self, INVALID_ELEMENT, IdKind, JanusAuth, NO_SUCH_ROOM, ROOM_EXISTS, VIDEOROOM,
};
pub use super::url::server_addr;
use crate::net::jitter::JitterConfig;
use crate::net::transport::PeerFrame;

#[derive(Debug, Clone)]
pub struct RoomConfig {
    /// Janus's API, `http(s)://host:8088/janus`.
    pub url: String,
    /// What a Janus that restricts its API asks of every request.
    pub auth: JanusAuth,
    pub room: String,
    /// Display name in the room.
    pub name: String,
    /// The room's pin (lipcall's room passphrase); a new room gets it.
    pub pin: Option<String>,
    /// Subscribe to the other publishers (a receiver does; a send-only member need not).
    pub subscribe: bool,
    pub jitter: JitterConfig,
    /// STUN and TURN servers for the media's ICE.
    pub ice: IceServers,
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
    /// A publisher we cannot hear (no Opus in its stream, or its subscription failed).
    Skipped {
        feed: String,
        name: String,
        reason: String,
    },
}

pub struct Room {
    client: Client,
    media: Arc<Media>,
    config: RoomConfig,
    handle: u64,
    /// How this server numbers rooms and feeds, and our room as it wants it.
    ids: IdKind,
    room_id: Value,
    id: String,
    private_id: Option<Value>,
    /// Subscription handle per publisher id.
    subscriptions: HashMap<String, (u64, String)>,
    /// Publishers gone whose media is still to be told so, once their departure was said.
    departed: Vec<String>,
}

impl std::fmt::Debug for Room {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Room")
            .field("room", &self.config.room)
            .field("id", &self.id)
            .finish_non_exhaustive()
    }
}

impl Room {
    /// Connects to Janus and joins the room, creating it if it does not exist.
    pub fn join(config: RoomConfig) -> Result<(Self, Vec<Notice>), JanusError> {
        let janus_ip = server_addr(&config.url)?.ip();
        let mut client = Client::connect(&config.url, &config.auth)?;
        let handle = client.attach(VIDEOROOM)?;
        let (ids, room_id, joined) = join_as_numbered(&mut client, handle, &config)?;
        let data = messages::plugin_data(&joined)?;
        let id = messages::id_string(&data["id"])
            .ok_or_else(|| JanusError::Protocol(format!("no publisher id in {data}")))?;
        let private_id = (!data["private_id"].is_null()).then(|| data["private_id"].clone());
        let news = messages::room_news(data);
        let media = Arc::new(Media::start(
            &host_ips(janus_ip)?,
            config.jitter,
            &config.ice,
        )?);
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
            departed: Vec::new(),
        };
        let mut notices = Vec::new();
        room.apply(news, &mut notices, &AtomicBool::new(false))?;
        room.mark_departed();
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

    /// Follows the room: subscribes to new publishers, lets those who left play out. The
    /// events waiting are taken together, so a publisher that came and went in between is
    /// never subscribed to; `stop` ends it between subscriptions.
    pub fn poll(&mut self, stop: &AtomicBool) -> Result<Vec<Notice>, JanusError> {
        let mut news = messages::RoomNews::default();
        for _ in 0..EVENTS_PER_POLL {
            let Some(event) = self.client.next_event()? else {
                break;
            };
            if event["janus"] != "event" || event["sender"] != self.handle {
                continue;
            }
            let Ok(data) = messages::plugin_data(&event) else {
                continue;
            };
            let more = messages::room_news(data);
            news.publishers.retain(|p| !more.gone.contains(&p.id));
            news.publishers.extend(more.publishers);
            news.gone.extend(more.gone);
        }
        let mut notices = Vec::new();
        self.apply(news, &mut notices, stop)?;
        Ok(notices)
    }

    fn apply(
        &mut self,
        news: messages::RoomNews,
        notices: &mut Vec<Notice>,
        stop: &AtomicBool,
    ) -> Result<(), JanusError> {
        let gone: HashSet<String> = news.gone.iter().cloned().collect();
        for gone in news.gone {
            if let Some((handle, name)) = self.subscriptions.remove(&gone) {
                self.departed.push(gone.clone());
                // Janus may have hung it up already; the handle goes either way.
                let _ = self.client.detach(handle);
                notices.push(Notice::Left { feed: gone, name });
            }
        }
        if !self.config.subscribe {
            return Ok(());
        }
        for p in news.publishers {
            if stop.load(Ordering::Relaxed) {
                break;
            }
            if p.id == self.id || gone.contains(&p.id) || self.subscriptions.contains_key(&p.id) {
                continue;
            }
            let handle = self.client.attach(VIDEOROOM)?;
            match self.subscribe(handle, &p.id, &p.display) {
                Ok(()) => {
                    self.subscriptions
                        .insert(p.id.clone(), (handle, p.display.clone()));
                    notices.push(Notice::Joined {
                        feed: p.id,
                        name: p.display,
                    });
                }
                Err(e) if concerns_the_session(&e) => return Err(e),
                Err(e) => {
                    // Only this publisher is out: the room and everyone else stay.
                    let _ = self.client.detach(handle);
                    notices.push(Notice::Skipped {
                        feed: p.id,
                        name: p.display,
                        reason: e.to_string(),
                    });
                }
            }
        }
        Ok(())
    }

    fn subscribe(&mut self, handle: u64, feed: &str, name: &str) -> Result<(), JanusError> {
        let feed_id = self.ids.id(feed).ok_or_else(|| {
            JanusError::Protocol(format!(
                "publisher id {feed:?} is not a number in a room numbered by Janus"
            ))
        })?;
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
        self.client.trickle_completed(handle)
    }

    pub fn media_stats(&self) -> MediaStats {
        self.media.stats()
    }

    /// Lets the media of publishers gone play out and fall silent. Called after their
    /// departure was told, so that nobody sees every feed gone before hearing who left.
    fn mark_departed(&mut self) {
        for feed in self.departed.drain(..) {
            self.media.feed_left(&feed);
        }
    }

    /// Hangs up (DTLS close, RTCP BYE) and destroys the Janus session, which takes us out of
    /// the room.
    pub fn leave(mut self) -> Result<(), JanusError> {
        self.media.hang_up();
        self.client.destroy()
    }
}

/// At most this many of Janus's events are read per poll (a flooding server waits).
const EVENTS_PER_POLL: usize = 200;

/// Whether a subscription's failure means the Janus session itself is in trouble (rejoin),
/// rather than that one publisher cannot be heard (skip it).
fn concerns_the_session(e: &JanusError) -> bool {
    matches!(
        e,
        JanusError::Http { .. }
            | JanusError::NotJanus { .. }
            | JanusError::Janus { .. }
            | JanusError::Lost(_)
    )
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
///
/// The room lives on the signalling thread; this handle holds the current media and the
/// notices, so none of its calls waits for Janus.
pub struct Member {
    shared: Arc<Mutex<Current>>,
    notices: Receiver<Notice>,
    stop: Arc<AtomicBool>,
    signalling: Option<JoinHandle<()>>,
}

/// What the tick side sees of the room the signalling thread is in.
#[derive(Default)]
struct Current {
    media: Option<Arc<Media>>,
    id: Option<String>,
    /// Packets published in rooms lost since.
    published_before: u64,
}

impl std::fmt::Debug for Member {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Member")
            .field("id", &self.current().id)
            .finish_non_exhaustive()
    }
}

const REJOIN_EVERY: Duration = Duration::from_secs(1);
const PUBLISH_TIMEOUT: Duration = Duration::from_secs(10);
/// How often the signalling thread looks for Janus's events.
const FOLLOW_EVERY: Duration = Duration::from_millis(20);
/// Notices not yet read by the owner; past this (a room churning faster than anyone reads)
/// the newest are dropped, not the memory grown.
const NOTICES_KEPT: usize = 1024;
/// How long leaving waits for the signalling thread to hang up: short, so that a command
/// ends within a second of `--seconds` or a signal even when Janus does not answer.
const LEAVE_WAIT: Duration = Duration::from_millis(700);

impl Member {
    /// Joins (and publishes, when `publish`); a first join that fails is an error.
    pub fn join(config: RoomConfig, publish: bool) -> Result<(Self, Vec<Notice>), JanusError> {
        let (room, notices) = enter(&config, publish)?;
        let shared = Arc::new(Mutex::new(Current::default()));
        let (tx, rx) = sync_channel(NOTICES_KEPT);
        let stop = Arc::new(AtomicBool::new(false));
        let follower = Follower {
            config,
            publish,
            shared: Arc::clone(&shared),
            tx,
            stop: Arc::clone(&stop),
            retry_at: Instant::now(),
            last_failure: None,
        };
        follower.entered(&room);
        let signalling = std::thread::Builder::new()
            .name("lipcall-janus-room".into())
            .spawn(move || follower.run(room))
            .map_err(|e| JanusError::Protocol(format!("cannot start the room's thread: {e}")))?;
        Ok((
            Self {
                shared,
                notices: rx,
                stop,
                signalling: Some(signalling),
            },
            notices,
        ))
    }

    fn current(&self) -> std::sync::MutexGuard<'_, Current> {
        self.shared.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn media(&self) -> Option<Arc<Media>> {
        self.current().media.clone()
    }

    /// Our publisher id, while in the room.
    pub fn id(&self) -> Option<String> {
        self.current().id.clone()
    }

    /// What happened in the room since the last call (never waits for Janus).
    pub fn poll(&mut self) -> Vec<Notice> {
        self.notices.try_iter().collect()
    }

    /// Sends one Opus payload; dropped while out of the room.
    pub fn send(&self, payload: &[u8], ticks: u32) -> Result<(), JanusError> {
        match self.media() {
            Some(media) => media.send(payload, ticks),
            None => Ok(()),
        }
    }

    /// Moves our stream's clock on by `ticks` without sending (a silent gap).
    pub fn skip(&self, ticks: u32) {
        if let Some(media) = self.media() {
            media.skip(ticks);
        }
    }

    pub fn pull(&self, now: Instant, out: &mut Vec<PeerFrame>) {
        if let Some(media) = self.media() {
            media.pull(now, out);
        }
    }

    /// The publishers of the current session (none while out of the room).
    pub fn feeds(&self) -> Vec<FeedInfo> {
        self.media().map(|m| m.feeds()).unwrap_or_default()
    }

    pub fn in_room(&self) -> bool {
        self.current().media.is_some()
    }

    /// The current session's media counters, `published` counting every session's.
    pub fn media_stats(&self) -> MediaStats {
        let current = self.current();
        let mut stats = current
            .media
            .as_ref()
            .map(|m| m.stats())
            .unwrap_or_default();
        stats.published += current.published_before;
        stats
    }

    /// Leaves the room: the signalling thread hangs up and destroys the session. Waits for it
    /// at most [`LEAVE_WAIT`]; a thread still held by a request that Janus does not answer is
    /// left to finish on its own (Janus then times the session out).
    pub fn leave(mut self) -> Result<(), JanusError> {
        self.stop.store(true, Ordering::Relaxed);
        if crate::net::join::join_within(&mut self.signalling, LEAVE_WAIT) {
            return Ok(());
        }
        Err(JanusError::Timeout(format!(
            "Janus did not confirm the leave within {} ms",
            LEAVE_WAIT.as_millis()
        )))
    }
}

impl Drop for Member {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

fn enter(config: &RoomConfig, publish: bool) -> Result<(Room, Vec<Notice>), JanusError> {
    let (mut room, notices) = Room::join(config.clone())?;
    if publish {
        room.publish()?;
        room.wait_published(PUBLISH_TIMEOUT)?;
    }
    Ok((room, notices))
}

/// The signalling thread: follows the room, rejoins a lost one, leaves when told.
struct Follower {
    config: RoomConfig,
    publish: bool,
    shared: Arc<Mutex<Current>>,
    tx: SyncSender<Notice>,
    stop: Arc<AtomicBool>,
    retry_at: Instant,
    last_failure: Option<String>,
}

impl Follower {
    fn run(mut self, room: Room) {
        let mut room = Some(room);
        while !self.stop.load(Ordering::Relaxed) {
            match &mut room {
                Some(r) => {
                    if let Err(e) = self.follow(r) {
                        self.tell(Notice::Lost {
                            reason: e.to_string(),
                        });
                        if let Some(lost) = room.take() {
                            self.left(&lost);
                            let _ = lost.leave();
                        }
                        self.retry_at = Instant::now();
                    }
                }
                None if Instant::now() >= self.retry_at => room = self.rejoin(),
                None => {}
            }
            std::thread::sleep(FOLLOW_EVERY);
        }
        if let Some(r) = room {
            let _ = r.leave();
        }
    }

    fn follow(&mut self, room: &mut Room) -> Result<(), JanusError> {
        for notice in room.poll(&self.stop)? {
            self.tell(notice);
        }
        room.mark_departed();
        Ok(())
    }

    fn rejoin(&mut self) -> Option<Room> {
        self.retry_at = Instant::now() + REJOIN_EVERY;
        match enter(&self.config, self.publish) {
            Ok((room, notices)) => {
                // Told to stop while rejoining: hang up at once.
                if self.stop.load(Ordering::Relaxed) {
                    let _ = room.leave();
                    return None;
                }
                self.entered(&room);
                self.tell(Notice::Rejoined {
                    id: room.id().to_string(),
                });
                for n in notices {
                    self.tell(n);
                }
                self.last_failure = None;
                Some(room)
            }
            Err(e) => {
                let reason = e.to_string();
                if self.last_failure.as_ref() != Some(&reason) {
                    self.tell(Notice::RejoinFailed {
                        reason: reason.clone(),
                    });
                    self.last_failure = Some(reason);
                }
                None
            }
        }
    }

    fn current(&self) -> std::sync::MutexGuard<'_, Current> {
        self.shared.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn entered(&self, room: &Room) {
        let mut current = self.current();
        current.media = Some(Arc::clone(&room.media));
        current.id = Some(room.id().to_string());
    }

    fn left(&self, room: &Room) {
        let mut current = self.current();
        current.published_before += room.media_stats().published;
        current.media = None;
        current.id = None;
    }

    fn tell(&self, notice: Notice) {
        match self.tx.try_send(notice) {
            Ok(()) | Err(TrySendError::Disconnected(_)) => {}
            Err(TrySendError::Full(dropped)) => {
                tracing::debug!("room notice dropped (nobody reading): {dropped:?}");
            }
        }
    }
}
