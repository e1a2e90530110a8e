//! Mouth geometry: the articulation of each viseme (from the design brief's table) and a point
//! model that turns it into 15 feature points on the lips and jaw.
//!
//! The point source is a parameter: [`VisemeShapes`] holds one flattened point vector per
//! viseme, whether it comes from [`VisemeShapes::point_model`], from marker key frames
//! (`markers`), or later from the 3D head's own viseme shapes ([`VisemeShapes::new`]).

use crate::vocab::{Viseme, VisemeSet};

/// Articulation relative to the neutral face (0 none, 1 full range).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Articulation {
    pub jaw: f32,
    pub lip_aperture: f32,
    /// Spread (+) or narrowed (-).
    pub width: f32,
    pub protrusion: f32,
}

#[rustfmt::skip]
const ARTICULATION: [(f32, f32, f32, f32); 15] = [
    // jaw  aperture width protrusion
    (0.05, 0.0,  0.0,  0.0), // sil
    (0.05, 0.0,  0.0,  0.0), // PP
    (0.15, 0.1,  0.1,  0.0), // FF
    (0.25, 0.3,  0.1,  0.0), // TH
    (0.25, 0.3,  0.15, 0.0), // DD
    (0.35, 0.35, 0.1,  0.0), // kk
    (0.2,  0.3, -0.3,  0.6), // CH
    (0.15, 0.2,  0.3,  0.0), // SS
    (0.25, 0.3,  0.1,  0.0), // nn
    (0.25, 0.25,-0.3,  0.4), // RR
    (1.0,  1.0,  0.1,  0.0), // aa
    (0.5,  0.55, 0.4,  0.0), // E
    (0.25, 0.3,  0.7,  0.0), // I
    (0.6,  0.6, -0.5,  0.6), // O
    (0.3,  0.2, -0.8,  1.0), // U
];

impl Articulation {
    pub fn of(viseme: Viseme) -> Self {
        let (jaw, lip_aperture, width, protrusion) = ARTICULATION[viseme.index()];
        Self {
            jaw,
            lip_aperture,
            width,
            protrusion,
        }
    }

    /// Mouth openness: the mean of jaw opening and lip aperture.
    pub fn openness(&self) -> f32 {
        0.5 * (self.jaw + self.lip_aperture)
    }

    /// Lip rounding: the protrusion of the lips (0 none, 1 a fully rounded /u/).
    pub fn rounding(&self) -> f32 {
        self.protrusion
    }

    /// The three continuous targets lipreaders see, in [`Cue`] order.
    pub fn cues(&self) -> [f32; CUE_COUNT] {
        [self.openness(), self.width, self.rounding()]
    }
}

/// The articulatory dimensions the network is trained on and scored by, beside the visemes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cue {
    Openness,
    /// Spread (+) or narrowed (-) lips.
    Width,
    Rounding,
}

pub const CUE_COUNT: usize = 3;

impl Cue {
    pub const ALL: [Cue; CUE_COUNT] = [Cue::Openness, Cue::Width, Cue::Rounding];

    pub fn name(self) -> &'static str {
        match self {
            Cue::Openness => "openness",
            Cue::Width => "width",
            Cue::Rounding => "rounding",
        }
    }
}

/// Openness, width and rounding of convex weights over `set` (each linear in the weights).
pub fn cues(set: &VisemeSet, weights: &[f32]) -> [f32; CUE_COUNT] {
    let mut out = [0.0; CUE_COUNT];
    for (v, w) in set.members().iter().zip(weights) {
        for (o, c) in out.iter_mut().zip(Articulation::of(*v).cues()) {
            *o += w * c;
        }
    }
    out
}

/// Lip aperture below which the lips count as closed: 10 % of the full opening (about 1 mm on
/// the point model), just under FF (lower lip on the teeth, 0.1). PP and sil are 0.
pub const CLOSED_APERTURE: f32 = 0.1;

/// Openness of convex weights over `set` (linear in the weights).
pub fn openness(set: &VisemeSet, weights: &[f32]) -> f32 {
    set.members()
        .iter()
        .zip(weights)
        .map(|(v, w)| w * Articulation::of(*v).openness())
        .sum()
}

/// Lip aperture of convex weights over `set` (linear in the weights).
pub fn lip_aperture(set: &VisemeSet, weights: &[f32]) -> f32 {
    set.members()
        .iter()
        .zip(weights)
        .map(|(v, w)| w * Articulation::of(*v).lip_aperture)
        .sum()
}

/// Feature points of the point model.
pub const MODEL_POINTS: usize = 15;

/// The 15 feature points (x right, y up, z forward, millimetres, nose tip above the origin) of
/// a mouth with the given articulation: 2 corners, 3 points on each outer lip contour, the
/// inner lip at the centre and left of centre, and 3 on the chin.
pub fn model_points(a: &Articulation) -> [[f32; 3]; MODEL_POINTS] {
    let jaw_drop = 14.0 * a.jaw;
    let gap = 12.0 * a.lip_aperture;
    let half_width = 25.0 * (1.0 + 0.25 * a.width);
    let forward = 8.0 * a.protrusion;
    let upper_inner = 0.3 * gap;
    let lower_inner = -0.7 * gap;
    // A rounded opening is as tall near the corners as in the middle.
    let off_centre = 0.7 + 0.25 * (-a.width).max(0.0);
    let corner_y = 0.1 * (upper_inner + lower_inner);
    let mid_x = 0.5 * half_width;
    [
        [-half_width, corner_y, 0.3 * forward],
        [half_width, corner_y, 0.3 * forward],
        [0.0, upper_inner + 9.0, forward],
        [-mid_x, off_centre * upper_inner + 7.0, 0.8 * forward],
        [mid_x, off_centre * upper_inner + 7.0, 0.8 * forward],
        [0.0, lower_inner - 10.0, forward],
        [-mid_x, off_centre * lower_inner - 8.0, 0.8 * forward],
        [mid_x, off_centre * lower_inner - 8.0, 0.8 * forward],
        [0.0, upper_inner, forward],
        [0.0, lower_inner, forward],
        [-0.9 * mid_x, off_centre * upper_inner, 0.8 * forward],
        [-0.9 * mid_x, off_centre * lower_inner, 0.8 * forward],
        [0.0, -40.0 - jaw_drop, -5.0],
        [-20.0, -35.0 - 0.8 * jaw_drop, -10.0],
        [20.0, -35.0 - 0.8 * jaw_drop, -10.0],
    ]
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ShapeError {
    #[error("no shape for viseme {0}")]
    Missing(Viseme),
    #[error("viseme shape of {found} coordinates, expected {expected}")]
    WrongLength { expected: usize, found: usize },
    #[error("point dimension must be 2 or 3, got {0}")]
    BadPointDim(usize),
}

/// One flattened point vector per viseme (points x `point_dim` coordinates).
#[derive(Debug, Clone, PartialEq)]
pub struct VisemeShapes {
    point_dim: usize,
    coords: usize,
    shapes: Vec<(Viseme, Vec<f32>)>,
}

impl VisemeShapes {
    /// Shapes from any source: every vector must have the same length, a multiple of `point_dim`.
    pub fn new(point_dim: usize, shapes: Vec<(Viseme, Vec<f32>)>) -> Result<Self, ShapeError> {
        if !(2..=3).contains(&point_dim) {
            return Err(ShapeError::BadPointDim(point_dim));
        }
        let coords = shapes.first().map_or(0, |(_, s)| s.len());
        for (_, s) in &shapes {
            if s.len() != coords || !coords.is_multiple_of(point_dim) {
                return Err(ShapeError::WrongLength {
                    expected: coords - coords % point_dim,
                    found: s.len(),
                });
            }
        }
        Ok(Self {
            point_dim,
            coords,
            shapes,
        })
    }

    /// The visemes that have a shape, in order.
    pub fn visemes(&self) -> Vec<Viseme> {
        self.shapes.iter().map(|(v, _)| *v).collect()
    }

    /// All 15 visemes from the point model (3D points).
    pub fn point_model() -> Self {
        let shapes = Viseme::ALL
            .iter()
            .map(|&v| {
                let points = model_points(&Articulation::of(v));
                (v, points.iter().flatten().copied().collect())
            })
            .collect();
        Self {
            point_dim: 3,
            coords: MODEL_POINTS * 3,
            shapes,
        }
    }

    pub fn point_dim(&self) -> usize {
        self.point_dim
    }

    /// Length of one flattened shape.
    pub fn coords(&self) -> usize {
        self.coords
    }

    pub fn shape(&self, viseme: Viseme) -> Result<&[f32], ShapeError> {
        self.shapes
            .iter()
            .find(|(v, _)| *v == viseme)
            .map(|(_, s)| s.as_slice())
            .ok_or(ShapeError::Missing(viseme))
    }

    /// The shapes of `set`, in its order.
    pub fn for_set(&self, set: &VisemeSet) -> Result<Vec<&[f32]>, ShapeError> {
        set.members().iter().map(|&v| self.shape(v)).collect()
    }

    /// Writes the blend `sum w_i V_i` (Eq. 2) of the shapes of `set` into `out`.
    pub fn blend_into(
        &self,
        set: &VisemeSet,
        weights: &[f32],
        out: &mut [f32],
    ) -> Result<(), ShapeError> {
        out.fill(0.0);
        for (&v, &w) in set.members().iter().zip(weights) {
            for (o, s) in out.iter_mut().zip(self.shape(v)?) {
                *o += w * s;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_shapes_have_touching_lips_and_open_ones_do_not() {
        let closed = model_points(&Articulation::of(Viseme::PP));
        assert_eq!(closed[8][1], closed[9][1]);
        let open = model_points(&Articulation::of(Viseme::Aa));
        assert!(open[8][1] - open[9][1] > 10.0);
        assert!(open[12][1] < closed[12][1] - 10.0, "the jaw drops");
        let round = model_points(&Articulation::of(Viseme::U));
        let spread = model_points(&Articulation::of(Viseme::I));
        assert!(
            round[1][0] < spread[1][0],
            "rounded corners are closer together"
        );
        assert!(round[2][2] > spread[2][2], "rounded lips protrude");
    }

    #[test]
    fn openness_and_aperture_are_linear_in_the_weights() {
        let set = VisemeSet::reduced(2).unwrap();
        assert_eq!(lip_aperture(&set, &[1.0, 0.0]), 0.0);
        assert!((openness(&set, &[0.5, 0.5]) - 0.5125).abs() < 1e-6);
    }

    #[test]
    fn shapes_blend_and_report_missing_visemes() {
        let shapes = VisemeShapes::point_model();
        assert_eq!(shapes.coords(), 45);
        let set = VisemeSet::reduced(2).unwrap();
        let mut out = vec![0.0; 45];
        shapes.blend_into(&set, &[0.0, 1.0], &mut out).unwrap();
        assert_eq!(out, shapes.shape(Viseme::Aa).unwrap());
        let partial = VisemeShapes::new(2, vec![(Viseme::PP, vec![0.0; 4])]).unwrap();
        assert_eq!(
            partial.blend_into(&set, &[0.5, 0.5], &mut [0.0; 4]),
            Err(ShapeError::Missing(Viseme::Aa))
        );
        assert!(VisemeShapes::new(2, vec![(Viseme::PP, vec![0.0; 3])]).is_err());
    }
}
