//! How far a head's mouth opens and spreads, measured on its own geometry in eye widths (the
//! unit face trackers and the GRID lip tracks use), and the calibration that makes every head
//! open about as far as a real speaker's mouth: avatars are built with very different ranges (a
//! Ready Player Me avatar's visemes parted its lips at most 0.086 eye widths in speech, where
//! real speakers reach 0.10-0.22), and the network's weights only mean the same on every head
//! once the ranges agree.
//!
//! The lip gap is read the way a camera in front of the face sees it: the head is cut by the
//! vertical plane through the middle of the mouth, and along that line the front-most surface
//! is either lip (the face's own surface at a point that lies, at rest, not far behind the rest
//! lips: the jaw may swing the lower lip back) or the inside of the mouth (teeth, tongue, the
//! mouth's far wall, nothing). The gap is the longest
//! stretch of inside with lip above and below it. The width is the distance between the mouth
//! corners (the vertices that move sideways most between the spread `I` and the rounded `U`).
//! The eye width is the sideways extent of what the blink shape moves (the lids, from the outer
//! corner of one eye to the other's), else of what the gaze shapes move (the eyeballs), else
//! the rest mouth width over [`REST_MOUTH_EYE_WIDTHS`].

use glam::Vec3;

use super::head::{Expression, HeadModel, Vertex};
use crate::vocab::{VISEME_COUNT, VisemeWeights};

/// The widest lip gap of GRID speaker s1, in eye widths: the 99.5th percentile of the inner-lip
/// midpoint distance (MediaPipe landmarks 13-14 over 33-263) over his 998 tracked clips. A
/// head's widest viseme is opened at least this far.
pub const TARGET_GAP: f32 = 0.17;
/// How far s1's mouth width moves, in eye widths: the 99.5th minus the 0.5th percentile of the
/// mouth-corner distance (landmarks 61-291) over the same frames. A head's widest viseme less
/// its narrowest is made to move at least this much.
pub const TARGET_WIDTH_RANGE: f32 = 0.12;
/// s1's median mouth width, in eye widths: the unit of a head without eye shapes.
pub const REST_MOUTH_EYE_WIDTHS: f32 = 0.59;
/// The most a head's mouth motion is amplified: beyond it a linear morph target distorts more
/// than it opens.
pub const MAX_GAIN: f32 = 3.0;

/// Samples along the cut through the middle of the mouth.
const SAMPLES: usize = 800;
/// The cut spans this many rest mouth widths above and below the mouth centre (a jaw wide
/// open drops the lower lip about half a mouth width).
const WINDOW: f32 = 1.0;
/// How far behind the rest lips (in rest mouth widths) a point of the face's own surface may lie
/// at rest and still count as lip (the lips' inner faces); the mouth's inside lies deeper.
const LIP_DEPTH: f32 = 0.2;
const VISEME_I: usize = 12;
const VISEME_U: usize = 14;

/// Where a head's mouth is and how to measure it.
#[derive(Debug, Clone)]
pub struct MouthGauge {
    /// Eye width in model units (metres for a glTF head).
    pub eye_width: f32,
    /// How the eye width was found.
    pub eye_width_from: &'static str,
    /// The face: the primitive with the mouth corners.
    face: usize,
    /// Mouth corner vertices (primitive-local index in `face`), right then left.
    corners: [usize; 2],
    centre: Vec3,
    rest_width: f32,
    lip_front: f32,
}

/// A mouth measured in one pose, in eye widths.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MouthOpening {
    pub gap: f32,
    pub width: f32,
}

/// What calibration measured and did to a head.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MouthCalibration {
    /// The widest lip gap over the 15 visemes before and after, in eye widths.
    pub gap_before: f32,
    pub gap_after: f32,
    /// The widest less the narrowest mouth width over the visemes, before and after.
    pub width_range_before: f32,
    pub width_range_after: f32,
    /// The factor on every viseme's motion, and the extra factor on its sideways motion.
    pub opening_gain: f32,
    pub width_gain: f32,
}

impl MouthGauge {
    /// Finds the mouth corners (from `I` and `U`), the middle of the mouth and the unit; `None`
    /// for a head without both shapes or whose corners cannot be told apart.
    pub fn new(head: &HeadModel) -> Option<Self> {
        let (face, corners) = mouth_corners(head)?;
        let verts = &head.primitives[face].vertices;
        let [r, l] = corners.map(|k| Vec3::from(verts[k].position));
        let rest_width = (l.x - r.x).abs();
        if rest_width.is_nan() || rest_width <= 0.0 {
            return None;
        }
        let (eye_width, eye_width_from) =
            eye_width(head).unwrap_or((rest_width / REST_MOUTH_EYE_WIDTHS, "rest mouth width"));
        let mut gauge = Self {
            eye_width,
            eye_width_from,
            face,
            corners,
            centre: 0.5 * (l + r),
            rest_width,
            lip_front: f32::NEG_INFINITY,
        };
        let rest = head.blend_cpu(&VisemeWeights::neutral());
        let cut = gauge.cut(head, &rest);
        let near = (0.05 * SAMPLES as f32 / (2.0 * WINDOW)) as usize;
        let mid = SAMPLES / 2;
        gauge.lip_front = cut[mid.saturating_sub(near)..(mid + near).min(SAMPLES)]
            .iter()
            .flatten()
            .filter(|hit| hit.primitive == face)
            .map(|hit| hit.rest_z)
            .fold(f32::NEG_INFINITY, f32::max);
        gauge.lip_front.is_finite().then_some(gauge)
    }

    /// The mouth in a blended pose (`blended` as [`HeadModel::blend_cpu`] returns it).
    pub fn measure(&self, head: &HeadModel, blended: &[Vertex]) -> MouthOpening {
        let cut = self.cut(head, blended);
        let depth = LIP_DEPTH * self.rest_width;
        let is_lip: Vec<bool> = cut
            .iter()
            .map(|h| {
                h.is_some_and(|hit| {
                    hit.primitive == self.face && hit.rest_z >= self.lip_front - depth
                })
            })
            .collect();
        // The longest run of inside with lip at both ends.
        let (mut best, mut run, mut seen_lip) = (0usize, 0usize, false);
        for lip in is_lip {
            if lip {
                if seen_lip {
                    best = best.max(run);
                }
                seen_lip = true;
                run = 0;
            } else {
                run += 1;
            }
        }
        let step = 2.0 * WINDOW * self.rest_width / SAMPLES as f32;
        let offset: usize = head.primitives[..self.face]
            .iter()
            .map(|p| p.vertices.len())
            .sum();
        let [r, l] = self
            .corners
            .map(|k| Vec3::from(blended[offset + k].position));
        MouthOpening {
            gap: best as f32 * step / self.eye_width,
            width: (l.x - r.x).abs() / self.eye_width,
        }
    }

    /// The mouth under each viseme alone.
    pub fn visemes(&self, head: &HeadModel) -> [MouthOpening; VISEME_COUNT] {
        std::array::from_fn(|v| self.measure(head, &head.blend_cpu(&VisemeWeights::one_hot(v))))
    }

    /// The front-most surface at each sample of the vertical line through the mouth centre,
    /// top to bottom.
    fn cut(&self, head: &HeadModel, blended: &[Vertex]) -> Vec<Option<Hit>> {
        let x0 = self.centre.x;
        let top = self.centre.y + WINDOW * self.rest_width;
        let step = 2.0 * WINDOW * self.rest_width / SAMPLES as f32;
        let mut front: Vec<Option<Hit>> = vec![None; SAMPLES];
        let mut offset = 0;
        for (pi, p) in head.primitives.iter().enumerate() {
            let posed = |i: u32| Vec3::from(blended[offset + i as usize].position);
            let rest = |i: u32| p.vertices.get(i as usize).map_or(0.0, |v| v.position[2]);
            for tri in p.indices.chunks_exact(3) {
                let corners = [0, 1, 2].map(|k| (posed(tri[k]), rest(tri[k])));
                let Some([(y0, z0, r0), (y1, z1, r1)]) = cross_section(corners, x0) else {
                    continue;
                };
                let (lo, hi) = (y0.min(y1), y0.max(y1));
                let first = ((top - hi) / step).ceil().max(0.0) as usize;
                let last = ((top - lo) / step).floor();
                if last < 0.0 {
                    continue;
                }
                let last = (last as usize).min(SAMPLES - 1);
                for (s, slot) in front.iter_mut().enumerate().take(last + 1).skip(first) {
                    let y = top - s as f32 * step;
                    let t = if hi > lo {
                        ((y - y0) / (y1 - y0)).clamp(0.0, 1.0)
                    } else {
                        0.0
                    };
                    let z = z0 + t * (z1 - z0);
                    if slot.is_none_or(|hit| z > hit.z) {
                        *slot = Some(Hit {
                            primitive: pi,
                            z,
                            rest_z: r0 + t * (r1 - r0),
                        });
                    }
                }
            }
            offset += p.vertices.len();
        }
        front
    }
}

/// A surface the cut meets: its primitive, its depth, and where that point of the surface
/// lies at rest (the lips keep their rest depth however far the jaw swings them back).
#[derive(Debug, Clone, Copy)]
struct Hit {
    primitive: usize,
    z: f32,
    rest_z: f32,
}

/// Where the triangle (posed corner, its rest depth) crosses the plane x = `x0`: the segment's
/// ends (y, z, rest z).
fn cross_section(corners: [(Vec3, f32); 3], x0: f32) -> Option<[(f32, f32, f32); 2]> {
    let mut ends = [(0.0f32, 0.0f32, 0.0f32); 2];
    let mut n = 0;
    for (a, b) in [(0, 1), (1, 2), (2, 0)] {
        let ((p, pr), (q, qr)) = (corners[a], corners[b]);
        let (dp, dq) = (p.x - x0, q.x - x0);
        if (dp < 0.0) == (dq < 0.0) || dp == dq {
            continue;
        }
        let t = dp / (dp - dq);
        if n < 2 {
            ends[n] = (
                p.y + t * (q.y - p.y),
                p.z + t * (q.z - p.z),
                pr + t * (qr - pr),
            );
            n += 1;
        }
    }
    (n == 2).then_some(ends)
}

/// The face primitive and its two mouth corners: on each side of the head, the vertex that
/// moves outward most from `U` to `I`.
fn mouth_corners(head: &HeadModel) -> Option<(usize, [usize; 2])> {
    let frame = head.face_frame();
    let centre_x = 0.5 * (frame.head_min.x + frame.head_max.x);
    let mut best: Option<(f32, usize, [usize; 2])> = None;
    for (pi, p) in head.primitives.iter().enumerate() {
        let (ti, tu) = (&p.targets[VISEME_I], &p.targets[VISEME_U]);
        if ti.is_empty() || tu.is_empty() {
            continue;
        }
        let mut side = [(0.0f32, usize::MAX); 2];
        for (k, v) in p.vertices.iter().enumerate() {
            let left = v.position[0] >= centre_x;
            let sign = if left { 1.0 } else { -1.0 };
            let score = (ti[k].position[0] - tu[k].position[0]) * sign;
            let s = &mut side[usize::from(left)];
            if score > s.0 {
                *s = (score, k);
            }
        }
        let total = side[0].0 + side[1].0;
        if side.iter().all(|s| s.1 != usize::MAX) && best.is_none_or(|b| total > b.0) {
            best = Some((total, pi, [side[0].1, side[1].1]));
        }
    }
    best.map(|(_, pi, corners)| (pi, corners))
}

/// The sideways extent of what an eye shape moves: the blink's lids, else the gaze's eyeballs.
fn eye_width(head: &HeadModel) -> Option<(f32, &'static str)> {
    for (expression, from) in [
        (Expression::Blink, "blink shape's lids"),
        (Expression::LookLeft, "gaze shape's eyeballs"),
    ] {
        let slot = expression.slot();
        let largest = head
            .primitives
            .iter()
            .flat_map(|p| p.targets[slot].iter())
            .map(|d| Vec3::from(d.position).length())
            .fold(0.0f32, f32::max);
        if largest <= 0.0 {
            continue;
        }
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for p in &head.primitives {
            for (v, d) in p.vertices.iter().zip(&p.targets[slot]) {
                if Vec3::from(d.position).length() > 0.1 * largest {
                    lo = lo.min(v.position[0]);
                    hi = hi.max(v.position[0]);
                }
            }
        }
        if hi > lo {
            return Some((hi - lo, from));
        }
    }
    None
}

/// Scales a head's mouth motion so that its widest viseme parts the lips at least
/// [`TARGET_GAP`] eye widths and its mouth width moves at least [`TARGET_WIDTH_RANGE`] (each
/// factor at most [`MAX_GAIN`]); a head that already opens and spreads that far is left as it
/// is. Equivalent to weighting each viseme's morph targets by the gain (and its sideways
/// motion by the width gain too). `None` where the head's lips cannot be measured.
pub fn calibrate(head: &mut HeadModel) -> Option<MouthCalibration> {
    let gauge = MouthGauge::new(head)?;
    let (gap_before, width_range_before) = extent(&gauge.visemes(head));
    if gap_before.is_nan() || gap_before <= 0.0 {
        return None;
    }
    // The gap does not grow in proportion (the lips have thickness and roll), so the gain is
    // refined on the measured result a few times.
    let mut opening_gain = 1.0f32;
    let (mut gap, mut width_range) = (gap_before, width_range_before);
    for _ in 0..OPENING_STEPS {
        let next = (opening_gain * TARGET_GAP / gap).clamp(1.0, MAX_GAIN);
        if (next - opening_gain).abs() <= 0.01 * opening_gain {
            break;
        }
        scale_mouth(head, next / opening_gain, 1.0);
        opening_gain = next;
        (gap, width_range) = extent(&gauge.visemes(head));
        if gap.is_nan() || gap <= 0.0 {
            break;
        }
    }
    // The corners' sideways distance is linear in the sideways motion: one step is exact.
    let width_gain = (TARGET_WIDTH_RANGE / width_range.max(1e-6)).clamp(1.0, MAX_GAIN);
    if width_gain > 1.0 {
        scale_mouth(head, 1.0, width_gain);
        (gap, width_range) = extent(&gauge.visemes(head));
    }
    Some(MouthCalibration {
        gap_before,
        gap_after: gap,
        width_range_before,
        width_range_after: width_range,
        opening_gain,
        width_gain,
    })
}

/// Refinements of the opening gain.
const OPENING_STEPS: usize = 4;

/// Multiplies every viseme's motion by `all`, and its sideways motion by `sideways` as well.
fn scale_mouth(head: &mut HeadModel, all: f32, sideways: f32) {
    for p in &mut head.primitives {
        for deltas in p.targets.iter_mut().take(VISEME_COUNT) {
            for d in deltas {
                for k in 0..3 {
                    d.position[k] *= all;
                    d.normal[k] *= all;
                }
                d.position[0] *= sideways;
            }
        }
    }
}

/// The widest gap and the width range over a set of poses.
fn extent(openings: &[MouthOpening]) -> (f32, f32) {
    let gap = openings.iter().map(|o| o.gap).fold(0.0f32, f32::max);
    let (lo, hi) = openings
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), o| {
            (lo.min(o.width), hi.max(o.width))
        });
    (gap, if hi > lo { hi - lo } else { 0.0 })
}
