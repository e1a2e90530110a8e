//! The call's remote peers by their link's [`PeerId`]: each admitted on its first frame,
//! animated frame by frame, described for the UI from what the link reports, and forgotten in
//! one place, with its mixer slot, when it leaves or the call ends.

use std::collections::{BTreeMap, VecDeque};
use std::net::SocketAddr;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use crate::audio::Playback;
use crate::net::peer::FrameKind;
use crate::net::transport::{PeerFrame, PeerId, PeerInfo};

use super::counters::{DEMO_NAME, EngineCounters};
use super::peer::{LEVEL_FLOOR_DB, PeerView, RemotePeer};

/// A peer whose last voiced frame is this recent is talking.
const TALKING_HOLD: Duration = Duration::from_millis(300);
/// Decoded frames above this energy are voice, for the talking indicator (dBFS).
const VOICE_DB: f32 = -45.0;

/// How long "NAME left" stays on screen.
pub const LEFT_NOTICE_STAYS: Duration = Duration::from_secs(6);
/// Notices of peers who left kept at most (a room emptying at once).
const LEFT_NOTICES_KEPT: usize = 8;
/// How fast a level meter falls back after a loud frame, per 20 ms frame (dB).
const LEVEL_FALL_DB: f32 = 3.0;

#[derive(Default)]
pub struct Roster {
    peers: BTreeMap<PeerId, RemotePeer>,
    /// The names of peers who left the call going on, and when.
    left: VecDeque<(String, Instant)>,
}

impl Roster {
    pub fn get(&self, peer: PeerId) -> Option<&RemotePeer> {
        self.peers.get(&peer)
    }

    pub fn get_mut(&mut self, peer: PeerId) -> Option<&mut RemotePeer> {
        self.peers.get_mut(&peer)
    }

    pub fn iter_mut(&mut self) -> impl Iterator<Item = &mut RemotePeer> {
        self.peers.values_mut()
    }

    pub fn len(&self) -> usize {
        self.peers.len()
    }

    pub fn is_empty(&self) -> bool {
        self.peers.is_empty()
    }

    /// The peers as the UI shows them (those the link has described), in the order they
    /// joined, then by name.
    pub fn views(&self) -> Vec<PeerView> {
        let mut views: Vec<PeerView> = self.peers.values().filter_map(|p| p.view.clone()).collect();
        views.sort_by(|a, b| (a.joined, &a.name).cmp(&(b.joined, &b.name)));
        views
    }

    /// When the peer at `addr` was first heard, if it is shown: the order callers are named in.
    pub(super) fn joined_at(&self, addr: SocketAddr) -> Option<Instant> {
        self.peers
            .values()
            .filter_map(|p| p.view.as_ref())
            .find(|v| v.addr == addr)
            .map(|v| v.joined)
    }

    /// The names of the peers who left within [`LEFT_NOTICE_STAYS`] of `now`, first first.
    pub fn left(&self, now: Instant) -> Vec<String> {
        self.left
            .iter()
            .filter(|(_, at)| now.saturating_duration_since(*at) < LEFT_NOTICE_STAYS)
            .map(|(name, _)| name.clone())
            .collect()
    }

    /// One pull's frames: into each peer's queue for the mixer, and through its animation.
    /// `ahead`: how many frames ahead of the mixer these are ([`crate::audio::PeerFeed::push_paced`]);
    /// `None` while the output takes nothing (they are not queued). A peer without a frame in
    /// this pull has its held-back frame's weights sent without their look-ahead.
    pub(super) fn play(
        &mut self,
        playback: &mut Playback,
        frames: &[PeerFrame],
        ahead: Option<usize>,
        now: Instant,
        counters: &EngineCounters,
    ) {
        for f in frames {
            let peer = match self.peers.entry(f.peer) {
                std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
                std::collections::btree_map::Entry::Vacant(e) => match playback.add_peer() {
                    Ok(feed) => e.insert(RemotePeer::new(f.peer, feed)),
                    Err(err) => {
                        tracing::debug!("peer {} not played: {err}", f.peer);
                        continue;
                    }
                },
            };
            if let Some(c) = playback.peer_controls(peer.feed.id()) {
                c.set_muted(peer.prefs.muted);
                c.set_volume(peer.prefs.volume);
            }
            peer.frames_received += 1;
            let resuming = !std::mem::replace(&mut peer.playing, ahead.is_some());
            // (Not queued when the mixer has mixed silence in its place already, or while the
            // output takes nothing: a device that has not started or stalls, a stopped mixer.)
            // The ear gets the codec's own band, resampled once to the mixer's rate; the face
            // the 8 kHz signal its features came from.
            let queued =
                ahead.and_then(|ahead| peer.feed.push_frame(&f.frame.audio, ahead, resuming));
            let Some(pos) = queued else {
                continue;
            };
            let energy = f.frame.features.energy_db;
            if f.frame.kind == FrameKind::Decoded && energy > VOICE_DB {
                peer.last_voice = Some(now);
            }
            peer.level_db = energy
                .max(peer.level_db - LEVEL_FALL_DB)
                .max(LEVEL_FLOOR_DB);
            let t0 = Instant::now();
            let animated = peer.animation.frames_animated;
            let out = peer
                .animation
                .step(&peer.prefs, pos, &f.frame.features, &f.frame.pcm);
            if peer.animation.frames_animated > animated {
                counters
                    .network_ns
                    .fetch_add(t0.elapsed().as_nanos() as u64, Ordering::Relaxed);
                counters.frames_animated.fetch_add(1, Ordering::Relaxed);
            }
            if let Some((pos, row)) = out {
                let heard = playback.heard_position(peer.feed.id(), now);
                counters.weights_scheduled(pos, heard, peer.feed.rate(), false);
                peer.weights.send(pos, row);
            }
        }
        for (id, peer) in &mut self.peers {
            if frames.iter().any(|f| f.peer == *id) {
                continue;
            }
            peer.playing = false;
            peer.level_db = (peer.level_db - LEVEL_FALL_DB).max(LEVEL_FLOOR_DB);
            if let Some((pos, row)) = peer.animation.flush() {
                let heard = playback.heard_position(peer.feed.id(), now);
                counters.weights_scheduled(pos, heard, peer.feed.rate(), true);
                peer.weights.send(pos, row);
            }
        }
    }

    /// Takes the link's account of its peers: describes those it knows for the UI and forgets
    /// those it no longer knows or that said goodbye and went quiet.
    pub(super) fn describe(&mut self, playback: &mut Playback, infos: &[PeerInfo], now: Instant) {
        let gone: Vec<PeerId> = self
            .peers
            .keys()
            .copied()
            .filter(|id| !infos.iter().any(|i| i.id == *id && !i.ended))
            .collect();
        for id in gone {
            self.forget(playback, id, now);
        }
        for info in infos {
            let Some(peer) = self.peers.get_mut(&info.id) else {
                continue;
            };
            peer.view = Some(view_of(peer, info, now));
        }
    }

    /// The direct callers at `ringing` wait for an answer; every other peer is in the call,
    /// from now where it was not before (an answered caller's timer starts at the answer).
    pub(super) fn ringing_at(&mut self, ringing: &[SocketAddr], now: Instant) {
        for peer in self.peers.values_mut() {
            let Some(view) = peer.view.as_mut() else {
                continue;
            };
            peer.in_call_since = if ringing.contains(&view.addr) {
                None
            } else {
                Some(peer.in_call_since.unwrap_or(now))
            };
            view.in_call_since = peer.in_call_since;
        }
    }

    /// Gives each of `members` (in the call, silent so far) a place: a head, still until they
    /// speak, and their controls.
    pub(super) fn seat(&mut self, playback: &mut Playback, members: &[PeerInfo]) {
        for m in members {
            if let std::collections::btree_map::Entry::Vacant(e) = self.peers.entry(m.id) {
                match playback.add_peer() {
                    Ok(feed) => {
                        e.insert(RemotePeer::new(m.id, feed));
                    }
                    Err(err) => tracing::debug!("member {} not shown: {err}", m.id),
                }
            }
        }
    }

    /// Forgets every peer (the call ended or changed: the call's phase says so, not a
    /// notice per peer).
    pub(super) fn clear(&mut self, playback: &mut Playback) {
        for (_, peer) in std::mem::take(&mut self.peers) {
            playback.remove_peer(peer.feed.id());
        }
        self.left.clear();
    }

    /// Lets a peer go; one that was shown leaves a notice with its name.
    fn forget(&mut self, playback: &mut Playback, id: PeerId, now: Instant) {
        let Some(peer) = self.peers.remove(&id) else {
            return;
        };
        playback.remove_peer(peer.feed.id());
        if let Some(view) = peer.view {
            self.left
                .retain(|(_, at)| now.saturating_duration_since(*at) < LEFT_NOTICE_STAYS);
            if self.left.len() >= LEFT_NOTICES_KEPT {
                self.left.pop_front();
            }
            self.left.push_back((view.name, now));
        }
    }
}

/// The name a peer gave (a SIP URI's display name, or its user), else its CNAME, else its
/// id: an id only where nothing better exists.
pub fn shown_name(info: &PeerInfo) -> String {
    if let Some(name) = info
        .name
        .as_deref()
        .map(str::trim)
        .filter(|n| !n.is_empty())
    {
        return sip_display(name).unwrap_or(name).to_owned();
    }
    info.cname
        .clone()
        .filter(|c| !c.trim().is_empty())
        .unwrap_or_else(|| match info.id {
            PeerId::Ssrc(id) | PeerId::Janus(id) => format!("peer {id:08x}"),
            PeerId::Mumble(session) => format!("user {session}"),
        })
}

/// `"Bob" <sip:bob@host>` as Bob, `sip:bob@host` as bob; `None` for what is no SIP address.
fn sip_display(name: &str) -> Option<&str> {
    if let Some((display, rest)) = name.split_once('<')
        && rest.trim_start().to_ascii_lowercase().starts_with("sip")
    {
        let display = display.trim().trim_matches('"').trim();
        if !display.is_empty() {
            return Some(display);
        }
        return sip_display(rest.trim_end_matches('>'));
    }
    let lower = name.to_ascii_lowercase();
    let bare = if lower.starts_with("sips:") {
        &name[5..]
    } else if lower.starts_with("sip:") {
        &name[4..]
    } else {
        return None;
    };
    let user = bare.split_once('@').map_or(bare, |(user, _)| user);
    let user = user.split([';', ':']).next().unwrap_or(user);
    Some(if user.is_empty() { bare } else { user })
}

fn view_of(peer: &RemotePeer, info: &PeerInfo, now: Instant) -> PeerView {
    let jitter = &info.receiver.jitter;
    let expected = jitter.played + jitter.lost;
    PeerView {
        peer: info.id,
        name: shown_name(info),
        named: info.name.as_deref().is_some_and(|n| !n.trim().is_empty()),
        addr: info.addr,
        feed: peer.feed.id(),
        is_demo: info.name.as_deref() == Some(DEMO_NAME),
        codec: info.receiver.codec,
        level_db: peer.level_db,
        joined: peer.joined,
        in_call_since: peer.in_call_since,
        talking: peer
            .last_voice
            .is_some_and(|t| now.saturating_duration_since(t) < TALKING_HOLD),
        loss_percent: if expected == 0 {
            0.0
        } else {
            100.0 * jitter.lost as f64 / expected as f64
        },
        jitter_ms: jitter.jitter_ms,
        delay_ms: jitter.current_delay_ms,
        frames_animated: peer.animation.frames_animated,
        frames_received: peer.frames_received,
        frames_recovered: info.receiver.recovered,
        unknown_payload: info.receiver.unknown_payload,
        queued_ms: peer.feed.queued() as f64 * 1000.0 / f64::from(peer.feed.rate()),
        buffer: *jitter,
    }
}

#[cfg(test)]
mod tests {
    //! The roster's decisions in simulated time: each test hands it pulls and link reports at
    //! instants it chooses; the mixer behind it is a real one on a silent output.

    use std::net::SocketAddr;

    use super::*;
    use crate::audio::PlaybackConfig;
    use crate::codec::any::Codec;
    use crate::net::peer::PlayedFrame;
    use crate::vocab::FrameFeatures;

    struct Call {
        roster: Roster,
        playback: Playback,
        counters: EngineCounters,
        t0: Instant,
        /// Pulls so far: the mixer (on a real-time silent output) takes next to nothing while a
        /// test runs, so each pull's frames sit one frame further ahead of it, as a burst of
        /// pulls from the pacer would.
        pulls: usize,
    }

    impl Call {
        fn new() -> Self {
            Self {
                roster: Roster::default(),
                playback: Playback::start_silent(PlaybackConfig::default()).unwrap(),
                counters: EngineCounters::default(),
                t0: Instant::now(),
                pulls: 0,
            }
        }

        fn at(&self, ms: u64) -> Instant {
            self.t0 + Duration::from_millis(ms)
        }

        /// One pull at `ms` with these peers' frames.
        fn pull(&mut self, ms: u64, frames: &[PeerFrame]) {
            let now = self.at(ms);
            self.pulls += 1;
            let ahead = Some(self.pulls);
            self.roster
                .play(&mut self.playback, frames, ahead, now, &self.counters);
        }

        fn report(&mut self, ms: u64, infos: &[PeerInfo]) {
            let now = self.at(ms);
            self.roster.describe(&mut self.playback, infos, now);
        }

        fn count(&self, counter: &std::sync::atomic::AtomicU64) -> u64 {
            counter.load(Ordering::Relaxed)
        }
    }

    fn frame(ssrc: u32, energy_db: f32) -> PeerFrame {
        let amplitude = if energy_db > -90.0 { 3000.0 } else { 0.0 };
        PeerFrame {
            peer: PeerId::Ssrc(ssrc),
            frame: PlayedFrame::narrowband(
                std::array::from_fn(|i| (amplitude * (i as f32 * 0.3).sin()) as i16),
                FrameFeatures {
                    mode: Some(5),
                    energy_db,
                    ..crate::vocab::FrameFeatures::silent()
                },
                FrameKind::Decoded,
                Codec::Speex,
            ),
        }
    }

    fn voiced(ssrc: u32) -> PeerFrame {
        frame(ssrc, -20.0)
    }

    fn info(ssrc: u32, name: &str) -> PeerInfo {
        PeerInfo {
            id: PeerId::Ssrc(ssrc),
            addr: SocketAddr::from(([127, 0, 0, 1], 5004)),
            cname: Some(format!("{name}@127.0.0.1")),
            name: Some(name.to_owned()),
            receiver: Default::default(),
            rtt_ms: None,
            their_loss: None,
            said_bye: false,
            ended: false,
        }
    }

    #[test]
    fn a_peer_is_admitted_on_its_first_frame_and_shown_once_the_link_describes_it() {
        let mut call = Call::new();
        call.pull(0, &[voiced(7)]);
        assert_eq!(call.roster.len(), 1);
        assert!(call.roster.views().is_empty(), "not described yet");
        let feed = call.roster.get(PeerId::Ssrc(7)).unwrap().feed();
        assert!(call.playback.peer_controls(feed).is_some(), "a mixer slot");

        call.report(200, &[info(7, "Ann"), info(9, "Bob")]);
        let views = call.roster.views();
        assert_eq!(views.len(), 1, "Bob has sent no frame: nothing to show");
        assert_eq!(
            (views[0].peer, views[0].name.as_str()),
            (PeerId::Ssrc(7), "Ann")
        );
        assert!(views[0].named);
        assert_eq!(views[0].feed, feed);
        assert_eq!(views[0].frames_received, 1);
    }

    #[test]
    fn a_ringing_callers_time_in_the_call_starts_when_it_is_answered() {
        let mut call = Call::new();
        call.pull(0, &[voiced(7)]);
        call.report(20, &[info(7, "Ann")]);
        let at = SocketAddr::from(([127, 0, 0, 1], 5004));
        call.roster.ringing_at(&[at], call.at(20));
        assert_eq!(call.roster.views()[0].in_call_since, None, "ringing");
        call.report(5000, &[info(7, "Ann")]);
        assert_eq!(call.roster.views()[0].in_call_since, None, "still ringing");
        call.roster.ringing_at(&[], call.at(6000));
        call.roster.ringing_at(&[], call.at(7000));
        call.report(7020, &[info(7, "Ann")]);
        let view = &call.roster.views()[0];
        assert_eq!(view.in_call_since, Some(call.at(6000)), "answered at 6 s");
    }

    #[test]
    fn a_silent_member_is_seated_with_a_head_and_let_go_when_gone() {
        let mut call = Call::new();
        let bob = info(9, "Bob");
        call.roster
            .seat(&mut call.playback, std::slice::from_ref(&bob));
        call.report(200, &[bob]);
        let views = call.roster.views();
        assert_eq!(views.len(), 1, "a member who has said nothing is shown");
        assert_eq!(
            (views[0].name.as_str(), views[0].frames_received),
            ("Bob", 0)
        );
        let feed = views[0].feed;
        assert!(
            call.playback.peer_controls(feed).is_some(),
            "with his controls"
        );
        call.report(400, &[]);
        assert!(call.roster.is_empty(), "gone from the channel: let go");
        assert!(call.playback.peer_controls(feed).is_none());
    }

    #[test]
    fn a_peer_that_leaves_is_forgotten_with_its_mixer_slot_and_choices() {
        let mut call = Call::new();
        call.pull(0, &[voiced(7), voiced(8)]);
        call.roster.get_mut(PeerId::Ssrc(7)).unwrap().prefs.muted = true;
        let (feed7, feed8) = (
            call.roster.get(PeerId::Ssrc(7)).unwrap().feed(),
            call.roster.get(PeerId::Ssrc(8)).unwrap().feed(),
        );
        let mut ended = info(8, "Bob");
        ended.ended = true;
        call.report(200, &[info(7, "Ann"), ended]);
        assert!(
            call.roster.get(PeerId::Ssrc(8)).is_none(),
            "said goodbye and went quiet"
        );
        assert!(call.playback.peer_controls(feed8).is_none());
        assert!(
            call.roster.get(PeerId::Ssrc(7)).unwrap().prefs.muted,
            "Ann's choice stays"
        );

        call.report(400, &[]);
        assert!(call.roster.is_empty(), "the link no longer knows Ann");
        assert!(call.playback.peer_controls(feed7).is_none());

        call.pull(420, &[voiced(7)]);
        assert!(
            !call.roster.get(PeerId::Ssrc(7)).unwrap().prefs.muted,
            "back after leaving: a new peer with default choices"
        );
    }

    #[test]
    fn talking_holds_for_300_ms_after_the_last_voiced_frame() {
        let mut call = Call::new();
        call.pull(0, &[voiced(7)]);
        call.pull(20, &[frame(7, -60.0)]);
        let talking = |call: &mut Call, ms| {
            call.report(ms, &[info(7, "Ann")]);
            call.roster.views()[0].talking
        };
        assert!(talking(&mut call, 290));
        assert!(!talking(&mut call, 310), "a quiet frame is not voice");

        let mut call = Call::new();
        call.pull(0, &[frame(7, -60.0)]);
        assert!(!talking(&mut call, 10), "quiet from the start");
    }

    #[test]
    fn the_mixer_follows_a_peers_mute_and_volume() {
        let mut call = Call::new();
        call.pull(0, &[voiced(7)]);
        let peer = call.roster.get_mut(PeerId::Ssrc(7)).unwrap();
        peer.prefs.muted = true;
        peer.prefs.volume = 0.5;
        let feed = peer.feed();
        call.pull(20, &[voiced(7)]);
        let controls = call.playback.peer_controls(feed).unwrap();
        assert!(controls.muted());
        assert_eq!(controls.volume(), 0.5);
    }

    #[test]
    fn weights_follow_one_frame_behind_and_a_missing_frame_flushes_the_held_one() {
        let mut call = Call::new();
        for i in 0..10 {
            call.pull(20 * i, &[voiced(7)]);
        }
        assert_eq!(call.count(&call.counters.frames_animated), 10);
        assert_eq!(
            call.count(&call.counters.weights_sent),
            9,
            "the last frame waits for its look-ahead"
        );
        assert_eq!(call.count(&call.counters.weights_fallback), 0);

        call.pull(200, &[]);
        assert_eq!(call.count(&call.counters.weights_sent), 10);
        assert_eq!(call.count(&call.counters.weights_fallback), 1);
        // The UI finds a row for every sample of the ten frames (at the mixer's rate: the peer's
        // 8 kHz frames were resampled to it), and none elsewhere.
        let frame = call.playback.mix_rate() as usize / 50;
        assert_eq!(frame, 960);
        let schedule = &mut call.roster.get_mut(PeerId::Ssrc(7)).unwrap().schedule;
        let covered = (0..40 * frame as u64)
            .filter(|&pos| schedule.at(pos).is_some())
            .count();
        assert_eq!(covered, 10 * frame);
    }

    #[test]
    fn a_peer_with_animation_off_runs_no_network_and_schedules_nothing() {
        let mut call = Call::new();
        call.pull(0, &[voiced(7)]);
        call.pull(20, &[]);
        assert_eq!(call.count(&call.counters.frames_animated), 1);
        assert_eq!(call.count(&call.counters.weights_sent), 1);
        call.roster.get_mut(PeerId::Ssrc(7)).unwrap().prefs.animate = false;
        for i in 2..11 {
            call.pull(20 * i, &[voiced(7)]);
        }
        call.pull(220, &[]);
        assert_eq!(call.count(&call.counters.frames_animated), 1);
        assert_eq!(call.count(&call.counters.weights_sent), 1);
        call.report(240, &[info(7, "Ann")]);
        assert_eq!(call.roster.views()[0].frames_received, 10, "still played");
    }

    #[test]
    fn frames_the_output_does_not_take_are_counted_but_not_animated() {
        let mut call = Call::new();
        let now = call.at(0);
        call.roster
            .play(&mut call.playback, &[voiced(7)], None, now, &call.counters);
        assert_eq!(call.count(&call.counters.frames_animated), 0);
        call.report(20, &[info(7, "Ann")]);
        assert_eq!(call.roster.views()[0].frames_received, 1);
    }

    #[test]
    fn clearing_forgets_every_peer_and_frees_the_mixer() {
        let mut call = Call::new();
        let ssrcs = [1, 2, 3];
        let frames: Vec<PeerFrame> = ssrcs.iter().map(|&s| voiced(s)).collect();
        call.pull(0, &frames);
        let feeds: Vec<_> = ssrcs
            .iter()
            .map(|&s| call.roster.get(PeerId::Ssrc(s)).unwrap().feed())
            .collect();
        call.roster.clear(&mut call.playback);
        assert!(call.roster.is_empty());
        for feed in feeds {
            assert!(call.playback.peer_controls(feed).is_none());
        }
    }

    #[test]
    fn peers_keep_their_join_order_and_one_who_leaves_leaves_a_notice() {
        let mut call = Call::new();
        call.pull(0, &[voiced(900)]);
        call.pull(20, &[voiced(900), voiced(5)]);
        call.pull(40, &[voiced(900), voiced(5), voiced(77)]);
        call.report(200, &[info(900, "Zed"), info(5, "Amy"), info(77, "Bob")]);
        let names = |call: &Call| -> Vec<String> {
            call.roster.views().into_iter().map(|v| v.name).collect()
        };
        assert_eq!(
            names(&call),
            ["Zed", "Amy", "Bob"],
            "by join time, not SSRC"
        );
        assert!(call.roster.left(call.at(200)).is_empty());

        call.report(400, &[info(900, "Zed"), info(77, "Bob")]);
        assert_eq!(names(&call), ["Zed", "Bob"], "the others keep their places");
        assert_eq!(call.roster.left(call.at(400)), ["Amy"]);
        let later = call.at(400) + LEFT_NOTICE_STAYS - Duration::from_millis(100);
        assert_eq!(call.roster.left(later), ["Amy"], "the notice stays a while");
        assert!(
            call.roster
                .left(call.at(400) + LEFT_NOTICE_STAYS)
                .is_empty()
        );

        // The call's end says so itself: no notice per peer.
        call.roster.clear(&mut call.playback);
        assert!(call.roster.left(call.at(400)).is_empty());
    }

    #[test]
    fn a_level_rises_with_the_voice_and_falls_back_in_silence() {
        let mut call = Call::new();
        call.pull(0, &[voiced(7)]);
        call.report(20, &[info(7, "Ann")]);
        let level = |call: &Call| call.roster.views()[0].level_db;
        assert!(level(&call) > -30.0, "{}", level(&call));
        for i in 0..40 {
            call.pull(40 + i * 20, &[]);
        }
        call.report(900, &[info(7, "Ann")]);
        assert_eq!(level(&call), LEVEL_FLOOR_DB);
    }

    #[test]
    fn names_people_gave_are_shown_before_ids() {
        let with = |name: Option<&str>, cname: Option<&str>| PeerInfo {
            name: name.map(str::to_owned),
            cname: cname.map(str::to_owned),
            ..info(0x1234abcd, "x")
        };
        assert_eq!(shown_name(&with(Some("Ann"), Some("ann@h"))), "Ann");
        assert_eq!(
            shown_name(&with(Some("sip:bob@127.0.0.1:5080"), None)),
            "bob"
        );
        assert_eq!(
            shown_name(&with(Some("\"Bob Smith\" <sip:bob@pbx>"), None)),
            "Bob Smith"
        );
        assert_eq!(shown_name(&with(Some("<sip:+46812@pbx>"), None)), "+46812");
        assert_eq!(shown_name(&with(Some("  "), Some("ann@h"))), "ann@h");
        assert_eq!(shown_name(&with(None, None)), "peer 1234abcd");
    }
}
