//! Levels of detail of a head: the same vertices (and so the same morph deltas) drawn with fewer
//! triangles where the head is shown small. On a software adapter a head's cost goes with its
//! triangles far more than with its pixels, and a 22k-triangle head in a tile 200 pixels high
//! puts several triangles on every pixel.
//!
//! Each coarser level is simplified (meshoptimizer's edge collapse) from the full mesh within an
//! error bound in metres that counts the mouth and eye shapes as well as the rest pose, so a
//! level that is exact to half a pixel at rest stays so when the mouth opens, rounds or spreads.
//! The lips and what shows between them (teeth, tongue) are kept whole, the skin around them is
//! simplified under a tighter measure of shading, and mesh borders (the eyelids' rims, the cut
//! at the neck) keep every vertex.

use glam::Vec3;
use meshopt::{SimplifyOptions, VertexDataAdapter};

use super::head::{Expression, HeadModel, MorphDelta, Primitive, Vertex};
use crate::vocab::{VISEME_COUNT, Viseme};

/// On-screen error a level may make, in pixels: below what sampling a pixel at its centre can
/// show.
pub const MAX_ERROR_PX: f32 = 0.5;

/// The parts inside the mouth (teeth, tongue: small parts lying within a mouth width of its
/// centre) are kept whole out to this many mouth widths: where teeth, tongue, lips and the
/// inside of the mouth nearly touch, a fraction of a millimetre changes which of them shows (a
/// bound on distance is no bound on what covers what).
const MOUTH_KEPT: f32 = 0.6;

/// The face's own surface is kept whole only on the lips: out to [`MOUTH_KEPT`] across and
/// forward, this far up and down (mouth widths). The chin, the cheeks and under the nose, within
/// the mouth's reach, are simplified like the rest of the head; about a sixth of a small tile's
/// triangles, which cost a software adapter more than its pixels do.
const LIPS_KEPT_HEIGHT: f32 = 0.25;

/// Near the mouth (out to [`EMPHASIS_REACH`] mouth widths) changes of normal and colour count
/// this many times more: the shading around the lips is what a lipreader reads.
const MOUTH_EMPHASIS: f32 = 4.0;
const EMPHASIS_REACH: f32 = 0.72;

/// Error bounds of the coarser levels, in metres (a human head is about 0.2 m high).
const LEVEL_ERRORS_M: [f32; 5] = [0.000_25, 0.000_5, 0.001, 0.002, 0.004];

/// The shapes whose deltas the simplifier keeps in view: the widest-open, the roundest and the
/// most spread mouths, the lip closure, the lower lip under the teeth, and the eyes shut.
const SHAPES: [usize; 6] = [
    Viseme::Aa as usize,
    Viseme::U as usize,
    Viseme::I as usize,
    Viseme::PP as usize,
    Viseme::FF as usize,
    VISEME_COUNT + Expression::Blink as usize,
];

/// Metres of error counted for a unit of change in a vertex's normal (about a radian): a tenth
/// of that, a shading change seen on a smooth forehead, counts as 2 mm.
const NORMAL_WEIGHT: f32 = 0.02;
/// Metres of error counted for a full change of a vertex colour channel: the brows, the lips'
/// edges and the hairline are colour on smooth skin, and must keep their shape.
const COLOR_WEIGHT: f32 = 0.25;

/// Floats per vertex given to the simplifier: the shapes' position deltas, the normal, the
/// colour.
const ATTRIBUTES: usize = SHAPES.len() * 3 + 3 + 3;

/// One level: each primitive's triangles (indices into that primitive's own vertices) and the
/// level's error bound.
#[derive(Debug, Clone, PartialEq)]
pub struct DetailLevel {
    /// Largest distance in metres (rest pose or any of the kept shapes) between this level's
    /// surface and the full mesh's, as the simplifier measures it; 0 for the full mesh.
    pub error_m: f32,
    /// Per primitive, in [`HeadModel::primitives`] order.
    pub indices: Vec<Vec<u32>>,
}

impl DetailLevel {
    pub fn triangle_count(&self) -> usize {
        self.indices.iter().map(|i| i.len() / 3).sum()
    }
}

/// A head's levels, finest (the full mesh) first; each coarser one has fewer triangles and a
/// larger error bound.
#[derive(Debug, Clone, PartialEq)]
pub struct DetailLevels(Vec<DetailLevel>);

impl DetailLevels {
    /// The full mesh alone.
    pub fn full(model: &HeadModel) -> Self {
        Self(vec![full_level(model)])
    }

    /// The full mesh and the coarser levels that save triangles (a level that removes fewer than
    /// a tenth of the previous one's triangles is left out).
    pub fn build(model: &HeadModel) -> Self {
        let mut levels = vec![full_level(model)];
        let frame = model.face_frame();
        // Offset from the mouth's centre in mouth widths.
        let from_mouth =
            |v: &Vertex| (Vec3::from(v.position) - frame.mouth) / frame.mouth_width.max(1e-4);
        // Parts lying within a mouth width of its centre: teeth, tongue.
        let inside_mouth: Vec<bool> = model
            .primitives
            .iter()
            .map(|p| p.vertices.iter().all(|v| from_mouth(v).length() <= 1.0))
            .collect();
        let inner_part = |v: &Vertex| from_mouth(v).length() <= MOUTH_KEPT;
        let lips = |v: &Vertex| {
            let d = from_mouth(v) / Vec3::new(MOUTH_KEPT, LIPS_KEPT_HEIGHT, MOUTH_KEPT);
            d.length_squared() <= 1.0
        };
        let emphasis = |v: &Vertex| {
            if from_mouth(v).length() <= EMPHASIS_REACH {
                MOUTH_EMPHASIS
            } else {
                1.0
            }
        };
        for bound in LEVEL_ERRORS_M {
            let mut error_m = 0.0f32;
            let indices = model
                .primitives
                .iter()
                .zip(&inside_mouth)
                .map(|(p, &inside_mouth)| {
                    let (indices, error) = if inside_mouth {
                        simplify(p, bound, &inner_part, &emphasis)
                    } else {
                        simplify(p, bound, &lips, &emphasis)
                    };
                    error_m = error_m.max(error);
                    indices
                })
                .collect();
            let level = DetailLevel { error_m, indices };
            let previous = levels.last().map_or(0, DetailLevel::triangle_count);
            if level.triangle_count() * 10 <= previous * 9 {
                levels.push(level);
            }
        }
        Self(levels)
    }

    pub fn levels(&self) -> &[DetailLevel] {
        &self.0
    }

    /// The coarsest level whose error stays under [`MAX_ERROR_PX`] at `pixels_per_metre` (at the
    /// head's distance); 0, the full mesh, when none does or the scale is not finite.
    pub fn level_for(&self, pixels_per_metre: f32) -> usize {
        level_for(self.0.iter().map(|l| l.error_m), pixels_per_metre)
    }
}

/// The coarsest of levels with these errors (finest first) that stays under [`MAX_ERROR_PX`].
pub(super) fn level_for(errors_m: impl Iterator<Item = f32>, pixels_per_metre: f32) -> usize {
    if !pixels_per_metre.is_finite() || pixels_per_metre <= 0.0 {
        return 0;
    }
    errors_m
        .enumerate()
        .filter(|(_, e)| e * pixels_per_metre <= MAX_ERROR_PX)
        .map(|(i, _)| i)
        .last()
        .unwrap_or(0)
}

fn full_level(model: &HeadModel) -> DetailLevel {
    DetailLevel {
        error_m: 0.0,
        indices: model.primitives.iter().map(|p| p.indices.clone()).collect(),
    }
}

/// `p`'s triangles simplified within `bound` metres, the vertices for which `keep` holds left in
/// place, changes of normal and colour counted `emphasis` times over, and the error reached.
fn simplify(
    p: &Primitive,
    bound: f32,
    keep: &impl Fn(&Vertex) -> bool,
    emphasis: &impl Fn(&Vertex) -> f32,
) -> (Vec<u32>, f32) {
    let bytes: &[u8] = bytemuck::cast_slice(&p.vertices);
    let Ok(adapter) = VertexDataAdapter::new(bytes, std::mem::size_of::<Vertex>(), 0) else {
        return (p.indices.clone(), 0.0);
    };
    let none = MorphDelta::default();
    let mut attributes = Vec::with_capacity(p.vertices.len() * ATTRIBUTES);
    for (i, v) in p.vertices.iter().enumerate() {
        for &slot in &SHAPES {
            let d = p.targets.get(slot).and_then(|t| t.get(i)).unwrap_or(&none);
            attributes.extend_from_slice(&d.position);
        }
        let e = emphasis(v);
        attributes.extend(v.normal.iter().map(|x| x * e));
        attributes.extend(v.color[..3].iter().map(|x| x * e));
    }
    // The simplifier measures positions scaled to the part's extent and attributes as given:
    // scaled alike, the weights are in metres.
    let scale = meshopt::simplify_scale(&adapter).max(f32::MIN_POSITIVE);
    let mut weights = [1.0 / scale; ATTRIBUTES];
    weights[SHAPES.len() * 3..SHAPES.len() * 3 + 3].fill(NORMAL_WEIGHT / scale);
    weights[SHAPES.len() * 3 + 3..].fill(COLOR_WEIGHT / scale);
    let locks: Vec<bool> = p.vertices.iter().map(keep).collect();
    let mut error = 0.0f32;
    let indices = meshopt::simplify_with_attributes_and_locks(
        &p.indices,
        &adapter,
        &attributes,
        &weights,
        ATTRIBUTES * std::mem::size_of::<f32>(),
        &locks,
        0,
        bound,
        SimplifyOptions::LockBorder | SimplifyOptions::ErrorAbsolute,
        Some(&mut error),
    );
    if indices.is_empty() && !p.indices.is_empty() {
        // A small part (an eye, a tooth) that would vanish whole: keep it as it is.
        return (p.indices.clone(), 0.0);
    }
    (indices, error)
}
