//! One remote peer of a call, whole: what the UI shows of it and chooses for it, its slot in
//! the mixer, its weights on the playback clock, and its animation. The call's peers are a
//! [`super::roster::Roster`] of these.

use std::net::SocketAddr;
use std::time::Instant;

use crate::audio::{PeerFeed, PeerId, Schedule, ScheduleSender};
pub use crate::call::pipeline::FaceRow;
use crate::call::pipeline::PeerPipeline;
use crate::codec::any::Codec;
use crate::lipsync::LipSyncOptions;
use crate::lipsync::life::DEFAULT_SEED;
use crate::net::jitter::JitterStats;
use crate::net::transport;
use crate::vocab::{FrameFeatures, VisemeSet};

use super::settings::PeerPrefs;

/// Weights scheduled ahead of the heard position, per peer.
const SCHEDULE_ROWS: usize = 256;

/// Everything the app keeps for one remote peer, from its first frame until it leaves; the
/// engine thread and the UI reach it under [`super::engine::Shared`]'s lock.
pub struct RemotePeer {
    /// What the UI shows; `None` until the link has described the peer (within 200 ms).
    pub view: Option<PeerView>,
    /// Its choices: the UI edits them, the engine follows them.
    pub prefs: PeerPrefs,
    /// The choices saved under its name were applied (once the name was known).
    pub saved_prefs_applied: bool,
    /// UI frames that showed weights for it.
    pub frames_shown: u64,
    /// Its weights, tagged with stream positions, for the UI to pick by the position heard.
    pub schedule: Schedule<FaceRow>,
    pub(super) feed: PeerFeed,
    pub(super) weights: ScheduleSender<FaceRow>,
    pub(super) animation: PeerAnimation,
    pub(super) last_voice: Option<Instant>,
    /// Its voice's level now: each frame's energy, falling back slowly (dBFS).
    pub(super) level_db: f32,
    /// When it was first heard or seated: tiles are shown in this order.
    pub(super) joined: Instant,
    /// Since when it is in the call: `None` for a direct caller still ringing.
    pub(super) in_call_since: Option<Instant>,
    pub(super) frames_received: u64,
    /// It had a frame in the last pull (its audio runs on in its queue).
    pub(super) playing: bool,
}

impl RemotePeer {
    /// A peer heard for the first time, with its mixer slot; its living face is seeded by its
    /// id, so two peers do not blink together.
    pub(super) fn new(id: transport::PeerId, feed: PeerFeed) -> Self {
        let prefs = PeerPrefs::default();
        let (weights, schedule) = Schedule::channel_with_rows(SCHEDULE_ROWS, feed.frame_len());
        Self {
            view: None,
            animation: PeerAnimation::with_seed(&prefs, u64::from(id.number())),
            prefs,
            saved_prefs_applied: false,
            frames_shown: 0,
            schedule,
            feed,
            weights,
            last_voice: None,
            level_db: LEVEL_FLOOR_DB,
            joined: Instant::now(),
            in_call_since: Some(Instant::now()),
            frames_received: 0,
            playing: false,
        }
    }

    /// Its slot in the mixer.
    pub fn feed(&self) -> PeerId {
        self.feed.id()
    }
}

/// What a peer's level meter reads in silence (dBFS).
pub const LEVEL_FLOOR_DB: f32 = -60.0;

/// One remote peer as the UI shows it.
#[derive(Debug, Clone)]
pub struct PeerView {
    pub peer: transport::PeerId,
    pub name: String,
    /// `name` is the peer's own (SDES NAME), not its CNAME or SSRC, which change with every
    /// run: only a named peer's choices are saved.
    pub named: bool,
    pub addr: SocketAddr,
    pub feed: PeerId,
    pub is_demo: bool,
    /// The codec of its last packet.
    pub codec: Option<Codec>,
    pub talking: bool,
    /// Its voice's level now (dBFS; [`LEVEL_FLOOR_DB`] in silence).
    pub level_db: f32,
    /// When it was first heard: the order of the tiles.
    pub joined: Instant,
    /// Since when it is in the call (its tile's timer): `None` while a direct caller rings.
    pub in_call_since: Option<Instant>,
    pub loss_percent: f64,
    pub jitter_ms: f64,
    pub delay_ms: f64,
    /// Frames the network (or jaw baseline) turned into weights.
    pub frames_animated: u64,
    pub frames_received: u64,
    /// Its lost frames rebuilt from the next packet's FEC (Opus).
    pub frames_recovered: u64,
    /// Its packets of a payload type no codec is mapped to (dropped).
    pub unknown_payload: u64,
    /// Its decoded audio waiting for the mixer, in ms.
    pub queued_ms: f64,
    /// Its jitter buffer's counts (delay, drift, frames inserted and dropped).
    pub buffer: JitterStats,
}

/// The choices an animator is built from; a change rebuilds it.
#[derive(Debug, Clone, PartialEq)]
struct AnimationKey {
    visemes: String,
    jaw: bool,
    closures: f32,
}

impl AnimationKey {
    fn of(prefs: &PeerPrefs) -> Self {
        Self {
            visemes: prefs.visemes.clone(),
            jaw: prefs.jaw,
            closures: prefs.closures,
        }
    }

    fn matches(&self, prefs: &PeerPrefs) -> bool {
        self.visemes == prefs.visemes && self.jaw == prefs.jaw && self.closures == prefs.closures
    }
}

/// One peer's decoded frames through the one per-peer pipeline ([`PeerPipeline`]: weights over
/// the chosen viseme set and, with the living face on, poses), or nothing at all when the peer's
/// animation is off.
pub struct PeerAnimation {
    pipeline: Option<PeerPipeline<'static>>,
    key: AnimationKey,
    pub frames_animated: u64,
}

impl PeerAnimation {
    /// With the living face seeded by [`DEFAULT_SEED`].
    pub fn new(prefs: &PeerPrefs) -> Self {
        Self::with_seed(prefs, DEFAULT_SEED)
    }

    /// With the living face seeded by `seed` (the app uses the peer's id, so two peers do not
    /// blink together).
    pub fn with_seed(prefs: &PeerPrefs, seed: u64) -> Self {
        let model = crate::lipsync::builtin::shipped();
        let pipeline = fallback(prefs, |options| {
            PeerPipeline::new(model, options, seed, prefs.life)
        });
        Self {
            pipeline,
            key: AnimationKey::of(prefs),
            frames_animated: 0,
        }
    }

    /// The viseme set the weights are expressed over.
    pub fn target(&self) -> Option<&VisemeSet> {
        self.pipeline.as_ref().map(PeerPipeline::visemes)
    }

    /// Feeds one decoded frame (its features and its 160 samples), tagged with its stream
    /// position. Returns the weights of the frame the network's look-ahead has now completed,
    /// with that frame's pose and tag, or `None` (and neither network nor living face runs when
    /// animation is off). Allocates nothing.
    pub fn step(
        &mut self,
        prefs: &PeerPrefs,
        tag: u64,
        features: &FrameFeatures,
        pcm: &[i16],
    ) -> Option<(u64, FaceRow)> {
        if !self.key.matches(prefs) {
            // The face keeps living through a change of viseme set or mode.
            let model = crate::lipsync::builtin::shipped();
            if let Some(pipeline) = &mut self.pipeline
                && fallback(prefs, |options| pipeline.rebuild(model, options)).is_none()
            {
                self.pipeline = None;
            }
            self.key = AnimationKey::of(prefs);
        }
        let pipeline = self.pipeline.as_mut()?;
        if !prefs.animate {
            pipeline.pause_life();
            return None;
        }
        self.frames_animated += 1;
        pipeline.set_life(prefs.life);
        pipeline.push_face(tag, features, pcm)
    }

    /// The oldest frame still waiting for its look-ahead, now: the peer's next frame did not
    /// come in time (loss, end of a talk spurt, the jitter buffer at its floor).
    pub fn flush(&mut self) -> Option<(u64, FaceRow)> {
        self.pipeline.as_mut()?.flush_face()
    }
}

/// `make` with the peer's choices, or, where the shapes cannot express the chosen set, with the
/// network's own set.
fn fallback<T, E>(
    prefs: &PeerPrefs,
    mut make: impl FnMut(&LipSyncOptions) -> Result<T, E>,
) -> Option<T> {
    let options = LipSyncOptions {
        jaw: prefs.jaw,
        closure_bias: prefs.closures,
        visemes: VisemeSet::parse(&prefs.visemes).ok(),
    };
    make(&options)
        .or_else(|_| {
            make(&LipSyncOptions {
                visemes: None,
                ..options
            })
        })
        .ok()
}
