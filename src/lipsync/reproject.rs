//! Weights over one viseme set re-expressed over another: blend the source shapes into mouth
//! points (Eq. 2), then decompose those points onto the target set (the paper's III.A.1). This is
//! how one network drives heads with 2 to 15 shapes.

use super::decompose::{DecomposeError, Decomposer};
use super::mouth::{ShapeError, VisemeShapes};
use super::visemes::VisemeSet;

#[derive(Debug, thiserror::Error)]
pub enum ReprojectError {
    #[error(transparent)]
    Shape(#[from] ShapeError),
    #[error(transparent)]
    Decompose(#[from] DecomposeError),
}

pub struct Reprojector {
    from: VisemeSet,
    to: VisemeSet,
    shapes: VisemeShapes,
    /// `None` when the two sets are the same and weights pass through.
    decomposer: Option<Decomposer>,
    points: Vec<f32>,
    previous: Vec<f32>,
}

impl Reprojector {
    pub fn new(
        from: VisemeSet,
        to: VisemeSet,
        shapes: VisemeShapes,
    ) -> Result<Self, ReprojectError> {
        let decomposer = if from == to {
            None
        } else {
            let points = shapes.coords() / shapes.point_dim();
            // Every point counts equally: the shapes are in one unit already.
            Some(Decomposer::new(&shapes, &to, &vec![1.0; points])?)
        };
        let previous = vec![1.0 / to.len() as f32; to.len()];
        Ok(Self {
            points: vec![0.0; shapes.coords()],
            from,
            to,
            shapes,
            decomposer,
            previous,
        })
    }

    pub fn target(&self) -> &VisemeSet {
        &self.to
    }

    /// Maps `weights` (over the source set) to `out` (over the target set), warm-started from the
    /// previous frame as the paper does.
    pub fn project(&mut self, weights: &[f32], out: &mut [f32]) -> Result<(), ReprojectError> {
        let Some(decomposer) = &self.decomposer else {
            out.copy_from_slice(weights);
            return Ok(());
        };
        self.shapes
            .blend_into(&self.from, weights, &mut self.points)?;
        decomposer.fit(&self.points, &mut self.previous);
        out.copy_from_slice(&self.previous);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lipsync::mouth;
    use crate::lipsync::visemes::Viseme;

    #[test]
    fn full_weights_reduce_to_a_set_that_keeps_openness_and_closure() {
        let full = VisemeSet::full();
        let reduced = VisemeSet::reduced(3).unwrap();
        let mut r =
            Reprojector::new(full.clone(), reduced.clone(), VisemeShapes::point_model()).unwrap();
        let mut out = vec![0.0; reduced.len()];
        for viseme in ["aa", "PP", "I"] {
            let mut w = vec![0.0; full.len()];
            let v: Viseme = viseme.parse().unwrap();
            w[full.position(v).unwrap()] = 1.0;
            r.project(&w, &mut out).unwrap();
            assert!((out.iter().sum::<f32>() - 1.0).abs() < 1e-4);
            assert!(out.iter().all(|&x| x >= 0.0));
            let k = reduced.position(v).unwrap();
            assert!(out[k] > 0.95, "{viseme}: {out:?}");
        }
        // A half-open E lands between closed and open, with the same openness.
        let mut w = vec![0.0; full.len()];
        let e: Viseme = "E".parse().unwrap();
        w[full.position(e).unwrap()] = 1.0;
        r.project(&w, &mut out).unwrap();
        let before = mouth::openness(&full, &w);
        let after = mouth::openness(&reduced, &out);
        assert!((before - after).abs() < 0.1, "{before} vs {after}");
    }

    #[test]
    fn same_set_passes_through() {
        let set = VisemeSet::reduced(4).unwrap();
        let mut r = Reprojector::new(set.clone(), set, VisemeShapes::point_model()).unwrap();
        let w = [0.1, 0.2, 0.3, 0.4];
        let mut out = [0.0; 4];
        r.project(&w, &mut out).unwrap();
        assert_eq!(out, w);
    }
}
