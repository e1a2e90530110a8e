//! The audio-visual lag of a speaker: how far his lip aperture leads or trails the sound, from
//! the cross-correlation of aperture with acoustic energy (and of their changes: the onsets)
//! pooled over clips, in 20 ms audio frames.

/// Energy of each 20 ms frame of `samples` at `rate` Hz, in dB of full scale.
pub fn frame_energy_db(samples: &[f32], rate: u32) -> Vec<f32> {
    let per_frame = (rate as usize / 50).max(1);
    samples
        .chunks_exact(per_frame)
        .map(|frame| {
            let power = frame.iter().map(|s| s * s).sum::<f32>() / frame.len() as f32;
            10.0 * (power + 1e-10).log10()
        })
        .collect()
}

/// One clip's series, frame by frame: the aperture (`None` untracked) and the energy.
pub struct ClipSeries {
    pub aperture: Vec<Option<f32>>,
    pub energy_db: Vec<f32>,
}

/// Pearson r of aperture at frame n with energy at frame n + k, for k in `-max..=max`, pooled
/// over the clips; with `onsets`, of their central differences instead. A peak at k > 0: the
/// lips lead the sound by k frames.
pub fn cross_correlation(clips: &[ClipSeries], max: i32, onsets: bool) -> Vec<(i32, f64)> {
    let series = |clip: &ClipSeries| -> (Vec<Option<f64>>, Vec<f64>) {
        let a: Vec<Option<f64>> = clip.aperture.iter().map(|a| a.map(f64::from)).collect();
        let e: Vec<f64> = clip.energy_db.iter().map(|&e| e as f64).collect();
        if !onsets {
            return (a, e);
        }
        let da = (0..a.len())
            .map(
                |n| match (n.checked_sub(1).and_then(|m| a[m]), a.get(n + 1)) {
                    (Some(x), Some(Some(y))) => Some(y - x),
                    _ => None,
                },
            )
            .collect();
        let de = (0..e.len())
            .map(|n| match (n.checked_sub(1), e.get(n + 1)) {
                (Some(m), Some(y)) => y - e[m],
                _ => 0.0,
            })
            .collect();
        (da, de)
    };
    let prepared: Vec<_> = clips.iter().map(series).collect();
    (-max..=max)
        .map(|k| {
            let (mut n, mut sx, mut sy, mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
            for (a, e) in &prepared {
                for (i, x) in a.iter().enumerate() {
                    let j = i as i64 + k as i64;
                    let (Some(x), Some(&y)) = (x, usize::try_from(j).ok().and_then(|j| e.get(j)))
                    else {
                        continue;
                    };
                    n += 1.0;
                    sx += x;
                    sy += y;
                    sxx += x * x;
                    syy += y * y;
                    sxy += x * y;
                }
            }
            let cov = sxy - sx * sy / n;
            let (vx, vy) = (sxx - sx * sx / n, syy - sy * sy / n);
            let r = if n > 2.0 && vx > 0.0 && vy > 0.0 {
                cov / (vx * vy).sqrt()
            } else {
                0.0
            };
            (k, r)
        })
        .collect()
}

/// The lag of the curve's highest r, refined between frames by a parabola through its
/// neighbours (in frames).
pub fn peak_lag(curve: &[(i32, f64)]) -> Option<f64> {
    let best = (0..curve.len()).max_by(|&a, &b| curve[a].1.total_cmp(&curve[b].1))?;
    let k = curve[best].0 as f64;
    if best == 0 || best + 1 == curve.len() {
        return Some(k);
    }
    let (l, c, r) = (curve[best - 1].1, curve[best].1, curve[best + 1].1);
    let denominator = l - 2.0 * c + r;
    if denominator.abs() < 1e-12 {
        return Some(k);
    }
    Some(k + (0.5 * (l - r) / denominator).clamp(-0.5, 0.5))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A clip whose aperture is its energy 3 frames later (the lips lead by 60 ms).
    fn leading_clip(seed: u64) -> ClipSeries {
        let mut x = seed as f32 * 0.37 + 0.1;
        let energy: Vec<f32> = (0..200)
            .map(|n| {
                x = (x * 3.9 + 0.13).fract();
                -40.0 + 20.0 * ((n as f32 * 0.21).sin() + x)
            })
            .collect();
        let aperture = (0..200)
            .map(|n| energy.get(n + 3).map(|e| (e + 60.0) / 100.0))
            .collect();
        ClipSeries {
            aperture,
            energy_db: energy,
        }
    }

    #[test]
    fn a_leading_aperture_peaks_at_its_lead() {
        let clips = [leading_clip(1), leading_clip(2)];
        for onsets in [false, true] {
            let curve = cross_correlation(&clips, 8, onsets);
            assert_eq!(curve.len(), 17);
            let lag = peak_lag(&curve).unwrap();
            assert!((lag - 3.0).abs() < 0.3, "onsets {onsets}: {lag} {curve:?}");
        }
    }

    #[test]
    fn energy_is_per_20_ms() {
        let tone: Vec<f32> = (0..16_000).map(|n| 0.5 * (n as f32 * 0.3).sin()).collect();
        let e = frame_energy_db(&tone, 16_000);
        assert_eq!(e.len(), 50);
        // A sine of amplitude 0.5 has power 0.125: -9 dB.
        assert!(e.iter().all(|&d| (d + 9.03).abs() < 0.1), "{:?}", &e[..3]);
    }
}
