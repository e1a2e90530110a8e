//! A Mumble server as the app's call (`mumble://HOST[:PORT]/CHANNEL` in the call bar). The
//! worker drives the call's [`MumbleLink`] like any other (frames, peers, our voice, the
//! server's news through [`Link::poll`]); the [`MumbleCall`] it keeps beside it holds the
//! link's [`MumbleHandle`] for what only Mumble has: the channels and users listed for the UI
//! ([`MumbleView`]), moving between them on request, and the microphone's mute and
//! push-to-talk told to the server as Mumble's self-mute, so that the others see it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, anyhow};

use super::call_status::CallStatus;
use crate::audio::MicControls;
use crate::call::link::Link;
use crate::call::mumble::{MumbleHandle, MumbleLink, parse_mumble_url};
use crate::codec::any::{Codec, EncoderSettings, FrameEncoder};
use crate::net::jitter::JitterConfig;
use crate::net::mumble::client::{Channel, ClientConfig};
use crate::net::mumble::connection::{ConnectConfig, with_port};
use crate::net::mumble::events::Member;
use crate::net::mumble::identity::{self, Trust};

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

/// What a Mumble join needs besides the address.
#[derive(Debug, Clone)]
pub struct MumbleJoin<'a> {
    pub name: String,
    /// The server's password.
    pub password: Option<&'a str>,
    /// Opus's band and frame length.
    pub encoder: EncoderSettings,
    /// Our certificate and the servers we trust ([`identity::default_dir`] if none).
    pub identity: Option<&'a Path>,
}

/// The app's side of a Mumble call, beside its [`Link`] (which says the server's news).
pub struct MumbleCall {
    handle: MumbleHandle,
    /// `host:port`.
    server: String,
    last_view: Option<Instant>,
    /// The self-mute the server was last told.
    muted: Option<bool>,
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
        let encoder = FrameEncoder::new(Codec::Opus, &join.encoder)?;
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
        let link = MumbleLink::join(config, format!("the Mumble server {shown}"))?;
        let call = Self {
            handle: link.handle(),
            server: shown,
            last_view: None,
            muted: None,
        };
        Ok((Box::new(link), call, encoder))
    }

    /// `host:port`.
    pub fn server(&self) -> &str {
        &self.server
    }

    /// Moves us to channel `id` of the server.
    pub fn join_channel(&self, id: u32) -> anyhow::Result<()> {
        let remote = self
            .handle
            .remote()
            .ok_or_else(|| anyhow!("not on the Mumble server yet: no channel to move to"))?;
        remote.join_channel(id);
        Ok(())
    }

    /// The worker's look at its Mumble call once per loop, once joined: the channels (in
    /// `view`, every [`VIEW_EVERY`]), the channel in the state line, the microphone's state
    /// told as self-mute.
    pub fn refresh(
        &mut self,
        status: &mut CallStatus,
        view: &mut Option<MumbleView>,
        mic: Option<&MicControls>,
    ) {
        let (Some(remote), Some((print, trust))) =
            (self.handle.remote(), self.handle.fingerprint())
        else {
            return;
        };
        if view.is_none() {
            *view = Some(MumbleView {
                server: self.server.clone(),
                fingerprint: print.to_string(),
                first_visit: *trust == Trust::New,
                ..MumbleView::default()
            });
        }
        // No microphone: nothing of ours can be heard, and the others see so.
        let muted = mic.is_none_or(|m| !m.transmitting());
        if self.muted != Some(muted) {
            remote.set_self_mute(muted);
            self.muted = Some(muted);
        }
        let now = Instant::now();
        if self
            .last_view
            .is_some_and(|t| now.saturating_duration_since(t) < VIEW_EVERY)
        {
            return;
        }
        self.last_view = Some(now);
        if let Some(v) = view {
            v.channels = channel_tree(&remote.channels(), remote.members());
            v.self_muted = muted;
            v.udp = remote.udp_working();
        }
        if let Some(channel) = remote.current_channel() {
            status.state = format!(
                "in channel {channel:?} of the Mumble server {}, sending opus",
                self.server
            );
        }
    }
}

/// A Mumble failure as the app says it: the protocol's reasons name the command line's flags.
pub fn app_words(reason: &str) -> String {
    reason
        .replace(
            "(set LIPCALL_MUMBLE_PASSWORD or give --password-file)",
            "(give it as the server password)",
        )
        .replace("pick another with --name", "pick another name")
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
