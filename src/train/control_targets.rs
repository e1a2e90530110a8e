//! The articulatory training targets of lip-sync v4 (issue 47): per 20 ms frame, [`Controls`]
//! and which of them are known. Phone-labelled voices (TIMIT, AN4) take each viseme's measured
//! controls (`lipsync::viseme_controls`: s1's lips per viseme) through the coarticulated phone
//! weights; s1's own video frames take their aperture and width from his tracked lips, the jaw
//! from that aperture, and rounding, closure and the lower lip's tuck from his aligned phones.

use std::path::Path;
use std::sync::Arc;

use crate::lipsync::controls::{CONTROL_COUNT, Controls};
use crate::lipsync::viseme_controls::{CONTROL_SPREAD, from_full, jaw_from_aperture};
use crate::train::corpus::{CorpusError, UtteranceTargets, read_phones, targets_from_phones};
use crate::train::grid_shapes::PHONE_RATE;
use crate::train::video::{LIP_CUES, VideoClip};
use crate::vocab::{FrameFeatures, FullWeights, Viseme};

/// One video clip's features and per-frame control targets.
#[derive(Debug, Clone)]
pub struct ControlClip {
    /// The call it belongs to (the speaker normalisation carries over within one).
    pub speaker: String,
    pub name: String,
    pub features: Vec<FrameFeatures>,
    pub targets: Vec<Option<ControlTarget>>,
}

/// The video half of a control network's training.
#[derive(Debug, Clone)]
pub struct ControlVideo {
    pub clips: Arc<Vec<ControlClip>>,
    /// Loss weight of a video frame against a phone-labelled frame's 1.
    pub frame_weight: f32,
}

/// Control targets of clips whose lips are still as measured (eye widths), with each clip's
/// phones from `alignments` (`NAME.phn`) where it has them.
pub fn control_clips(
    clips: &[VideoClip],
    alignments: Option<&Path>,
) -> Result<Vec<ControlClip>, CorpusError> {
    clips
        .iter()
        .map(|clip| {
            let phones = match alignments {
                Some(dir) => aligned_weights(dir, &clip.name)?,
                None => None,
            };
            Ok(ControlClip {
                speaker: clip.speaker.clone(),
                name: clip.name.clone(),
                features: clip.features.clone(),
                targets: video_controls(&clip.lips, phones.as_deref()),
            })
        })
        .collect()
}

/// One frame's target: the controls, and per control 1 where it is known, 0 where not.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControlTarget {
    pub values: [f32; CONTROL_COUNT],
    pub known: [f32; CONTROL_COUNT],
}

/// Every control of a phone-labelled frame, from its coarticulated viseme weights.
pub fn phone_controls(targets: &UtteranceTargets) -> Vec<ControlTarget> {
    targets
        .weights
        .iter()
        .map(|w| ControlTarget {
            values: from_full(w).to_array(),
            known: [1.0; CONTROL_COUNT],
        })
        .collect()
}

/// A silence frame in the phone weights: the clip's rest is measured there.
const SILENT_WEIGHT: f32 = 0.5;

/// A video clip's targets from its measured lips (aperture, width; eye widths, absolute) and,
/// where known, its frames' coarticulated phone weights. The lips are taken above the clip's
/// rest: their mean over its silent frames by the phones, else its 10th-percentile aperture and
/// median width. Untracked frames have no target.
pub fn video_controls(
    lips: &[Option<[f32; LIP_CUES]>],
    phones: Option<&[FullWeights]>,
) -> Vec<Option<ControlTarget>> {
    let Some(rest) = rest_of(lips, phones) else {
        return vec![None; lips.len()];
    };
    lips.iter()
        .enumerate()
        .map(|(n, l)| {
            let l = (*l)?;
            let aperture = l[0] - rest[0];
            let mut values = Controls {
                aperture,
                width: l[1] - rest[1],
                jaw: jaw_from_aperture(aperture),
                ..Controls::default()
            }
            .to_array();
            let mut known = [1.0, 1.0, 1.0, 0.0, 0.0, 0.0];
            if let Some(w) = phones.and_then(|p| p.get(n)) {
                let from_phones = from_full(w).to_array();
                values[3..].copy_from_slice(&from_phones[3..]);
                known[3..].fill(1.0);
            }
            Some(ControlTarget { values, known })
        })
        .collect()
}

fn rest_of(
    lips: &[Option<[f32; LIP_CUES]>],
    phones: Option<&[FullWeights]>,
) -> Option<[f32; LIP_CUES]> {
    if let Some(phones) = phones {
        let silent: Vec<[f32; LIP_CUES]> = lips
            .iter()
            .zip(phones)
            .filter(|(_, w)| w[Viseme::Sil.index()] >= SILENT_WEIGHT)
            .filter_map(|(l, _)| *l)
            .collect();
        if !silent.is_empty() {
            let n = silent.len() as f32;
            return Some(std::array::from_fn(|k| {
                silent.iter().map(|l| l[k]).sum::<f32>() / n
            }));
        }
    }
    let tracked: Vec<[f32; LIP_CUES]> = lips.iter().flatten().copied().collect();
    if tracked.is_empty() {
        return None;
    }
    let quantile = |k: usize, q: f32| {
        let mut v: Vec<f32> = tracked.iter().map(|l| l[k]).collect();
        v.sort_by(f32::total_cmp);
        v[((v.len() - 1) as f32 * q).round() as usize]
    };
    Some([quantile(0, 0.1), quantile(1, 0.5)])
}

/// The coarticulated phone weights of a GRID clip from its alignment (`DIR/NAME.phn`, 16 kHz
/// samples from 0 to the clip's end); `None` when the clip has no alignment.
pub fn aligned_weights(dir: &Path, name: &str) -> Result<Option<Vec<FullWeights>>, CorpusError> {
    let path = dir.join(format!("{name}.phn"));
    if !path.is_file() {
        return Ok(None);
    }
    let phones = read_phones(&path)?;
    let samples = phones.iter().map(|p| p.end).max().unwrap_or(0);
    let samples = u32::try_from(samples).unwrap_or(u32::MAX);
    let targets =
        targets_from_phones(&phones, PHONE_RATE as u32, samples).map_err(|(line, source)| {
            CorpusError::UnknownPhone {
                path: path.clone(),
                line,
                source,
            }
        })?;
    Ok(Some(targets.weights))
}

/// Each control's spread over `targets` (where known), floored at a quarter of its usual
/// spread ([`CONTROL_SPREAD`]) so a control the data hardly moves cannot dominate the loss.
pub fn spreads(targets: &[ControlTarget]) -> [f32; CONTROL_COUNT] {
    std::array::from_fn(|c| {
        let (mut n, mut sum, mut sum2) = (0.0f64, 0.0f64, 0.0f64);
        for t in targets.iter().filter(|t| t.known[c] > 0.0) {
            let v = f64::from(t.values[c]);
            (n, sum, sum2) = (n + 1.0, sum + v, sum2 + v * v);
        }
        let var = if n > 1.0 {
            (sum2 - sum * sum / n) / (n - 1.0)
        } else {
            0.0
        };
        (var.max(0.0).sqrt() as f32).max(0.25 * CONTROL_SPREAD[c])
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lipsync::viseme_controls::of;
    use crate::train::corpus::PhoneSegment;

    fn phone(start: u64, end: u64, phone: &str) -> PhoneSegment {
        PhoneSegment {
            start,
            end,
            phone: phone.into(),
        }
    }

    /// 0.4 s: silence, /b/, /aa/, /m/, silence.
    fn phones() -> Vec<PhoneSegment> {
        vec![
            phone(0, 1600, "h#"),
            phone(1600, 2400, "b"),
            phone(2400, 4000, "aa"),
            phone(4000, 4800, "m"),
            phone(4800, 6400, "h#"),
        ]
    }

    #[test]
    fn phone_frames_open_at_vowels_and_close_at_bilabials() {
        let targets = targets_from_phones(&phones(), 16_000, 6400).unwrap();
        let controls = phone_controls(&targets);
        assert_eq!(controls.len(), 20);
        // /b/ covers frames 5-7, /aa/ 7-12: the widest opening and the firmest closure.
        let most = |range: std::ops::Range<usize>, c: usize| {
            controls[range]
                .iter()
                .map(|t| t.values[c])
                .fold(f32::MIN, f32::max)
        };
        assert!(
            most(7..13, 0) > 0.05 && most(7..13, 2) > 0.3,
            "{controls:?}"
        );
        assert!(most(5..8, 4) > 0.5 && most(0..3, 4) < 0.5, "{controls:?}");
        assert!(controls.iter().all(|c| c.known == [1.0; CONTROL_COUNT]));
        // Coarticulation: the vowel's opening grows, not jumps, out of the closure.
        let apertures: Vec<f32> = controls[4..9].iter().map(|c| c.values[0]).collect();
        assert!(
            apertures.windows(2).all(|w| w[1] >= w[0] - 0.005),
            "{apertures:?}"
        );
    }

    #[test]
    fn video_frames_are_measured_above_the_clips_rest_with_phones_for_the_rest() {
        let weights = targets_from_phones(&phones(), 16_000, 6400)
            .unwrap()
            .weights;
        let rest = [0.02, 0.6];
        let mut lips: Vec<Option<[f32; 2]>> = (0..20)
            .map(|n| {
                Some(if (7..11).contains(&n) {
                    [0.12, 0.59]
                } else {
                    rest
                })
            })
            .collect();
        lips[15] = None;
        let targets = video_controls(&lips, Some(&weights));
        assert!(targets[15].is_none());
        let open = targets[8].unwrap();
        assert!((open.values[0] - 0.10).abs() < 1e-5 && (open.values[1] + 0.01).abs() < 1e-5);
        assert_eq!(open.values[2], jaw_from_aperture(0.10));
        assert_eq!(open.known, [1.0; CONTROL_COUNT]);
        assert!(targets[5].unwrap().values[4] > 0.5);
        // Without phones: only what the lips show is known, above the clip's own rest.
        let bare = video_controls(&lips, None);
        let quiet = bare[0].unwrap();
        assert_eq!(quiet.values[..2], [0.0, 0.0]);
        assert_eq!(quiet.known, [1.0, 1.0, 1.0, 0.0, 0.0, 0.0]);
        assert!(
            video_controls(&[None, None], None)
                .iter()
                .all(Option::is_none)
        );
        let s = spreads(&targets.iter().flatten().copied().collect::<Vec<_>>());
        assert!(s[0] > 0.01 && s.iter().zip(CONTROL_SPREAD).all(|(s, u)| *s >= 0.25 * u));
        let _ = of(Viseme::PP);
    }
}
