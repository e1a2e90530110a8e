//! One peer's receive pipeline past the decoder: each decoded 20 ms frame (its features and
//! samples) becomes that frame's viseme weights ([`LipSync`]: look-ahead, the rest in digital
//! silence, re-projection, the fallback flush) and the living face's pose ([`LifeGenerator`]),
//! both tagged with the frame's stream position so a player shows them with the audio they
//! belong to. The app, `receive`, `animate` and evaluation all run this one pipeline: real-time
//! callers push frames as they are decoded, offline ones hand a whole stream to [`run_stream`].

use crate::lipsync::controls::Controls;
use crate::lipsync::life::{DEFAULT_SEED, LifeGenerator};
use crate::lipsync::network::{MAX_LOOKAHEAD, Model};
use crate::lipsync::reproject::ReprojectError;
use crate::lipsync::{Animator, LipSync, LipSyncOptions};
use crate::vocab::{FRAME_SIZE, FacePose, FrameFeatures, FullWeights, VisemeSet};

/// Poses kept for frames whose weights the look-ahead still holds back.
const POSE_RING: usize = MAX_LOOKAHEAD + 4;

/// What a head shows for one 20 ms frame of a peer's audio: the mouth's weights over all 15
/// visemes and the living face's pose (at rest when it is off), scheduled together so both are
/// shown with the audio they belong to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaceRow {
    pub weights: FullWeights,
    /// The same frame's articulatory controls ([`LipSync::controls`]), for heads driven by
    /// controls rather than visemes.
    pub controls: Controls,
    pub pose: FacePose,
}

/// One frame out of the pipeline: its tag, its weights over [`PeerPipeline::visemes`], its pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Animated<'a> {
    pub tag: u64,
    pub weights: &'a [f32],
    pub controls: Controls,
    pub pose: FacePose,
}

/// The living face of one peer, stepped once per decoded frame while it is on.
struct Life {
    generator: LifeGenerator,
    on: bool,
    /// The generator ran on the previous frame (so a face switched back on starts at rest).
    running: bool,
    /// (tag, pose) of the latest frames, to pair each frame's pose with its weights, which come
    /// out after the look-ahead.
    poses: [(u64, FacePose); POSE_RING],
    next: usize,
}

impl Life {
    fn new(seed: u64, on: bool) -> Self {
        Self {
            generator: LifeGenerator::new(seed),
            on,
            running: false,
            poses: [(u64::MAX, FacePose::REST); POSE_RING],
            next: 0,
        }
    }

    fn step(&mut self, tag: u64, features: &FrameFeatures, pcm: &[i16]) {
        let pose = if self.on {
            if !self.running {
                self.generator.settle();
            }
            self.generator.step_frame(features, pcm)
        } else {
            FacePose::REST
        };
        self.running = self.on;
        self.poses[self.next] = (tag, pose);
        self.next = (self.next + 1) % POSE_RING;
    }

    /// The pose made for frame `tag` (at rest if none was).
    fn pose(&self, tag: u64) -> FacePose {
        self.poses
            .iter()
            .find(|(t, _)| *t == tag)
            .map_or(FacePose::REST, |(_, pose)| *pose)
    }
}

/// One peer's frames to tagged weights and poses. `A` is the animator: the model's or the jaw's
/// by default (built from [`LipSyncOptions`]); evaluation hands in its own.
pub struct PeerPipeline<'m, A: Animator + ?Sized = dyn Animator + Send + 'm> {
    lipsync: LipSync<'m, A>,
    life: Life,
}

impl<'m> PeerPipeline<'m> {
    /// `model` driven as `options` say, with the living face seeded by `seed` (on or off as
    /// `life` says; off, every pose is [`FacePose::REST`] and the generator does not run).
    pub fn new(
        model: &'m Model,
        options: &LipSyncOptions,
        seed: u64,
        life: bool,
    ) -> Result<Self, ReprojectError> {
        Ok(Self {
            lipsync: LipSync::new(model, options)?,
            life: Life::new(seed, life),
        })
    }

    /// The viewer changed the viseme set, the mode or the closures: a new lip sync (the frames
    /// it still held are dropped), while the face lives on.
    pub fn rebuild(
        &mut self,
        model: &'m Model,
        options: &LipSyncOptions,
    ) -> Result<(), ReprojectError> {
        self.lipsync = LipSync::new(model, options)?;
        Ok(())
    }
}

impl<'m, A: Animator + ?Sized> PeerPipeline<'m, A> {
    /// Around a lip sync made elsewhere (evaluation's animator), the living face off.
    pub fn with_lipsync(lipsync: LipSync<'m, A>) -> Self {
        Self {
            lipsync,
            life: Life::new(DEFAULT_SEED, false),
        }
    }

    /// The set the weights are expressed over.
    pub fn visemes(&self) -> &VisemeSet {
        self.lipsync.visemes()
    }

    /// Frames of look-ahead: a frame comes out this many pushes after its own.
    pub fn lookahead(&self) -> usize {
        self.lipsync.lookahead()
    }

    /// Turns the living face on or off from the next frame on (back on, it starts at rest).
    pub fn set_life(&mut self, on: bool) {
        self.life.on = on;
    }

    /// A frame went by without the pipeline (the viewer turned animation off): when the face
    /// runs again it starts at rest.
    pub fn pause_life(&mut self) {
        self.life.running = false;
    }

    /// Starts a new stream (another speaker): forgets the history and any frame still waiting;
    /// the face lives on.
    pub fn reset(&mut self) {
        self.lipsync.reset();
    }

    /// Feeds one decoded frame (its features and its samples, 160 or fewer), tagged with its
    /// stream position. Returns the frame the look-ahead has now completed, unless
    /// [`PeerPipeline::flush`] gave it out already. Allocates nothing.
    pub fn push(
        &mut self,
        tag: u64,
        features: &FrameFeatures,
        pcm: &[i16],
    ) -> Option<Animated<'_>> {
        self.life.step(tag, features, pcm);
        let (tag, weights, controls) = self.lipsync.push_with_controls(tag, features)?;
        Some(Animated {
            tag,
            weights,
            controls,
            pose: self.life.pose(tag),
        })
    }

    /// The oldest frame still waiting for its look-ahead, now: the next frame did not come in
    /// time (loss, the end of a talk spurt, the jitter buffer at its floor, the stream's end).
    pub fn flush(&mut self) -> Option<Animated<'_>> {
        let (tag, weights, controls) = self.lipsync.flush_with_controls()?;
        Some(Animated {
            tag,
            weights,
            controls,
            pose: self.life.pose(tag),
        })
    }

    /// [`PeerPipeline::push`] as a head takes it: the weights over all 15 visemes.
    pub fn push_face(
        &mut self,
        tag: u64,
        features: &FrameFeatures,
        pcm: &[i16],
    ) -> Option<(u64, FaceRow)> {
        self.life.step(tag, features, pcm);
        let (tag, weights) = self.lipsync.push_full(tag, features)?;
        Some((tag, self.face(tag, weights)))
    }

    /// [`PeerPipeline::flush`] as a head takes it.
    pub fn flush_face(&mut self) -> Option<(u64, FaceRow)> {
        let (tag, weights) = self.lipsync.flush_full()?;
        Some((tag, self.face(tag, weights)))
    }

    fn face(&self, tag: u64, weights: FullWeights) -> FaceRow {
        FaceRow {
            weights,
            controls: self.lipsync.controls(),
            pose: self.life.pose(tag),
        }
    }
}

/// A whole stream through a pipeline as a receiver runs it: every frame pushed in order
/// (tagged with its index, given its 160 samples of `pcm` where there are any), then the frames
/// still waiting for their future flushed. `each` sees every frame once, in order.
pub fn run_stream<A: Animator + ?Sized>(
    pipeline: &mut PeerPipeline<'_, A>,
    features: &[FrameFeatures],
    pcm: &[i16],
    mut each: impl FnMut(Animated<'_>),
) {
    for (n, f) in features.iter().enumerate() {
        let samples = pcm.get(n * FRAME_SIZE..(n + 1) * FRAME_SIZE).unwrap_or(&[]);
        if let Some(out) = pipeline.push(n as u64, f, samples) {
            each(out);
        }
    }
    while let Some(out) = pipeline.flush() {
        each(out);
    }
}

/// The weights (over the pipeline's set) and poses of every frame of a stream.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Track {
    pub rows: Vec<Vec<f32>>,
    /// Each row's articulatory controls ([`LipSync::controls`]).
    pub controls: Vec<Controls>,
    /// The living face's pose of each row; empty when it is off.
    pub poses: Vec<FacePose>,
}

/// [`run_stream`], collected.
pub fn stream_track<A: Animator + ?Sized>(
    pipeline: &mut PeerPipeline<'_, A>,
    features: &[FrameFeatures],
    pcm: &[i16],
) -> Track {
    let life = pipeline.life.on;
    let mut track = Track {
        rows: Vec::with_capacity(features.len()),
        controls: Vec::with_capacity(features.len()),
        poses: Vec::with_capacity(if life { features.len() } else { 0 }),
    };
    run_stream(pipeline, features, pcm, |out| {
        track.rows.push(out.weights.to_vec());
        track.controls.push(out.controls);
        if life {
            track.poses.push(out.pose);
        }
    });
    track
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vocab::{FeatureFamily, SAMPLE_RATE};

    /// Talking: syllables with pauses, as 160-sample frames with their features.
    fn speech(frames: usize) -> (Vec<FrameFeatures>, Vec<i16>) {
        let pcm: Vec<i16> = (0..frames * FRAME_SIZE)
            .map(|i| {
                let n = i / FRAME_SIZE;
                if n % 12 >= 9 {
                    return 0;
                }
                let t = i as f32 / SAMPLE_RATE as f32;
                let p = 2.0 * std::f32::consts::PI * (120.0 + 2.0 * (n % 12) as f32) * t;
                (6000.0 * (p.sin() + 0.4 * (2.0 * p).sin())) as i16
            })
            .collect();
        let features = pcm
            .chunks(FRAME_SIZE)
            .enumerate()
            .map(|(n, c)| {
                let mut lsp = crate::vocab::flat_lsp();
                lsp[0] += 0.02 * (n % 7) as f32;
                FrameFeatures {
                    mode: Some(5),
                    lsp,
                    energy_db: crate::vocab::energy_db(c),
                    family: FeatureFamily::Bitstream,
                }
            })
            .collect();
        (features, pcm)
    }

    #[test]
    fn a_stream_gives_every_frame_once_with_the_pose_made_for_it() {
        let model = crate::lipsync::default_model();
        let (features, pcm) = speech(300);
        let mut pipeline = PeerPipeline::new(&model, &LipSyncOptions::default(), 3, true).unwrap();
        let track = stream_track(&mut pipeline, &features, &pcm);
        assert_eq!(track.rows.len(), features.len());
        // The poses are the living face's own, frame by frame, whatever the look-ahead.
        let mut life = LifeGenerator::new(3);
        let poses: Vec<FacePose> = features
            .iter()
            .zip(pcm.chunks(FRAME_SIZE))
            .map(|(f, c)| life.step_frame(f, c))
            .collect();
        assert_eq!(track.poses, poses);
        // And the weights are the lip sync's.
        let mut lipsync = LipSync::new(&model, &LipSyncOptions::default()).unwrap();
        let mut rows = Vec::new();
        for (n, f) in features.iter().enumerate() {
            rows.extend(lipsync.push(n as u64, f).map(|(_, w)| w.to_vec()));
        }
        while let Some((_, w)) = lipsync.flush() {
            rows.push(w.to_vec());
        }
        assert_eq!(track.rows, rows);
    }

    #[test]
    fn with_the_face_off_no_pose_is_made() {
        let model = crate::lipsync::default_model();
        let (features, pcm) = speech(20);
        let mut pipeline = PeerPipeline::new(&model, &LipSyncOptions::default(), 3, false).unwrap();
        let track = stream_track(&mut pipeline, &features, &pcm);
        assert!(track.poses.is_empty());
        pipeline.reset();
        let (_, row) = pipeline
            .push_face(0, &features[0], &pcm[..FRAME_SIZE])
            .or_else(|| pipeline.flush_face())
            .unwrap();
        assert_eq!(row.pose, FacePose::REST);
    }

    #[test]
    fn a_borrowed_animator_runs_the_same_pipeline() {
        let model = crate::lipsync::default_model();
        let (features, pcm) = speech(60);
        let mut own = PeerPipeline::new(&model, &LipSyncOptions::default(), 0, false).unwrap();
        let expected = stream_track(&mut own, &features, &pcm).rows;
        let mut animator = crate::lipsync::ModelAnimator::new(&model);
        let borrowed: Box<dyn Animator + '_> = Box::new(&mut animator);
        let mut pipeline =
            PeerPipeline::with_lipsync(LipSync::with_animator(borrowed, None).unwrap());
        assert_eq!(stream_track(&mut pipeline, &features, &[]).rows, expected);
    }
}
