//! CPU-side head model: triangle meshes with per-viseme morph deltas, independent of the GPU.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use super::RenderError;

/// The 15 viseme names of the Oculus / MPEG-4 set, in the order used everywhere in the renderer.
pub const VISEME_NAMES: [&str; VISEME_COUNT] = [
    "sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "I", "O", "U",
];
/// Number of viseme shapes the renderer blends.
pub const VISEME_COUNT: usize = 15;

/// Index of a viseme name in [`VISEME_NAMES`] (exact spelling, as in the design brief).
pub fn viseme_index(name: &str) -> Option<usize> {
    VISEME_NAMES.iter().position(|v| *v == name)
}

/// One weight per viseme, in [`VISEME_NAMES`] order. Convex weights are expected
/// (non-negative, sum 1); the renderer blends whatever it is given.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisemeWeights(pub [f32; VISEME_COUNT]);

impl Default for VisemeWeights {
    fn default() -> Self {
        Self::neutral()
    }
}

impl VisemeWeights {
    /// All weight on `sil`: the neutral face.
    pub fn neutral() -> Self {
        Self::one_hot(0)
    }

    /// All weight on viseme `index` (clamped into range).
    pub fn one_hot(index: usize) -> Self {
        let mut w = [0.0; VISEME_COUNT];
        w[index.min(VISEME_COUNT - 1)] = 1.0;
        Self(w)
    }

    /// All weight on the named viseme.
    pub fn single(name: &str) -> Option<Self> {
        viseme_index(name).map(Self::one_hot)
    }

    /// Builds weights from (name, weight) pairs of a possibly reduced viseme set.
    pub fn from_named<'a>(
        pairs: impl IntoIterator<Item = (&'a str, f32)>,
    ) -> Result<Self, RenderError> {
        let mut w = [0.0; VISEME_COUNT];
        for (name, value) in pairs {
            let i =
                viseme_index(name).ok_or_else(|| RenderError::UnknownViseme(name.to_owned()))?;
            w[i] += value;
        }
        Ok(Self(w))
    }

    /// Linear interpolation; convex inputs give a convex result.
    pub fn lerp(&self, other: &Self, t: f32) -> Self {
        let mut w = [0.0; VISEME_COUNT];
        for (i, out) in w.iter_mut().enumerate() {
            *out = self.0[i] + (other.0[i] - self.0[i]) * t;
        }
        Self(w)
    }
}

/// A vertex as uploaded to the GPU.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct Vertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    pub uv: [f32; 2],
    pub color: [f32; 4],
}

/// Displacement of one vertex for one viseme at full weight.
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
}

impl Default for Material {
    fn default() -> Self {
        Self {
            name: "default".into(),
            base_color: [1.0; 4],
            texture: None,
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
    /// One entry per viseme; each is empty (no motion) or holds one delta per vertex.
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
            targets: vec![Vec::new(); VISEME_COUNT],
        }
    }

    /// True when some viseme moves a vertex of this primitive.
    pub fn has_targets(&self) -> bool {
        self.targets.iter().any(|t| !t.is_empty())
    }
}

/// Where a head's viseme shapes came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TargetSource {
    /// Made by lipcall's own generator.
    Procedural,
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
            if p.targets.len() != VISEME_COUNT
                || p.targets.iter().any(|t| !t.is_empty() && t.len() != n)
            {
                return Err(RenderError::InvalidHead(format!(
                    "primitive {:?} has morph targets of the wrong size",
                    p.name
                )));
            }
        }
        if !self.primitives.iter().any(Primitive::has_targets) {
            return Err(RenderError::NoUsableTargets { found: Vec::new() });
        }
        Ok(())
    }

    pub fn vertex_count(&self) -> usize {
        self.primitives.iter().map(|p| p.vertices.len()).sum()
    }

    pub fn triangle_count(&self) -> usize {
        self.primitives.iter().map(|p| p.indices.len() / 3).sum()
    }

    /// Reference blend on the CPU: every vertex of every primitive, in order.
    pub fn blend_cpu(&self, weights: &VisemeWeights) -> Vec<Vertex> {
        let mut out = Vec::with_capacity(self.vertex_count());
        for p in &self.primitives {
            for (i, v) in p.vertices.iter().enumerate() {
                let mut pos = Vec3::from(v.position);
                let mut nrm = Vec3::from(v.normal);
                for (t, target) in p.targets.iter().enumerate() {
                    let w = weights.0[t];
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

fn total_motion(p: &Primitive, k: usize) -> f32 {
    p.targets
        .iter()
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
