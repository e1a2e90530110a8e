//! Weights over one viseme set re-expressed over another, as a fixed linear map: each source
//! viseme goes to its convex decomposition onto the target set's shapes (the paper's III.A.1,
//! per viseme), a viseme both sets share to itself. This is how one network drives heads with
//! 2 to 15 shapes, and how its training targets over a reduced set are made from the 15.
//!
//! Per viseme rather than per frame: a frame's blend decomposed anew would let PP + aa stand in
//! for FF, whose points are nearly theirs, and onto a set that holds the source's shapes (all
//! 15) the per-frame fit has many exact answers to search among. The map costs
//! `source x target` multiply-adds a frame and keeps no state.

use super::decompose::{DecomposeError, Decomposer};
use super::mouth::{ShapeError, VisemeShapes};
use crate::vocab::VisemeSet;

#[derive(Debug, thiserror::Error)]
pub enum ReprojectError {
    #[error(transparent)]
    Shape(#[from] ShapeError),
    #[error(transparent)]
    Decompose(#[from] DecomposeError),
}

/// `from.len() x to.len()`, row-major: row i is source viseme i's convex weights over `to`.
/// `point_weights` weigh the shape points in the decomposition (one per point).
pub fn decomposition_map(
    shapes: &VisemeShapes,
    from: &VisemeSet,
    to: &VisemeSet,
    point_weights: &[f32],
) -> Result<Vec<f32>, DecomposeError> {
    let k = to.len();
    let mut map = vec![0.0f32; from.len() * k];
    let mut decomposer = None;
    for (&v, row) in from.members().iter().zip(map.chunks_exact_mut(k)) {
        match to.position(v) {
            Some(i) => row[i] = 1.0,
            None => {
                let decomposer = match &mut decomposer {
                    Some(d) => d,
                    None => decomposer.insert(Decomposer::new(shapes, to, point_weights)?),
                };
                row.fill(1.0 / k as f32);
                decomposer.fit(shapes.shape(v)?, row);
            }
        }
    }
    Ok(map)
}

pub struct Reprojector {
    to: VisemeSet,
    /// `None` when the two sets are the same and weights pass through.
    map: Option<Vec<f32>>,
}

impl Reprojector {
    pub fn new(
        from: VisemeSet,
        to: VisemeSet,
        shapes: VisemeShapes,
    ) -> Result<Self, ReprojectError> {
        let map = if from == to {
            None
        } else {
            // Every point counts equally: the shapes are in one unit already.
            let points = shapes.coords() / shapes.point_dim();
            Some(decomposition_map(&shapes, &from, &to, &vec![1.0; points])?)
        };
        Ok(Self { to, map })
    }

    pub fn target(&self) -> &VisemeSet {
        &self.to
    }

    /// Maps `weights` (over the source set) to `out` (over the target set); convex weights stay
    /// convex.
    pub fn project(&self, weights: &[f32], out: &mut [f32]) {
        let Some(map) = &self.map else {
            for (o, w) in out.iter_mut().zip(weights) {
                *o = *w;
            }
            return;
        };
        out.fill(0.0);
        // The map has a row per source viseme: weights beyond them have none.
        for (w, row) in weights.iter().zip(map.chunks_exact(self.to.len())) {
            for (o, m) in out.iter_mut().zip(row) {
                *o += w * m;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lipsync::mouth;
    use crate::vocab::Viseme;

    #[test]
    fn full_weights_reduce_to_a_set_that_keeps_openness_and_closure() {
        let full = VisemeSet::full();
        let reduced = VisemeSet::reduced(3).unwrap();
        let r =
            Reprojector::new(full.clone(), reduced.clone(), VisemeShapes::point_model()).unwrap();
        let mut out = vec![0.0; reduced.len()];
        for viseme in ["aa", "PP", "I"] {
            let mut w = vec![0.0; full.len()];
            let v: Viseme = viseme.parse().unwrap();
            w[full.position(v).unwrap()] = 1.0;
            r.project(&w, &mut out);
            assert!((out.iter().sum::<f32>() - 1.0).abs() < 1e-4);
            assert!(out.iter().all(|&x| x >= 0.0));
            let k = reduced.position(v).unwrap();
            assert!(out[k] > 0.95, "{viseme}: {out:?}");
        }
        // A half-open E lands between closed and open, with the same openness.
        let mut w = vec![0.0; full.len()];
        let e: Viseme = "E".parse().unwrap();
        w[full.position(e).unwrap()] = 1.0;
        r.project(&w, &mut out);
        let before = mouth::openness(&full, &w);
        let after = mouth::openness(&reduced, &out);
        assert!((before - after).abs() < 0.1, "{before} vs {after}");
    }

    #[test]
    fn same_set_passes_through() {
        let set = VisemeSet::reduced(4).unwrap();
        let r = Reprojector::new(set.clone(), set, VisemeShapes::point_model()).unwrap();
        let w = [0.1, 0.2, 0.3, 0.4];
        let mut out = [0.0; 4];
        r.project(&w, &mut out);
        assert_eq!(out, w);
    }

    #[test]
    fn a_set_that_holds_the_source_takes_the_weights_as_they_are() {
        let from = VisemeSet::parse("PP,FF,aa,I,U").unwrap();
        let full = VisemeSet::full();
        let r = Reprojector::new(from.clone(), full.clone(), VisemeShapes::point_model()).unwrap();
        let w = [0.1, 0.2, 0.3, 0.15, 0.25];
        let mut out = vec![0.0; full.len()];
        r.project(&w, &mut out);
        for (v, x) in full.members().iter().zip(&out) {
            let expected = from.position(*v).map_or(0.0, |i| w[i]);
            assert_eq!(*x, expected, "{v:?}");
        }
    }

    #[test]
    fn a_blend_maps_to_the_blend_of_its_shapes_maps() {
        let from = VisemeSet::parse("PP,FF,aa,I,U").unwrap();
        let to = VisemeSet::reduced(6).unwrap();
        let r = Reprojector::new(from.clone(), to.clone(), VisemeShapes::point_model()).unwrap();
        let one = |i: usize| {
            let mut w = [0.0; 5];
            w[i] = 1.0;
            let mut out = vec![0.0; to.len()];
            r.project(&w, &mut out);
            out
        };
        let (aa, u) = (one(2), one(4));
        let mut blend = vec![0.0; to.len()];
        r.project(&[0.0, 0.0, 0.4, 0.0, 0.6], &mut blend);
        for ((b, a), u) in blend.iter().zip(&aa).zip(&u) {
            assert!((b - (0.4 * a + 0.6 * u)).abs() < 1e-6);
        }
        assert!((blend.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        assert!(blend.iter().all(|&x| x >= 0.0));
        // U, absent from the set, becomes rounded O more than anything else.
        let o = to.position("O".parse().unwrap()).unwrap();
        assert!(u.iter().all(|&x| x <= u[o]), "{u:?}");
    }
}
