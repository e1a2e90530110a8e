//! Measured lips as a second kind of truth: GRID clips through the codec paths, their lip
//! aperture and width as targets of a loss term on the network's convex weights (through the
//! head's own viseme shapes, so that what is trained is what a face shows), and the scores of
//! any animator against real lips.
//!
//! The network's weights become an aperture and a width through the design table's viseme
//! shapes ([`lip_aperture`], [`cues`]); s1's measured lips (in outer-eye distances) are mapped
//! onto that scale by an affine map whose mean and spread match what the phone-trained network
//! shows on his training clips. Pearson r, the score, does not depend on that map.

use std::sync::Arc;

use crate::call::pipeline::{PeerPipeline, run_stream};
use crate::lipsync::mouth::{Cue, cues, lip_aperture};
use crate::lipsync::network::Model;
use crate::lipsync::reproject::ReprojectError;
use crate::lipsync::{Animator, LipSyncOptions};
use crate::train::augment::{Rng, warp_frames};
use crate::train::codec_features::{CodecFeatures, CodecPath};
use crate::train::corpus::{BoxError, CorpusError};
use crate::train::eval::{pearson, predict_streams};
use crate::train::grid::LipClip;
use crate::vocab::{FrameFeatures, VisemeSet};

/// The measures trained and scored: aperture and width.
pub const LIP_CUES: usize = 2;

/// One clip's features through a codec path beside its lips (`None` untracked).
#[derive(Debug, Clone)]
pub struct VideoClip {
    /// The call the clip belongs to: s1's clips are one speaker, each other clip its own.
    pub speaker: String,
    pub name: String,
    pub features: Vec<FrameFeatures>,
    pub lips: Vec<Option<[f32; LIP_CUES]>>,
}

/// The video half of a training run.
#[derive(Debug, Clone)]
pub struct VideoTraining {
    /// Targets already shifted by the lag and mapped onto the head's scale.
    pub clips: Arc<Vec<VideoClip>>,
    /// Loss weight of a video frame against a phone-labelled frame's 1.
    pub frame_weight: f32,
    /// Weights of the squared aperture and width errors inside a video frame's loss.
    pub cue_weights: [f32; LIP_CUES],
}

/// Aperture and width the head shows for convex `weights` over `set`.
pub fn head_lips(set: &VisemeSet, weights: &[f32]) -> [f32; LIP_CUES] {
    [
        lip_aperture(set, weights),
        cues(set, weights)[Cue::Width as usize],
    ]
}

/// The call name of a clip of `set` (`s1` or another speaker's clip).
fn speaker_of(clip: &LipClip) -> String {
    if clip.set == "s1" {
        "grid-s1".into()
    } else {
        format!("grid-{}-{}", clip.set, clip.name)
    }
}

/// Each clip through one of `settings` (rotating, `versions` per clip), its lips `shift`
/// audio frames later (negative: earlier) than the frame they stand beside.
pub fn prepare_clips(
    codec: &CodecFeatures,
    clips: &[LipClip],
    settings: &[CodecPath],
    versions: usize,
    shift: i32,
) -> Result<Vec<VideoClip>, CorpusError> {
    let versions = versions.clamp(1, settings.len().max(1));
    let mut out = Vec::new();
    for (i, clip) in clips.iter().enumerate() {
        for k in 0..versions {
            let Some(&path) = settings.get((i * versions + k) % settings.len().max(1)) else {
                continue;
            };
            let mut features =
                codec
                    .features_through(&clip.wav, path)
                    .map_err(|source: BoxError| CorpusError::Features {
                        path: clip.wav.clone(),
                        source,
                    })?;
            let lips: Vec<Option<[f32; LIP_CUES]>> = (0..features.len())
                .map(|n| {
                    let m = usize::try_from(n as i64 + shift as i64).ok()?;
                    clip.lips
                        .get(m)
                        .copied()
                        .flatten()
                        .map(|l| [l.aperture, l.width])
                })
                .collect();
            features.truncate(clip.lips.len());
            let mut lips = lips;
            lips.truncate(features.len());
            out.push(VideoClip {
                speaker: speaker_of(clip),
                name: clip.name.clone(),
                features,
                lips,
            });
        }
    }
    Ok(out)
}

/// Makes each clip a call of its own (the speaker normalisation starts afresh in each, as
/// for a newcomer's first seconds), its LSPs scaled by its own random factor in
/// `[1 - warp, 1 + warp]` (a longer or shorter vocal tract; 0 leaves them).
pub fn vary_voices(clips: &mut [VideoClip], warp: f32, seed: u64) {
    let mut rng = Rng::new(seed);
    for (i, clip) in clips.iter_mut().enumerate() {
        if warp > 0.0 {
            warp_frames(&mut clip.features, warp, &mut rng);
        }
        clip.speaker = format!("{}-{i}", clip.speaker);
    }
}

/// Every second clip (with two codec versions a clip: one version of each) a call of its own,
/// as a newcomer's first seconds are, moved after the rest, which stay one long call, as later
/// in a call: a network taught both meets the speaker normalisation settled and unsettled.
pub fn mix_calls(clips: &mut Vec<VideoClip>) {
    let (long, mut own): (Vec<_>, Vec<_>) =
        clips.drain(..).enumerate().partition(|(i, _)| i % 2 == 0);
    for (i, clip) in &mut own {
        clip.speaker = format!("{}-{i}", clip.speaker);
    }
    clips.extend(long.into_iter().chain(own).map(|(_, clip)| clip));
}

/// Moves each clip's lips so that their mean is that of all clips, measure by measure: what
/// differs between recordings (the head turned a little, the camera nearer) is not what a
/// voice says, and the score (r within a clip) never sees it.
pub fn centre_each_clip(clips: &mut [VideoClip]) {
    let mean_of = |clips: &[VideoClip], cue: usize| {
        let (sum, n) = clips
            .iter()
            .flat_map(|c| c.lips.iter().flatten())
            .fold((0.0f64, 0usize), |(s, n), l| (s + l[cue] as f64, n + 1));
        (n > 0).then(|| (sum / n as f64) as f32)
    };
    for cue in 0..LIP_CUES {
        let Some(overall) = mean_of(clips, cue) else {
            return;
        };
        for clip in clips.iter_mut() {
            let Some(own) = mean_of(std::slice::from_ref(clip), cue) else {
                continue;
            };
            for lips in clip.lips.iter_mut().flatten() {
                lips[cue] += overall - own;
            }
        }
    }
}

fn streams(clips: &[VideoClip]) -> Vec<(&str, &[FrameFeatures])> {
    clips
        .iter()
        .map(|c| (c.speaker.as_str(), &c.features[..]))
        .collect()
}

/// Maps each clip's lips by `scale * x + offset`, per measure, so that their mean and spread
/// over all tracked frames equal those of what `animator` shows on the same frames.
pub fn map_onto_head(animator: &mut dyn Animator, clips: &mut [VideoClip]) -> [(f32, f32); 2] {
    let set = animator.visemes().clone();
    let k = set.len();
    let shown = predict_streams(animator, &streams(clips));
    let mut map = [(1.0, 0.0); LIP_CUES];
    for (cue, m) in map.iter_mut().enumerate() {
        let (mut head, mut video) = (Vec::new(), Vec::new());
        for (clip, weights) in clips.iter().zip(&shown) {
            for (n, lips) in clip.lips.iter().enumerate() {
                if let Some(lips) = lips {
                    head.push(head_lips(&set, &weights[n * k..(n + 1) * k])[cue] as f64);
                    video.push(lips[cue] as f64);
                }
            }
        }
        let (head_mean, head_sd) = mean_sd(&head);
        let (video_mean, video_sd) = mean_sd(&video);
        if video_sd > 0.0 && head_sd > 0.0 {
            let scale = head_sd / video_sd;
            *m = (scale as f32, (head_mean - scale * video_mean) as f32);
        }
    }
    for clip in clips.iter_mut() {
        for lips in clip.lips.iter_mut().flatten() {
            for (x, (scale, offset)) in lips.iter_mut().zip(map) {
                *x = scale * *x + offset;
            }
        }
    }
    map
}

fn mean_sd(x: &[f64]) -> (f64, f64) {
    let n = x.len().max(1) as f64;
    let mean = x.iter().sum::<f64>() / n;
    let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
    (mean, var.sqrt())
}

/// How well what an animator shows follows measured lips.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LipScores {
    /// Pearson r over all tracked frames of all clips together.
    pub aperture_r: f64,
    pub width_r: f64,
    /// The mean of the clips' own r.
    pub clip_aperture_r: f64,
    pub clip_width_r: f64,
    pub clips: usize,
    pub frames: usize,
}

/// What a face showed against the lips measured, frame by frame, pooled and per clip.
#[derive(Default)]
struct LipTally {
    pooled: [(Vec<f64>, Vec<f64>); LIP_CUES],
    clip: [(Vec<f64>, Vec<f64>); LIP_CUES],
    per_clip: [f64; LIP_CUES],
    clips: usize,
    frames: usize,
}

impl LipTally {
    fn frame(&mut self, shown: [f32; LIP_CUES], lips: &[f32; LIP_CUES]) {
        self.frames += 1;
        for cue in 0..LIP_CUES {
            for (h, v) in [&mut self.pooled[cue], &mut self.clip[cue]] {
                h.push(f64::from(shown[cue]));
                v.push(f64::from(lips[cue]));
            }
        }
    }

    fn end_clip(&mut self) {
        self.clips += 1;
        for (sum, (h, v)) in self.per_clip.iter_mut().zip(&mut self.clip) {
            *sum += pearson(h, v);
            h.clear();
            v.clear();
        }
    }

    fn scores(&self) -> LipScores {
        let clips = self.clips.max(1) as f64;
        LipScores {
            aperture_r: pearson(&self.pooled[0].0, &self.pooled[0].1),
            width_r: pearson(&self.pooled[1].0, &self.pooled[1].1),
            clip_aperture_r: self.per_clip[0] / clips,
            clip_width_r: self.per_clip[1] / clips,
            clips: self.clips,
            frames: self.frames,
        }
    }
}

/// Scores `animator` on `clips` (their lips unshifted: the face against the real face).
pub fn score_clips(animator: &mut dyn Animator, clips: &[VideoClip]) -> LipScores {
    let set = animator.visemes().clone();
    let k = set.len();
    let shown = predict_streams(animator, &streams(clips));
    let mut tally = LipTally::default();
    for (clip, weights) in clips.iter().zip(&shown) {
        for (n, lips) in clip.lips.iter().enumerate() {
            let Some(lips) = lips else { continue };
            tally.frame(head_lips(&set, &weights[n * k..(n + 1) * k]), lips);
        }
        tally.end_clip();
    }
    tally.scores()
}

/// Scores the controls (aperture, width) that `model`'s receiver gives each frame, as a head
/// driven by controls shows them, against `clips`' lips: one call per speaker, as
/// [`score_clips`] runs it. A score per lag in `lags`, the network run once: the controls of
/// frame n meet the lips of frame n + lag (0: as recorded; -1: lips a frame earlier, as for
/// lips that lead their sound).
pub fn score_controls(
    model: &Model,
    clips: &[VideoClip],
    lags: &[i32],
) -> Result<Vec<LipScores>, ReprojectError> {
    let mut pipeline = PeerPipeline::new(model, &LipSyncOptions::default(), 0, false)?;
    let mut current: Option<&str> = None;
    let mut tallies: Vec<LipTally> = lags.iter().map(|_| LipTally::default()).collect();
    for clip in clips {
        if current != Some(clip.speaker.as_str()) {
            pipeline.reset();
            current = Some(clip.speaker.as_str());
        }
        let mut shown = vec![None; clip.features.len()];
        run_stream(&mut pipeline, &clip.features, &[], |frame| {
            if let Some(slot) = shown.get_mut(frame.tag as usize) {
                *slot = Some([frame.controls.aperture, frame.controls.width]);
            }
        });
        for (&lag, tally) in lags.iter().zip(&mut tallies) {
            for (n, head) in shown.iter().enumerate() {
                let lips = n
                    .checked_add_signed(lag as isize)
                    .and_then(|m| clip.lips.get(m));
                if let (Some(Some(lips)), Some(head)) = (lips, head) {
                    tally.frame(*head, lips);
                }
            }
            tally.end_clip();
        }
    }
    Ok(tallies.iter().map(LipTally::scores).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lipsync::mouth::Articulation;
    use crate::vocab::Viseme;

    #[test]
    fn head_lips_follow_the_design_table() {
        let set = VisemeSet::parse("PP,FF,aa,I,U").unwrap();
        let aa = head_lips(&set, &[0.0, 0.0, 1.0, 0.0, 0.0]);
        assert_eq!(aa[0], Articulation::of(Viseme::Aa).lip_aperture);
        let mix = head_lips(&set, &[0.0, 0.0, 0.0, 0.5, 0.5]);
        let (i, u) = (Articulation::of(Viseme::I), Articulation::of(Viseme::U));
        assert!((mix[1] - 0.5 * (i.width + u.width)).abs() < 1e-6);
    }

    #[test]
    fn centred_clips_share_the_overall_mean_and_keep_their_motion() {
        let clip = |lips: Vec<Option<[f32; 2]>>| VideoClip {
            speaker: "grid-s1".into(),
            name: "c".into(),
            features: vec![FrameFeatures::silent(); lips.len()],
            lips,
        };
        let mut clips = vec![
            clip(vec![Some([0.1, 0.5]), None, Some([0.3, 0.7])]),
            clip(vec![Some([0.0, 0.4]), Some([0.2, 0.4]), Some([0.1, 0.4])]),
            clip(vec![None]),
        ];
        centre_each_clip(&mut clips);
        // Overall means over the five tracked frames: aperture 0.14, width 0.48.
        let a: Vec<[f32; 2]> = clips[0].lips.iter().flatten().copied().collect();
        let b: Vec<[f32; 2]> = clips[1].lips.iter().flatten().copied().collect();
        let close = |x: f32, y: f32| (x - y).abs() < 1e-6;
        assert!(close(a[0][0], 0.04) && close(a[1][0], 0.24), "{a:?}");
        assert!(close(a[0][1], 0.38) && close(a[1][1], 0.58), "{a:?}");
        assert!(close(b[0][0], 0.04) && close(b[2][0], 0.14), "{b:?}");
        assert!(b.iter().all(|l| close(l[1], 0.48)), "{b:?}");
        assert!(clips[1].lips[1].is_some());
        assert_eq!(clips[2].lips, vec![None]);
    }

    #[test]
    fn varied_voices_are_calls_of_their_own_with_their_own_tract() {
        let mut frame = FrameFeatures::silent();
        frame.lsp = std::array::from_fn(|i| 0.25 * (i + 1) as f32);
        let clip = VideoClip {
            speaker: "grid-s1".into(),
            name: "bbaf2n".into(),
            features: vec![frame; 4],
            lips: vec![Some([0.1, 0.5]); 4],
        };
        let mut clips = vec![clip.clone(); 3];
        vary_voices(&mut clips, 0.1, 7);
        let names: Vec<&str> = clips.iter().map(|c| c.speaker.as_str()).collect();
        assert_eq!(names, ["grid-s1-0", "grid-s1-1", "grid-s1-2"]);
        let factors: Vec<f32> = clips
            .iter()
            .map(|c| c.features[0].lsp[0] / frame.lsp[0])
            .collect();
        for (c, f) in clips.iter().zip(&factors) {
            assert!((0.9..=1.1).contains(f), "{f}");
            assert!(c.features.iter().all(|x| x.lsp == c.features[0].lsp));
            assert!(c.features[0].lsp.windows(2).all(|w| w[0] < w[1]));
            assert_eq!(c.lips, clip.lips);
        }
        assert!(factors[0] != factors[1] && factors[1] != factors[2]);
        let mut unwarped = vec![clip.clone(); 2];
        vary_voices(&mut unwarped, 0.0, 7);
        assert_eq!(unwarped[1].features, clip.features);
        assert_eq!(unwarped[1].speaker, "grid-s1-1");
    }

    #[test]
    fn mixed_calls_keep_half_the_clips_one_call_and_give_the_rest_their_own() {
        let clip = |name: &str| VideoClip {
            speaker: "grid-s1".into(),
            name: name.into(),
            features: vec![FrameFeatures::silent(); 2],
            lips: vec![None; 2],
        };
        let mut clips: Vec<VideoClip> = ["a", "a", "b", "b", "c"].map(clip).into();
        mix_calls(&mut clips);
        let order: Vec<(&str, &str)> = clips
            .iter()
            .map(|c| (c.name.as_str(), c.speaker.as_str()))
            .collect();
        assert_eq!(
            order,
            [
                ("a", "grid-s1"),
                ("b", "grid-s1"),
                ("c", "grid-s1"),
                ("a", "grid-s1-1"),
                ("b", "grid-s1-3")
            ]
        );
    }

    /// `evaluate --grid`'s "network's controls" row: the receiver's own width, frame by frame,
    /// one call per speaker; the lips of frame n + lag meet the controls of frame n.
    #[test]
    fn the_controls_score_reads_the_receivers_width_per_frame_and_lag() {
        use crate::call::pipeline::stream_track;
        use crate::lipsync::animator::articulation_beside;
        use crate::lipsync::default_model;

        let plain = default_model();
        let paired = plain
            .clone()
            .with_articulation(articulation_beside(&plain, 0.5))
            .unwrap();
        let mut rng = Rng::new(11);
        let talk = |rng: &mut Rng| -> Vec<FrameFeatures> {
            (0..80)
                .map(|n| {
                    let mut f = FrameFeatures::silent();
                    f.energy_db = -45.0 + 35.0 * rng.next_f32();
                    f.lsp = std::array::from_fn(|i| 0.27 * (i + 1) as f32 + 0.02 * (n % 5) as f32);
                    f
                })
                .collect()
        };
        let features = [talk(&mut rng), talk(&mut rng)];
        // The second clip follows the first in one call, as the score runs them.
        let mut pipeline =
            PeerPipeline::new(&paired, &LipSyncOptions::default(), 0, false).unwrap();
        let own: Vec<Vec<[f32; 2]>> = features
            .iter()
            .map(|f| {
                let track = stream_track(&mut pipeline, f, &[]);
                assert_eq!(track.controls.len(), f.len());
                track
                    .controls
                    .iter()
                    .map(|c| [c.aperture, c.width])
                    .collect()
            })
            .collect();
        let clips_trailing = |by: usize, sign: f32| -> Vec<VideoClip> {
            own.iter()
                .zip(&features)
                .enumerate()
                .map(|(c, (own, f))| VideoClip {
                    speaker: "grid-s1".into(),
                    name: format!("c{c}"),
                    features: f.clone(),
                    lips: (0..own.len())
                        .map(|n| {
                            let [a, w] = own[n.checked_sub(by)?];
                            // Every 7th frame untracked; each clip at its own offset and scale.
                            (n % 7 != 3).then_some([0.1 + a, 0.5 + c as f32 + sign * 3.0 * w])
                        })
                        .collect(),
                })
                .collect()
        };
        let at = |model: &Model, clips: &[VideoClip], lags: &[i32]| {
            score_controls(model, clips, lags).unwrap()
        };
        let [same] = &at(&paired, &clips_trailing(0, 1.0), &[0])[..] else {
            panic!("a score per lag")
        };
        assert_eq!((same.clips, same.frames), (2, 2 * (80 - 11)));
        assert!(
            same.clip_width_r > 0.999 && same.clip_aperture_r > 0.999,
            "{same:?}"
        );
        assert!(same.width_r < 0.9, "pooled over two offsets: {same:?}");
        let [flipped] = &at(&paired, &clips_trailing(0, -1.0), &[0])[..] else {
            panic!("a score per lag")
        };
        assert!(flipped.clip_width_r < -0.999, "{flipped:?}");
        let trailing = clips_trailing(1, 1.0);
        let [on_time, a_frame_on, a_frame_back] = &at(&paired, &trailing, &[0, 1, -1])[..] else {
            panic!("a score per lag")
        };
        assert!(a_frame_on.clip_width_r > 0.999, "{a_frame_on:?}");
        assert!(on_time.clip_width_r < 0.9 && a_frame_back.clip_width_r < 0.9);
        // The viseme network alone shows the width its weights derive, not the articulation's.
        let [alone] = &at(&plain, &clips_trailing(0, 1.0), &[0])[..] else {
            panic!("a score per lag")
        };
        assert!(
            alone.clip_width_r < 0.9 && alone.clip_aperture_r > 0.999,
            "{alone:?}"
        );
    }
}
