//! A Mumble server as the app's call (`mumble://HOST[:PORT]/CHANNEL` in the call bar). The join
//! runs on its own thread (TLS and the server's answer take a moment; the 20 ms tick never
//! waits for it); the server's news is said in Mumble's words in the call bar; its channels and
//! users are listed for the UI ([`MumbleView`]) and we move between them on request; and the
//! microphone's mute and push-to-talk reach the server as Mumble's self-mute, so that the others
//! see it.
//!
//! The worker drives the call's [`Link`] like any other (frames, peers, our voice); the
//! [`MumbleCall`] it keeps beside it shares the connection for what only Mumble has.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, anyhow};

use super::call_status::{CallStatus, Encryption};
use crate::audio::MicControls;
use crate::call::link::{Link, LinkEvent};
use crate::call::mumble::{MumbleLink, parse_mumble_url};
use crate::codec::any::{Codec, EncoderSettings, FrameEncoder};
use crate::codec::opus::codec::Bandwidth;
use crate::net::jitter::JitterConfig;
use crate::net::mumble::MumbleError;
use crate::net::mumble::client::{Channel, ClientConfig};
use crate::net::mumble::connection::{ConnectConfig, Connection, with_port};
use crate::net::mumble::events::Member;
use crate::net::mumble::identity::{self, Trust};
use crate::net::session::{PeerFrame, PeerInfo};

/// How often the channels and users are refreshed for the UI.
const VIEW_EVERY: Duration = Duration::from_millis(200);

/// A channel as the UI lists it: its place in the tree and who is in it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelRow {
    pub id: u32,
    pub name: String,
    /// How deep in the tree (the root is 0).
    pub depth: usize,
    pub members: Vec<Member>,
    /// We are in it.
    pub ours: bool,
}

/// What the UI shows of the Mumble server we are on.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct MumbleView {
    /// `host:port`.
    pub server: String,
    /// The server certificate's SHA-256 fingerprint.
    pub fingerprint: String,
    /// The certificate was first seen on this join, and is trusted from now on.
    pub first_visit: bool,
    /// Parents before their children, siblings by name.
    pub channels: Vec<ChannelRow>,
    /// The server was told that we are muted.
    pub self_muted: bool,
    /// Voice goes by UDP (else through the TLS tunnel).
    pub udp: bool,
}

impl MumbleView {
    /// Everyone on the server, wherever they are.
    pub fn members(&self) -> impl Iterator<Item = (&ChannelRow, &Member)> {
        self.channels
            .iter()
            .flat_map(|c| c.members.iter().map(move |m| (c, m)))
    }
}

type Joining = JoinHandle<Result<Connection, MumbleError>>;

enum Stage {
    Joining(Option<Joining>),
    In(Box<MumbleLink>),
    /// Left, refused or removed: nothing more comes.
    Over,
}

fn lock(stage: &Mutex<Stage>) -> MutexGuard<'_, Stage> {
    stage.lock().unwrap_or_else(|e| e.into_inner())
}

/// What a Mumble join needs besides the address.
#[derive(Debug, Clone)]
pub struct MumbleJoin<'a> {
    pub name: String,
    /// The server's password.
    pub password: Option<&'a str>,
    pub bandwidth: Bandwidth,
    /// Our certificate and the servers we trust ([`identity::default_dir`] if none).
    pub identity: Option<&'a Path>,
}

/// The app's side of a Mumble call, beside its [`Link`].
pub struct MumbleCall {
    stage: Arc<Mutex<Stage>>,
    /// `host:port`.
    server: String,
    /// The call's status is not said yet.
    fresh: bool,
    last_view: Option<Instant>,
    /// The self-mute the server was last told.
    muted: Option<bool>,
}

/// How a call stands after a look at it.
enum Step {
    Going,
    /// The worker left the call (for another, or none).
    Left,
    /// The server refused or removed us: the worker should leave.
    Failed,
}

impl MumbleCall {
    /// Starts joining the server of a `mumble://HOST[:PORT]/CHANNEL` address. Returns the link
    /// the worker drives, this handle, and the Opus encoder our voice goes out in.
    pub fn join(
        address: &str,
        join: MumbleJoin<'_>,
    ) -> anyhow::Result<(Box<dyn Link>, Self, FrameEncoder)> {
        let (server, channel) = parse_mumble_url(address).ok_or_else(|| {
            anyhow!("{address:?} is not a Mumble address (mumble://HOST[:PORT]/CHANNEL)")
        })?;
        let identity_dir: PathBuf = match join.identity {
            Some(dir) => dir.to_path_buf(),
            None => identity::default_dir()
                .context("no folder for the client certificate: set HOME or XDG_CONFIG_HOME")?,
        };
        let encoder = FrameEncoder::new(Codec::Opus, &EncoderSettings::wideband(join.bandwidth))?;
        let config = ConnectConfig {
            address: server.clone(),
            client: ClientConfig {
                name: join.name,
                password: join.password.filter(|p| !p.is_empty()).map(str::to_string),
                channel,
                jitter: JitterConfig::default(),
                tcp_only: false,
            },
            identity_dir,
        };
        let shown = with_port(&server)?;
        let handle = std::thread::Builder::new()
            .name("mumble-join".into())
            .spawn(move || Connection::connect(config))?;
        let stage = Arc::new(Mutex::new(Stage::Joining(Some(handle))));
        let call = Self {
            stage: stage.clone(),
            server: shown,
            fresh: true,
            last_view: None,
            muted: None,
        };
        Ok((Box::new(CallLink(stage)), call, encoder))
    }

    /// Moves us to channel `id` of the server.
    pub fn join_channel(&self, id: u32) -> anyhow::Result<()> {
        match &*lock(&self.stage) {
            Stage::In(link) => {
                link.connection().join_channel(id);
                Ok(())
            }
            _ => Err(anyhow!(
                "not on the Mumble server yet: no channel to move to"
            )),
        }
    }

    fn step(
        &mut self,
        status: &mut CallStatus,
        view: &mut Option<MumbleView>,
        mic: Option<&MicControls>,
    ) -> Step {
        if std::mem::take(&mut self.fresh) {
            *status = CallStatus {
                state: format!("joining the Mumble server {}…", self.server),
                in_call: true,
                encryption: Encryption::HopByHop,
                codec: Some(Codec::Opus),
                ..CallStatus::default()
            };
        }
        let mut stage = lock(&self.stage);
        if let Stage::Joining(handle) = &mut *stage {
            if !handle.as_ref().is_some_and(JoinHandle::is_finished) {
                return Step::Going;
            }
            match handle.take().map(JoinHandle::join) {
                Some(Ok(Ok(connection))) => {
                    let (print, trust) = connection.fingerprint();
                    *view = Some(MumbleView {
                        server: self.server.clone(),
                        fingerprint: print.to_string(),
                        first_visit: *trust == Trust::New,
                        ..MumbleView::default()
                    });
                    let place = format!("the Mumble server {}", self.server);
                    *stage = Stage::In(Box::new(MumbleLink::joined(connection, place)));
                    self.last_view = None;
                }
                Some(Ok(Err(e))) => {
                    *stage = Stage::Over;
                    status.error =
                        Some(format!("Mumble server {}: {}", self.server, app_words(&e)));
                    return Step::Failed;
                }
                _ => {
                    *stage = Stage::Over;
                    status.error = Some("the Mumble join stopped unexpectedly".into());
                    return Step::Failed;
                }
            }
        }
        let Stage::In(link) = &mut *stage else {
            return Step::Left;
        };
        if self.hear(link, status) {
            *stage = Stage::Over;
            return Step::Failed;
        }
        // No microphone: nothing of ours can be heard, and the others see so.
        let muted = mic.is_none_or(|m| !m.transmitting());
        if self.muted != Some(muted) {
            link.connection().set_self_mute(muted);
            self.muted = Some(muted);
        }
        let now = Instant::now();
        if self
            .last_view
            .is_none_or(|t| now.saturating_duration_since(t) >= VIEW_EVERY)
        {
            self.last_view = Some(now);
            let connection = link.connection();
            if let Some(v) = view {
                v.channels = channel_tree(&connection.channels(), connection.members());
                v.self_muted = muted;
                v.udp = connection.udp_working();
            }
            if let Some(channel) = connection.current_channel() {
                status.state = format!(
                    "in channel {channel:?} of the Mumble server {}, sending opus",
                    self.server
                );
            }
        }
        Step::Going
    }

    /// What the server said, in the call bar; `true` when it removed us.
    fn hear(&self, link: &mut MumbleLink, status: &mut CallStatus) -> bool {
        let server = &self.server;
        for event in link.poll() {
            match event {
                LinkEvent::Failed(reason) => {
                    status.error = Some(reason);
                    return true;
                }
                LinkEvent::Lost { reason } => {
                    status.state = format!("reconnecting to the Mumble server {server}…");
                    status.error = Some(format!(
                        "lost the Mumble server {server} ({reason}); reconnecting"
                    ));
                }
                LinkEvent::RejoinFailed { reason } => {
                    status.error = Some(format!(
                        "cannot reconnect to the Mumble server {server}: {reason}"
                    ));
                }
                LinkEvent::Rejoined { id } => {
                    tracing::info!("back on the Mumble server {server} as session {id}");
                    status.error = None;
                }
                LinkEvent::PeerJoined { id, name } => {
                    tracing::info!("{name:?} (session {id}) is in the channel");
                }
                LinkEvent::PeerLeft { id, name } => {
                    tracing::info!("{name:?} (session {id}) left the channel");
                }
                LinkEvent::PeerSkipped { id, name, reason } => {
                    tracing::warn!("{name:?} (session {id}) cannot be heard: {reason}");
                }
                LinkEvent::Joined { .. } => {}
            }
        }
        for note in link.take_notes() {
            if note.starts_with("the server refused") {
                status.error = Some(format!("Mumble: {note}"));
            } else {
                tracing::info!("Mumble: {note}");
            }
        }
        false
    }
}

/// A join's failure as the app says it: the protocol's reasons name the command line's flags.
fn app_words(e: &MumbleError) -> String {
    e.to_string()
        .replace(
            "(give it with --password)",
            "(give it as the server password)",
        )
        .replace("pick another with --name", "pick another name")
}

/// The worker's look at its Mumble call, if any, once per loop: the join's outcome, the
/// server's news (in `status`), the channels (in `view`), the microphone's state told as
/// self-mute. Forgets a call the worker has left. `true`: the call failed (refused, removed);
/// the worker should leave it.
pub fn follow(
    call: &mut Option<MumbleCall>,
    status: &mut CallStatus,
    view: &mut Option<MumbleView>,
    mic: Option<&MicControls>,
) -> bool {
    let Some(c) = call else {
        *view = None;
        return false;
    };
    match c.step(status, view, mic) {
        Step::Going => false,
        Step::Left => {
            *call = None;
            *view = None;
            false
        }
        Step::Failed => {
            *call = None;
            *view = None;
            true
        }
    }
}

/// The channels in tree order with their members. Parent links that loop or point nowhere
/// (a hostile server) make a channel a root; none is listed twice.
fn channel_tree(channels: &[Channel], members: Vec<Member>) -> Vec<ChannelRow> {
    let ours = members.iter().find(|m| m.us).map(|m| m.channel);
    let mut by_channel: BTreeMap<u32, Vec<Member>> = BTreeMap::new();
    for m in members {
        by_channel.entry(m.channel).or_default().push(m);
    }
    let known: BTreeSet<u32> = channels.iter().map(|c| c.id).collect();
    let is_root =
        |c: &Channel| c.parent.is_none_or(|p| p == c.id || !known.contains(&p)) || c.id == 0;
    let mut sorted: Vec<&Channel> = channels.iter().collect();
    sorted.sort_by(|a, b| a.name.cmp(&b.name).then(a.id.cmp(&b.id)));
    let mut rows = Vec::new();
    let mut seen = BTreeSet::new();
    let mut stack: Vec<(&Channel, usize)> = sorted
        .iter()
        .rev()
        .filter(|c| is_root(c))
        .map(|c| (*c, 0))
        .collect();
    loop {
        while let Some((channel, depth)) = stack.pop() {
            if !seen.insert(channel.id) {
                continue;
            }
            rows.push(ChannelRow {
                id: channel.id,
                name: channel.name.clone(),
                depth,
                members: by_channel.remove(&channel.id).unwrap_or_default(),
                ours: ours == Some(channel.id),
            });
            let children = sorted
                .iter()
                .rev()
                .filter(|c| c.parent == Some(channel.id) && !is_root(c));
            stack.extend(children.map(|c| (*c, depth + 1)));
        }
        // Channels only reachable through a loop of parents: listed as roots.
        match sorted.iter().find(|c| !seen.contains(&c.id)) {
            Some(c) => stack.push((c, 0)),
            None => break,
        }
    }
    rows
}

/// The call's [`Link`] for the worker: the joined channel's speakers once in, nothing before.
/// The [`MumbleCall`] beside it says what the server does, so its `poll` says nothing.
struct CallLink(Arc<Mutex<Stage>>);

impl Link for CallLink {
    fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) {
        if let Stage::In(link) = &mut *lock(&self.0) {
            link.pull(now, out);
        }
    }

    fn peers(&self) -> Vec<PeerInfo> {
        match &*lock(&self.0) {
            Stage::In(link) => link.peers(),
            _ => Vec::new(),
        }
    }

    fn silent_members(&self) -> Vec<PeerInfo> {
        match &*lock(&self.0) {
            Stage::In(link) => link.silent_members(),
            _ => Vec::new(),
        }
    }

    fn all_left(&self) -> bool {
        match &*lock(&self.0) {
            Stage::In(link) => link.all_left(),
            _ => false,
        }
    }

    fn send_frames(&mut self, payload: &[u8], frames: u32) {
        if let Stage::In(link) = &mut *lock(&self.0) {
            link.send_frames(payload, frames);
        }
    }

    fn skip_frames(&mut self, frames: u32) {
        if let Stage::In(link) = &mut *lock(&self.0) {
            link.skip_frames(frames);
        }
    }

    fn unknown_payload(&self) -> u64 {
        match &*lock(&self.0) {
            Stage::In(link) => link.unknown_payload(),
            _ => 0,
        }
    }

    /// Disconnects, on a thread of its own: a connection in the middle of a reconnect takes up
    /// to a second to stop, which the worker's tick must not wait for. A join still running
    /// finishes on its own thread, and its connection closes as it is dropped there.
    fn leave(&mut self) {
        let stage = std::mem::replace(&mut *lock(&self.0), Stage::Over);
        if let Stage::In(mut link) = stage {
            let closing = std::thread::Builder::new()
                .name("mumble-leave".into())
                .spawn(move || link.leave());
            if let Err(e) = closing {
                tracing::warn!("cannot close the Mumble connection on its own thread: {e}");
            }
        }
    }

    fn over(&self) -> bool {
        matches!(&*lock(&self.0), Stage::Over)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(id: u32, parent: Option<u32>, name: &str) -> Channel {
        Channel {
            id,
            parent,
            name: name.into(),
        }
    }

    fn member(session: u32, channel: u32, us: bool) -> Member {
        Member {
            session,
            name: format!("u{session}"),
            channel,
            self_mute: false,
            us,
        }
    }

    #[test]
    fn channels_are_listed_as_a_tree_with_their_members() {
        let channels = [
            channel(0, None, "Root"),
            channel(2, Some(0), "Zoo"),
            channel(1, Some(0), "Cellar"),
            channel(3, Some(1), "Wine"),
        ];
        let rows = channel_tree(&channels, vec![member(5, 3, true), member(6, 0, false)]);
        let order: Vec<(&str, usize)> = rows.iter().map(|r| (r.name.as_str(), r.depth)).collect();
        assert_eq!(order, [("Root", 0), ("Cellar", 1), ("Wine", 2), ("Zoo", 1)]);
        assert!(rows[2].ours && !rows[0].ours);
        assert_eq!(rows[0].members[0].session, 6);
        assert_eq!(rows[2].members[0].session, 5);
    }

    #[test]
    fn a_hostile_server_s_looping_parents_list_each_channel_once() {
        let channels = [
            channel(0, None, "Root"),
            channel(4, Some(5), "A"),
            channel(5, Some(4), "B"),
            channel(6, Some(6), "Self"),
            channel(7, Some(99), "Orphan"),
        ];
        let rows = channel_tree(&channels, Vec::new());
        let mut ids: Vec<u32> = rows.iter().map(|r| r.id).collect();
        ids.sort_unstable();
        assert_eq!(ids, [0, 4, 5, 6, 7]);
    }

    proptest::proptest! {
        #[test]
        fn any_channel_states_list_each_channel_once(
            links in proptest::collection::btree_map(0u32..12, proptest::option::of(0u32..14), 0..12),
        ) {
            let channels: Vec<Channel> =
                links.iter().map(|(&id, &parent)| channel(id, parent, "c")).collect();
            let rows = channel_tree(&channels, vec![member(1, 3, true)]);
            let mut ids: Vec<u32> = rows.iter().map(|r| r.id).collect();
            ids.sort_unstable();
            let want: Vec<u32> = links.keys().copied().collect();
            proptest::prop_assert_eq!(ids, want);
        }
    }
}
