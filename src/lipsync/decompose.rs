//! The paper's viseme decomposition (III.A.1): every frame of a point track is expressed as a
//! convex blend of viseme shapes, found with a constrained partial-gradient method warm-started
//! from the previous frame, and scored with the Eq. 1 error.

use std::fmt;

use super::mouth::{ShapeError, VisemeShapes};
use crate::vocab::{VISEME_COUNT, VisemeError, VisemeSet};

/// Frames of feature points, each frame flattened (`points * point_dim` coordinates).
#[derive(Debug, Clone, PartialEq)]
pub struct PointTrack {
    point_dim: usize,
    coords: usize,
    data: Vec<f32>,
}

#[derive(Debug, thiserror::Error)]
pub enum DecomposeError {
    #[error(transparent)]
    Shape(#[from] ShapeError),
    #[error(transparent)]
    Viseme(#[from] VisemeError),
    #[error("frame of {found} coordinates, the track has {expected}")]
    FrameLength { expected: usize, found: usize },
    #[error("the track has no frames")]
    EmptyTrack,
    #[error("the track's points are {track}D but the shapes' are {shapes}D ({coords} coordinates)")]
    Mismatch {
        track: usize,
        shapes: usize,
        coords: usize,
    },
}

impl PointTrack {
    pub fn new(point_dim: usize, coords: usize) -> Self {
        Self {
            point_dim,
            coords,
            data: Vec::new(),
        }
    }

    pub fn push(&mut self, frame: &[f32]) -> Result<(), DecomposeError> {
        if frame.len() != self.coords {
            return Err(DecomposeError::FrameLength {
                expected: self.coords,
                found: frame.len(),
            });
        }
        self.data.extend_from_slice(frame);
        Ok(())
    }

    /// The track of blends of `shapes` with per-frame weights over `set` (Eq. 2).
    pub fn from_weights<'a>(
        shapes: &VisemeShapes,
        set: &VisemeSet,
        weights: impl IntoIterator<Item = &'a [f32]>,
    ) -> Result<Self, DecomposeError> {
        let mut track = Self::new(shapes.point_dim(), shapes.coords());
        let mut frame = vec![0.0; shapes.coords()];
        for w in weights {
            shapes.blend_into(set, w, &mut frame)?;
            track.push(&frame)?;
        }
        Ok(track)
    }

    pub fn point_dim(&self) -> usize {
        self.point_dim
    }

    pub fn coords(&self) -> usize {
        self.coords
    }

    pub fn points(&self) -> usize {
        self.coords / self.point_dim
    }

    pub fn len(&self) -> usize {
        self.data.len().checked_div(self.coords).unwrap_or(0)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn frame(&self, j: usize) -> &[f32] {
        &self.data[j * self.coords..(j + 1) * self.coords]
    }

    pub fn frames(&self) -> impl Iterator<Item = &[f32]> {
        self.data.chunks_exact(self.coords.max(1))
    }

    /// Linear resampling from one frame period to another (the paper: 40 ms video to 20 ms).
    pub fn resample(&self, from_period_s: f64, to_period_s: f64) -> Self {
        let mut out = Self::new(self.point_dim, self.coords);
        let n = self.len();
        if n == 0 {
            return out;
        }
        let duration = (n - 1) as f64 * from_period_s;
        let count = (duration / to_period_s).floor() as usize + 1;
        for j in 0..count {
            let pos = j as f64 * to_period_s / from_period_s;
            let lo = (pos.floor() as usize).min(n - 1);
            let hi = (lo + 1).min(n - 1);
            let frac = (pos - lo as f64) as f32;
            let (a, b) = (self.frame(lo), self.frame(hi));
            out.data
                .extend(a.iter().zip(b).map(|(x, y)| x + frac * (y - x)));
        }
        out
    }

    /// Per point: the RMS distance from its mean position, sigma(S^i) of Eq. 1.
    pub fn point_sigmas(&self) -> Vec<f32> {
        let n = self.len().max(1) as f64;
        let mut mean = vec![0.0f64; self.coords];
        for frame in self.frames() {
            for (m, x) in mean.iter_mut().zip(frame) {
                *m += *x as f64 / n;
            }
        }
        let mut var = vec![0.0f64; self.points()];
        for frame in self.frames() {
            for (c, (x, m)) in frame.iter().zip(&mean).enumerate() {
                var[c / self.point_dim] += (*x as f64 - m).powi(2) / n;
            }
        }
        var.iter().map(|v| v.sqrt() as f32).collect()
    }
}

/// The paper's "important" points: those whose deviation is above the average deviation.
pub fn important_points(sigmas: &[f32]) -> Vec<usize> {
    let mean = sigmas.iter().sum::<f32>() / sigmas.len().max(1) as f32;
    (0..sigmas.len()).filter(|&i| sigmas[i] > mean).collect()
}

/// Eq. 1: the mean over `points` and frames of the distance between generated and target point,
/// each divided by the target point's deviation `sigmas[i]` (a fraction; x100 for percent).
pub fn eq1_error(
    generated: &PointTrack,
    target: &PointTrack,
    points: &[usize],
    sigmas: &[f32],
) -> f64 {
    let dim = target.point_dim();
    let frames = generated.len().min(target.len());
    let mut total = 0.0f64;
    let mut count = 0usize;
    for j in 0..frames {
        let (g, s) = (generated.frame(j), target.frame(j));
        for &i in points {
            if sigmas[i] <= 0.0 {
                continue;
            }
            let range = i * dim..(i + 1) * dim;
            let dist: f32 = g[range.clone()]
                .iter()
                .zip(&s[range])
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f32>()
                .sqrt();
            total += (dist / sigmas[i]) as f64;
            count += 1;
        }
    }
    if count == 0 {
        0.0
    } else {
        total / count as f64
    }
}

/// Finds convex weights over a viseme set that best reproduce a frame of points.
///
/// Each step of the partial-gradient method moves along one viseme's direction `e_k - w`: the
/// weight of viseme k changes a lot and all others shrink or grow in proportion, so the weights
/// stay non-negative and sum to 1. The step length is the exact minimiser of the squared,
/// deviation-normalised distance (the smooth counterpart of Eq. 1) along that line, clipped so
/// no weight goes negative. The distance is kept as a quadratic form over the weights (Gram
/// matrix of the shapes), so a step costs O(shapes), not O(coordinates).
#[derive(Debug, Clone)]
pub struct Decomposer {
    shapes: Vec<Vec<f64>>,
    coordinate_weight: Vec<f64>,
    gram: Vec<Vec<f64>>,
    max_sweeps: usize,
}

impl Decomposer {
    /// `sigmas`: per-point deviation of the target signal (points that never move are ignored).
    pub fn new(
        shapes: &VisemeShapes,
        set: &VisemeSet,
        sigmas: &[f32],
    ) -> Result<Self, DecomposeError> {
        let dim = shapes.point_dim();
        let coordinate_weight: Vec<f64> = (0..shapes.coords())
            .map(|c| match sigmas.get(c / dim) {
                Some(&s) if s > 0.0 => 1.0 / (s as f64 * s as f64),
                _ => 0.0,
            })
            .collect();
        let shapes: Vec<Vec<f64>> = shapes
            .for_set(set)?
            .into_iter()
            .map(|s| s.iter().map(|&x| x as f64).collect())
            .collect();
        let gram = shapes
            .iter()
            .map(|a| {
                shapes
                    .iter()
                    .map(|b| weighted_dot(&coordinate_weight, a, b))
                    .collect()
            })
            .collect();
        Ok(Self {
            shapes,
            coordinate_weight,
            gram,
            max_sweeps: 20_000,
        })
    }

    /// Improves `weights` (convex, the previous frame's result) until they fit `target`.
    pub fn fit(&self, target: &[f32], weights: &mut [f32]) {
        // A start that is not convex (NaN from upstream) would make the step's bound NaN, and
        // `clamp` panics on it: restart from the even mix. A non-finite target has no fit.
        if weights.is_empty() {
            return;
        }
        let total: f32 = weights.iter().sum();
        let convex = weights.iter().all(|w| *w >= 0.0) && total > 0.0 && total.is_finite();
        if !convex {
            weights.fill(1.0 / weights.len() as f32);
        }
        if !target.iter().all(|x| x.is_finite()) {
            return;
        }
        // A viseme set has at most VISEME_COUNT shapes: the per-shape state lives on the stack,
        // so a frame's fit allocates nothing (it runs on the receiver's step).
        let n = self.shapes.len();
        if weights.len() != n {
            return;
        }
        let mut toward = [0.0f64; VISEME_COUNT];
        let toward = &mut toward[..n];
        for (t, shape) in toward.iter_mut().zip(&self.shapes) {
            *t = weighted_dot_f32(&self.coordinate_weight, shape, target);
        }
        // Each step moves along `e_k - w`, which keeps the sum at 1 only if it starts there, and
        // a start handed back in f32 misses 1 by rounding.
        let mut w = [0.0f64; VISEME_COUNT];
        let w = &mut w[..n];
        for (x, &given) in w.iter_mut().zip(weights.iter()) {
            *x = f64::from(given);
        }
        let start_total: f64 = w.iter().sum();
        w.iter_mut().for_each(|x| *x /= start_total);
        // gram_w = H w, kept up to date through every step.
        let mut gram_w = [0.0f64; VISEME_COUNT];
        let gram_w = &mut gram_w[..n];
        for (g, row) in gram_w.iter_mut().zip(&self.gram) {
            *g = row.iter().zip(w.iter()).map(|(h, x)| h * x).sum();
        }
        let scale = 1.0
            + self
                .coordinate_weight
                .iter()
                .zip(target)
                .map(|(c, &x)| c * f64::from(x) * f64::from(x))
                .sum::<f64>();
        for _ in 0..self.max_sweeps {
            let mut decrease = 0.0f64;
            for k in 0..w.len() {
                if w[k] >= 1.0 {
                    continue;
                }
                let w_gram_w: f64 = w.iter().zip(gram_w.iter()).map(|(a, b)| a * b).sum();
                let w_toward: f64 = w.iter().zip(toward.iter()).map(|(a, b)| a * b).sum();
                let curvature = self.gram[k][k] - 2.0 * gram_w[k] + w_gram_w;
                // Below this the curvature is rounding noise (w is at shape k already), and a
                // step of noise over noise runs to the bound and zeroes every weight.
                let noise = 1e-12 * (self.gram[k][k] + w_gram_w);
                if curvature <= noise.max(1e-18) {
                    continue;
                }
                let slope = (toward[k] - w_toward) - (gram_w[k] - w_gram_w);
                let t = (slope / curvature).clamp(-w[k] / (1.0 - w[k]), 1.0);
                for wj in w.iter_mut() {
                    *wj *= 1.0 - t;
                }
                w[k] += t;
                for (g, h) in gram_w.iter_mut().zip(&self.gram[k]) {
                    *g = (1.0 - t) * *g + t * h;
                }
                decrease += 2.0 * t * slope - t * t * curvature;
            }
            if decrease < 1e-15 * scale {
                break;
            }
        }
        let total: f64 = w.iter().map(|x| x.max(0.0)).sum();
        if !(total > 0.0 && total.is_finite()) {
            return;
        }
        for (out, x) in weights.iter_mut().zip(w.iter()) {
            *out = (x.max(0.0) / total) as f32;
        }
    }
}

fn weighted_dot_f32(weight: &[f64], a: &[f64], b: &[f32]) -> f64 {
    weight
        .iter()
        .zip(a)
        .zip(b)
        .map(|((w, x), &y)| w * x * f64::from(y))
        .sum()
}

fn weighted_dot(weight: &[f64], a: &[f64], b: &[f64]) -> f64 {
    weight
        .iter()
        .zip(a)
        .zip(b)
        .map(|((w, x), y)| w * x * y)
        .sum()
}

/// Decomposes every frame of `track` onto `set`, each frame warm-started from the last.
pub fn decompose_track(
    track: &PointTrack,
    shapes: &VisemeShapes,
    set: &VisemeSet,
    sigmas: &[f32],
) -> Result<Vec<Vec<f32>>, DecomposeError> {
    check_compatible(track, shapes)?;
    let decomposer = Decomposer::new(shapes, set, sigmas)?;
    let mut weights = vec![1.0 / set.len() as f32; set.len()];
    Ok(track
        .frames()
        .map(|frame| {
            decomposer.fit(frame, &mut weights);
            weights.clone()
        })
        .collect())
}

fn check_compatible(track: &PointTrack, shapes: &VisemeShapes) -> Result<(), DecomposeError> {
    if track.point_dim() != shapes.point_dim() || track.coords() != shapes.coords() {
        return Err(DecomposeError::Mismatch {
            track: track.point_dim(),
            shapes: shapes.point_dim(),
            coords: shapes.coords(),
        });
    }
    if track.is_empty() {
        return Err(DecomposeError::EmptyTrack);
    }
    Ok(())
}

/// One row of Table I.
#[derive(Debug, Clone, PartialEq)]
pub struct TableRow {
    pub set: VisemeSet,
    /// Eq. 1 error on the important points, as a fraction.
    pub error: f64,
}

/// Eq. 1 error of the decomposition as a function of the viseme set (the paper's Table I).
#[derive(Debug, Clone, PartialEq)]
pub struct TableI {
    pub rows: Vec<TableRow>,
    pub frames: usize,
    pub important_points: Vec<usize>,
}

/// Decomposes `track` onto each set and reports the Eq. 1 error on the important points.
pub fn table_i(
    track: &PointTrack,
    shapes: &VisemeShapes,
    sets: &[VisemeSet],
) -> Result<TableI, DecomposeError> {
    check_compatible(track, shapes)?;
    let sigmas = track.point_sigmas();
    let important = important_points(&sigmas);
    let rows = sets
        .iter()
        .map(|set| {
            let weights = decompose_track(track, shapes, set, &sigmas)?;
            let generated =
                PointTrack::from_weights(shapes, set, weights.iter().map(Vec::as_slice))?;
            Ok(TableRow {
                set: set.clone(),
                error: eq1_error(&generated, track, &important, &sigmas),
            })
        })
        .collect::<Result<_, DecomposeError>>()?;
    Ok(TableI {
        rows,
        frames: track.len(),
        important_points: important,
    })
}

/// Table I over the paper's reduced sets of 2 to 6 shapes.
pub fn table_i_reduced(
    track: &PointTrack,
    shapes: &VisemeShapes,
) -> Result<TableI, DecomposeError> {
    let sets = (2..=6)
        .map(VisemeSet::reduced)
        .collect::<Result<Vec<_>, _>>()?;
    table_i(track, shapes, &sets)
}

impl fmt::Display for TableI {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "Eq. 1 error on {} important points over {} frames",
            self.important_points.len(),
            self.frames
        )?;
        writeln!(f, "{:>3}  {:<28} {:>8}", "No.", "Visemes", "Error")?;
        for row in &self.rows {
            let names = row.set.to_string().replace(',', " ");
            writeln!(
                f,
                "{:>3}  {:<28} {:>7.2}%",
                row.set.len(),
                names,
                100.0 * row.error
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vocab::Viseme;

    #[test]
    fn decomposition_recovers_known_convex_weights() {
        let shapes = VisemeShapes::point_model();
        // The point model spans 4 articulation parameters, so at most 5 shapes are affinely
        // independent and have unique weights.
        let set = VisemeSet::reduced(5).unwrap();
        let truth = [
            vec![0.1, 0.5, 0.0, 0.2, 0.2],
            vec![0.0, 0.0, 0.7, 0.0, 0.3],
            vec![0.9, 0.1, 0.0, 0.0, 0.0],
            vec![0.3, 0.1, 0.2, 0.25, 0.15],
        ];
        let track =
            PointTrack::from_weights(&shapes, &set, truth.iter().map(Vec::as_slice)).unwrap();
        let sigmas = vec![1.0; track.points()];
        let found = decompose_track(&track, &shapes, &set, &sigmas).unwrap();
        for (f, t) in found.iter().zip(&truth) {
            assert!((f.iter().sum::<f32>() - 1.0).abs() < 1e-5);
            for (a, b) in f.iter().zip(t) {
                assert!(*a >= 0.0 && (a - b).abs() < 2e-3, "{f:?} vs {t:?}");
            }
        }
    }

    #[test]
    fn non_finite_starts_and_targets_give_convex_weights_not_a_panic() {
        let shapes = VisemeShapes::point_model();
        let set = VisemeSet::reduced(6).unwrap();
        let decomposer = Decomposer::new(&shapes, &set, &[1.0; 15]).unwrap();
        let target: Vec<f32> = shapes.shape(Viseme::Aa).unwrap().to_vec();
        let mut w = vec![f32::NAN; 6];
        decomposer.fit(&target, &mut w);
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{w:?}");
        assert!(w.iter().all(|x| x.is_finite() && *x >= 0.0), "{w:?}");
        let mut bad_target = target.clone();
        bad_target[0] = f32::INFINITY;
        let mut w = vec![0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        decomposer.fit(&bad_target, &mut w);
        assert!(w.iter().all(|x| x.is_finite() && *x >= 0.0), "{w:?}");
    }

    #[test]
    fn shapes_outside_the_hull_get_the_nearest_convex_blend() {
        let shapes = VisemeShapes::point_model();
        let set = VisemeSet::reduced(2).unwrap();
        let decomposer = Decomposer::new(&shapes, &set, &[1.0; 15]).unwrap();
        let mut w = vec![0.5, 0.5];
        // A mouth opened further than aa: the best convex answer is pure aa.
        let beyond: Vec<f32> = shapes
            .shape(Viseme::PP)
            .unwrap()
            .iter()
            .zip(shapes.shape(Viseme::Aa).unwrap())
            .map(|(p, a)| p + 1.5 * (a - p))
            .collect();
        decomposer.fit(&beyond, &mut w);
        assert!((w[1] - 1.0).abs() < 1e-6 && w[0].abs() < 1e-6, "{w:?}");
    }

    #[test]
    fn table_i_error_falls_as_shapes_are_added() {
        let shapes = VisemeShapes::point_model();
        let full = VisemeSet::full();
        let frames: Vec<Vec<f32>> = Viseme::ALL.iter().map(|v| v.one_hot().to_vec()).collect();
        let track =
            PointTrack::from_weights(&shapes, &full, frames.iter().map(Vec::as_slice)).unwrap();
        let table = table_i_reduced(&track, &shapes).unwrap();
        let errors: Vec<f64> = table.rows.iter().map(|r| r.error).collect();
        assert!(errors.windows(2).all(|e| e[1] <= e[0] + 1e-9), "{errors:?}");
        assert!(
            errors[0] > 0.05 && errors[4] < errors[0] / 2.0,
            "{errors:?}"
        );
        let text = table.to_string();
        assert!(text.contains("PP aa I O E FF"), "{text}");
        assert_eq!(
            table_i(&PointTrack::new(3, 45), &shapes, &[full])
                .unwrap_err()
                .to_string(),
            "the track has no frames"
        );
    }

    #[test]
    fn resampling_interpolates_linearly() {
        let mut track = PointTrack::new(2, 2);
        track.push(&[0.0, 0.0]).unwrap();
        track.push(&[4.0, 8.0]).unwrap();
        let fine = track.resample(0.04, 0.02);
        assert_eq!(fine.len(), 3);
        assert_eq!(fine.frame(1), &[2.0, 4.0]);
        assert!(track.push(&[1.0]).is_err());
    }
}
