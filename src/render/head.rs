//! CPU-side head model: triangle meshes with per-viseme and per-expression morph deltas, and the
//! pose of the living face (blink, gaze, head rotation), independent of the GPU.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::vocab::{FacePose, VISEME_COUNT, VISEME_NAMES, VisemeWeights};

use super::RenderError;

/// The expression shapes blended beside the visemes (the eyes), in slot order after the 15
/// visemes. Looking "left" and "right" are the head's own sides (left is +X for a head facing +Z).
pub const EXPRESSION_NAMES: [&str; EXPRESSION_COUNT] = [
    "eyeBlink",
    "eyeLookUp",
    "eyeLookDown",
    "eyeLookLeft",
    "eyeLookRight",
];
/// Number of expression shapes.
pub const EXPRESSION_COUNT: usize = 5;
/// Morph target slots the renderer blends: the 15 visemes, then the expressions.
pub const TARGET_COUNT: usize = VISEME_COUNT + EXPRESSION_COUNT;

/// One expression slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Expression {
    /// Both eyes' lids closed.
    Blink,
    /// Both eyes looking up.
    LookUp,
    /// Both eyes looking down.
    LookDown,
    /// Both eyes looking to the head's own left (+X).
    LookLeft,
    /// Both eyes looking to the head's own right (-X).
    LookRight,
}

impl Expression {
    pub const ALL: [Expression; EXPRESSION_COUNT] = [
        Expression::Blink,
        Expression::LookUp,
        Expression::LookDown,
        Expression::LookLeft,
        Expression::LookRight,
    ];

    /// Index among the expressions (0..EXPRESSION_COUNT).
    pub fn index(self) -> usize {
        self as usize
    }

    /// Morph target slot (after the visemes).
    pub fn slot(self) -> usize {
        VISEME_COUNT + self as usize
    }

    /// The slot's own target name (what the tests' GLB writer writes).
    pub fn name(self) -> &'static str {
        EXPRESSION_NAMES[self as usize]
    }
}

/// Name of a morph target slot: a viseme name, then the expression names.
pub fn slot_name(slot: usize) -> Option<&'static str> {
    VISEME_NAMES
        .get(slot)
        .or_else(|| EXPRESSION_NAMES.get(slot.wrapping_sub(VISEME_COUNT)))
        .copied()
}

/// The weights of a pose's expression slots, in [`EXPRESSION_NAMES`] order: blink, and the gaze
/// split into up/down/left/right. Non-finite values count as 0; all are clamped to 0..1.
pub fn expression_weights(pose: &FacePose) -> [f32; EXPRESSION_COUNT] {
    let f = |v: f32| {
        if v.is_finite() {
            v.clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    let (x, y) = (pose.gaze.x, pose.gaze.y);
    [f(pose.blink), f(y), f(-y), f(x), f(-x)]
}

/// Weights of all [`TARGET_COUNT`] slots: the visemes as given, then the pose's expressions;
/// non-finite ones and those under [`MIN_SLOT_WEIGHT`] as 0. The pose never changes a viseme
/// weight.
pub fn slot_weights(weights: &VisemeWeights, pose: &FacePose) -> [f32; TARGET_COUNT] {
    let mut w = [0.0; TARGET_COUNT];
    for (dst, &src) in w.iter_mut().zip(weights.0.iter()) {
        *dst = src;
    }
    w[VISEME_COUNT..].copy_from_slice(&expression_weights(pose));
    for x in &mut w {
        if !x.is_finite() || x.abs() < MIN_SLOT_WEIGHT {
            *x = 0.0;
        }
    }
    w
}

/// Slot weights below this are not blended: a shape moving a vertex 2 cm moves it 0.04 mm at
/// this weight, and every slot skipped is a pass over the moving vertices saved.
pub const MIN_SLOT_WEIGHT: f32 = 1.0 / 512.0;

/// A vertex as uploaded to the GPU.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct Vertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    pub uv: [f32; 2],
    pub color: [f32; 4],
}

/// Displacement of one vertex for one target slot (viseme or expression) at full weight.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct MorphDelta {
    pub position: [f32; 3],
    pub normal: [f32; 3],
}

/// An RGBA8 (sRGB) image.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
}

/// Base colour factor (linear RGBA) and optional base colour texture.
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    pub name: String,
    pub base_color: [f32; 4],
    pub texture: Option<Texture>,
    /// Both faces drawn (glTF `doubleSided`); otherwise back faces (clockwise on screen) are culled.
    pub double_sided: bool,
}

impl Default for Material {
    fn default() -> Self {
        Self {
            name: "default".into(),
            base_color: [1.0; 4],
            texture: None,
            double_sided: false,
        }
    }
}

/// A triangle list with its morph deltas, already in head (world) space.
#[derive(Debug, Clone, PartialEq)]
pub struct Primitive {
    pub name: String,
    pub material: usize,
    pub vertices: Vec<Vertex>,
    pub indices: Vec<u32>,
    /// One entry per target slot ([`TARGET_COUNT`]: the visemes, then the expressions); each is
    /// empty (no motion) or holds one delta per vertex.
    pub targets: Vec<Vec<MorphDelta>>,
}

impl Primitive {
    /// A primitive without morph targets.
    pub fn new(name: &str, material: usize, vertices: Vec<Vertex>, indices: Vec<u32>) -> Self {
        Self {
            name: name.to_owned(),
            material,
            vertices,
            indices,
            targets: vec![Vec::new(); TARGET_COUNT],
        }
    }

    /// True when some viseme or expression moves a vertex of this primitive.
    pub fn has_targets(&self) -> bool {
        self.targets.iter().any(|t| !t.is_empty())
    }

    /// True when some viseme (a mouth shape) moves a vertex of this primitive.
    pub fn has_viseme_targets(&self) -> bool {
        self.targets
            .iter()
            .take(VISEME_COUNT)
            .any(|t| !t.is_empty())
    }
}

/// Where a head's viseme shapes came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TargetSource {
    /// Morph targets named after the visemes (`viseme_aa` or `aa`).
    Visemes,
    /// ARKit blendshapes combined through [`crate::render::arkit`].
    Arkit,
}

/// Where the mouth is and how large the face is, for framing cameras.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaceFrame {
    /// Centre of the mouth at rest.
    pub mouth: Vec3,
    /// Width of the moving mouth region (about the lip corners).
    pub mouth_width: f32,
    /// Bounding box of the primitives that carry morph targets (the head).
    pub head_min: Vec3,
    pub head_max: Vec3,
}

impl FaceFrame {
    /// Where the head turns on the neck: a little below the mouth and two mouth widths (about
    /// 10 cm on a human head) behind the lips, on the head's midline. Derived from the mouth
    /// rather than the bounding box, which may or may not include a neck.
    pub fn neck_pivot(&self) -> Vec3 {
        let w = self.mouth_width.max(1e-4);
        self.mouth + Vec3::new(0.0, -0.25 * w, -2.0 * w)
    }
}

/// A complete head: what the renderer uploads once.
#[derive(Debug, Clone, PartialEq)]
pub struct HeadModel {
    pub primitives: Vec<Primitive>,
    pub materials: Vec<Material>,
    pub source: TargetSource,
    /// Visemes that have no shape in this head (they blend as the neutral face).
    pub missing_visemes: Vec<String>,
}

impl HeadModel {
    /// Checks the invariants the renderer relies on.
    pub fn validate(&self) -> Result<(), RenderError> {
        if self.primitives.is_empty() {
            return Err(RenderError::InvalidHead("no triangle meshes".into()));
        }
        for p in &self.primitives {
            let n = p.vertices.len();
            if p.material >= self.materials.len() {
                return Err(RenderError::InvalidHead(format!(
                    "primitive {:?} uses missing material {}",
                    p.name, p.material
                )));
            }
            if p.indices.len() % 3 != 0 || p.indices.iter().any(|&i| i as usize >= n) {
                return Err(RenderError::InvalidHead(format!(
                    "primitive {:?} has bad triangle indices",
                    p.name
                )));
            }
            if p.targets.len() != TARGET_COUNT
                || p.targets.iter().any(|t| !t.is_empty() && t.len() != n)
            {
                return Err(RenderError::InvalidHead(format!(
                    "primitive {:?} has morph targets of the wrong size",
                    p.name
                )));
            }
        }
        if !self.primitives.iter().any(Primitive::has_viseme_targets) {
            return Err(RenderError::NoUsableTargets { found: Vec::new() });
        }
        Ok(())
    }

    /// True when some primitive has a shape for the expression (a head without
    /// [`Expression::Blink`] does not blink).
    pub fn has_expression(&self, expression: Expression) -> bool {
        self.primitives.iter().any(|p| {
            p.targets
                .get(expression.slot())
                .is_some_and(|t| !t.is_empty())
        })
    }

    pub fn vertex_count(&self) -> usize {
        self.primitives.iter().map(|p| p.vertices.len()).sum()
    }

    pub fn triangle_count(&self) -> usize {
        self.primitives.iter().map(|p| p.indices.len() / 3).sum()
    }

    /// Reference blend on the CPU with the eyes at rest: every vertex of every primitive, in
    /// order.
    pub fn blend_cpu(&self, weights: &VisemeWeights) -> Vec<Vertex> {
        self.blend_cpu_posed(weights, &FacePose::REST)
    }

    /// Reference blend on the CPU of every slot, the pose's expressions included (in head space:
    /// the head rotation is the model matrix's, not the blend's). What the vertex shader and
    /// its compute twin `cs_blend` compute.
    pub fn blend_cpu_posed(&self, weights: &VisemeWeights, pose: &FacePose) -> Vec<Vertex> {
        let slots = slot_weights(weights, pose);
        let mut out = Vec::with_capacity(self.vertex_count());
        for p in &self.primitives {
            for (i, v) in p.vertices.iter().enumerate() {
                let mut pos = Vec3::from(v.position);
                let mut nrm = Vec3::from(v.normal);
                for (t, target) in p.targets.iter().enumerate() {
                    let w = slots.get(t).copied().unwrap_or(0.0);
                    if w != 0.0 && !target.is_empty() {
                        pos += w * Vec3::from(target[i].position);
                        nrm += w * Vec3::from(target[i].normal);
                    }
                }
                out.push(Vertex {
                    position: pos.into(),
                    normal: nrm.into(),
                    ..*v
                });
            }
        }
        out
    }

    /// Estimates the mouth: its corners are the vertices that move sideways the most between the
    /// spread `I` and the rounded `U`; without those shapes, the centroid of the lip motion.
    pub fn face_frame(&self) -> FaceFrame {
        let mut head_min = Vec3::splat(f32::INFINITY);
        let mut head_max = Vec3::splat(f32::NEG_INFINITY);
        for p in self.primitives.iter().filter(|p| p.has_targets()) {
            for v in &p.vertices {
                head_min = head_min.min(Vec3::from(v.position));
                head_max = head_max.max(Vec3::from(v.position));
            }
        }
        if !head_min.is_finite() {
            for v in self.primitives.iter().flat_map(|p| &p.vertices) {
                head_min = head_min.min(Vec3::from(v.position));
                head_max = head_max.max(Vec3::from(v.position));
            }
        }
        if !head_min.is_finite() {
            head_min = Vec3::splat(-0.1);
            head_max = Vec3::splat(0.1);
        }
        let centre_x = 0.5 * (head_min.x + head_max.x);
        let size = head_max - head_min;
        let fallback = FaceFrame {
            mouth: Vec3::new(centre_x, head_min.y + 0.3 * size.y, head_max.z),
            mouth_width: size.x * 0.35,
            head_min,
            head_max,
        };
        let (i, u) = (12, 14);
        // Best corner candidate on each side: (score, position).
        let mut best = [(0.0f32, Vec3::ZERO); 2];
        for p in self.primitives.iter().filter(|p| p.has_targets()) {
            let (ti, tu) = (&p.targets[i], &p.targets[u]);
            if ti.is_empty() || tu.is_empty() {
                continue;
            }
            for (k, v) in p.vertices.iter().enumerate() {
                let pos = Vec3::from(v.position);
                let side = if pos.x >= centre_x { 1 } else { 0 };
                let sign = if side == 1 { 1.0 } else { -1.0 };
                let score = (ti[k].position[0] - tu[k].position[0]) * sign;
                if score > best[side].0 {
                    best[side] = (score, pos);
                }
            }
        }
        if best[0].0 > 0.0 && best[1].0 > 0.0 {
            let mouth = 0.5 * (best[0].1 + best[1].1);
            let width = (best[1].1.x - best[0].1.x).abs();
            if width > size.x * 0.1 {
                return FaceFrame {
                    mouth,
                    mouth_width: width,
                    head_min,
                    head_max,
                };
            }
        }
        // Weighted centroid of strongly moving vertices.
        let mut max_motion = 0.0f32;
        for p in self.primitives.iter().filter(|p| p.has_targets()) {
            for k in 0..p.vertices.len() {
                max_motion = max_motion.max(total_motion(p, k));
            }
        }
        let mut sum = Vec3::ZERO;
        let mut total = 0.0f32;
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for p in self.primitives.iter().filter(|p| p.has_targets()) {
            for (k, v) in p.vertices.iter().enumerate() {
                let m = total_motion(p, k);
                if max_motion > 0.0 && m >= 0.35 * max_motion {
                    let pos = Vec3::from(v.position);
                    sum += m * pos;
                    total += m;
                    lo = lo.min(pos.x);
                    hi = hi.max(pos.x);
                }
            }
        }
        if total > 0.0 && hi > lo {
            FaceFrame {
                mouth: sum / total,
                mouth_width: (hi - lo).max(size.x * 0.15),
                head_min,
                head_max,
            }
        } else {
            fallback
        }
    }
}

/// How far vertex `k` moves over all mouth shapes (the eyes' shapes do not count).
fn total_motion(p: &Primitive, k: usize) -> f32 {
    p.targets
        .iter()
        .take(VISEME_COUNT)
        .filter_map(|t| t.get(k))
        .map(|d| Vec3::from(d.position).length())
        .sum()
}

/// Area-weighted smooth vertex normals for a triangle list.
pub fn smooth_normals(positions: &[Vec3], indices: &[u32]) -> Vec<Vec3> {
    let mut normals = vec![Vec3::ZERO; positions.len()];
    for tri in indices.chunks_exact(3) {
        let [a, b, c] = [tri[0] as usize, tri[1] as usize, tri[2] as usize];
        if a >= positions.len() || b >= positions.len() || c >= positions.len() {
            continue;
        }
        let n = (positions[b] - positions[a]).cross(positions[c] - positions[a]);
        normals[a] += n;
        normals[b] += n;
        normals[c] += n;
    }
    normals
        .into_iter()
        .map(|n| n.try_normalize().unwrap_or(Vec3::Y))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Mat4, Vec2};

    #[test]
    fn the_pose_drives_only_the_eye_slots() {
        let weights = VisemeWeights::from_named([("aa", 0.7), ("PP", 0.3)]).unwrap();
        let pose = FacePose {
            blink: 0.8,
            gaze: Vec2::new(-0.2, 0.1),
            pitch: 0.05,
            yaw: -0.03,
            roll: 0.02,
        };
        let slots = slot_weights(&weights, &pose);
        assert_eq!(slots[..VISEME_COUNT], weights.0);
        assert_eq!(slots[Expression::Blink.slot()], 0.8);
        assert_eq!(slots[Expression::LookUp.slot()], 0.1);
        assert_eq!(slots[Expression::LookDown.slot()], 0.0);
        assert_eq!(slots[Expression::LookLeft.slot()], 0.0);
        assert_eq!(slots[Expression::LookRight.slot()], 0.2);
        let odd = FacePose {
            blink: f32::NAN,
            gaze: Vec2::new(3.0, f32::INFINITY),
            ..FacePose::REST
        };
        assert_eq!(
            expression_weights(&odd),
            [0.0, 0.0, 0.0, 1.0, 0.0],
            "non-finite as 0, clamped to 1"
        );
        assert_eq!(
            slot_weights(&weights, &FacePose::REST)[VISEME_COUNT..],
            [0.0; 5]
        );
        assert_eq!(
            slot_name(Expression::LookRight.slot()),
            Some("eyeLookRight")
        );
        assert_eq!(slot_name(10), Some("aa"));
        assert_eq!(slot_name(TARGET_COUNT), None);
    }

    #[test]
    fn head_motion_is_a_rotation_about_the_neck_pivot() {
        let pivot = Vec3::new(0.0, -0.02, -0.1);
        assert_eq!(FacePose::REST.head_matrix(pivot), Mat4::IDENTITY);
        let nod = FacePose {
            pitch: 0.1,
            ..FacePose::REST
        };
        let m = nod.head_matrix(pivot);
        assert!(m.transform_point3(pivot).abs_diff_eq(pivot, 1e-6));
        // A positive pitch brings the chin (below and in front of the pivot) down and back...
        let chin = pivot + Vec3::new(0.0, -0.05, 0.1);
        let moved = m.transform_point3(chin);
        assert!(moved.y < chin.y && moved.z < chin.z, "{moved}");
        // ... and the nose tip (in front) down.
        let nose = pivot + Vec3::new(0.0, 0.0, 0.12);
        assert!(m.transform_point3(nose).y < nose.y);
        // A positive yaw turns the face to the head's left (+X).
        let turn = FacePose {
            yaw: 0.1,
            ..FacePose::REST
        };
        assert!(turn.head_matrix(pivot).transform_point3(nose).x > 0.0);
        // Rigid: lengths and angles kept, so normals go through the same matrix.
        let all = FacePose {
            pitch: 0.07,
            yaw: -0.05,
            roll: 0.04,
            ..FacePose::REST
        };
        let m3 = glam::Mat3::from_mat4(all.head_matrix(pivot));
        assert!((m3 * m3.transpose()).abs_diff_eq(glam::Mat3::IDENTITY, 1e-6));
        assert!((m3.determinant() - 1.0).abs() < 1e-6);
        assert!(!all.head_is_still() && all.without_head_motion().head_is_still());
    }
}
