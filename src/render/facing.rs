//! Triangles a frontal camera can see. The app's tiles and the rendered frames look at a head
//! from the front ([`Camera::framing`]), and the living face turns it by at most
//! [`HEAD_MAX_RAD`]: about 30 % of a head's triangles (the back of the skull and neck, the far
//! sides of the teeth, eyeballs and ears) then face away in every frame. Back-face culling
//! drops them anyway, but a software adapter shades their vertices and sets them up first; left
//! out of the draws, they cost nothing and no pixel changes (`tests/render_unseen.rs`).

use glam::Vec3;

use super::camera::{Camera, Framing};
use super::head::{FaceFrame, MorphDelta, Primitive};
use crate::vocab::FacePose;
use crate::vocab::pose::HEAD_MAX_RAD;

/// Degrees beyond the pose bounds that are tested too.
const ANGLE_MARGIN_DEG: f32 = 3.0;
/// How far past edge-on (a sine: about 3 degrees) a triangle may face and still be kept. A
/// blend of shapes tilts a triangle between the tilts of the shapes tested, not exactly within
/// them.
const EDGE_ON_MARGIN: f32 = 0.05;

/// The eye positions of the frontal framings of a head with this face frame.
pub fn frontal_eyes(frame: &FaceFrame) -> [Vec3; 2] {
    [Framing::Face, Framing::Mouth].map(|f| Camera::framing(frame, f).eye)
}

/// The eye positions that see a frontal framing of a head, the head's own turns folded in.
pub struct FrontalEyes(Vec<Vec3>);

impl FrontalEyes {
    /// Each frontal framing's eye, seen from the still head as the head turns about its neck
    /// pivot by up to the bounds (and a margin) on each axis.
    pub fn of(frame: &FaceFrame) -> Self {
        let pivot = frame.neck_pivot();
        let span = |axis: usize| {
            let max = HEAD_MAX_RAD[axis] + ANGLE_MARGIN_DEG.to_radians();
            [-max, 0.0, max]
        };
        // Turning the head by a rotation is seeing the still head from the eye turned back by
        // it.
        let mut eyes = Vec::with_capacity(54);
        for eye in frontal_eyes(frame) {
            for pitch in span(0) {
                for yaw in span(1) {
                    for roll in span(2) {
                        let pose = FacePose {
                            pitch,
                            yaw,
                            roll,
                            ..FacePose::REST
                        };
                        eyes.push(pivot + pose.head_rotation().inverse() * (eye - pivot));
                    }
                }
            }
        }
        Self(eyes)
    }

    /// The triangles of `indices` (into `p`'s vertices) that some eye sees from the front in
    /// the rest pose or with one morph target at full weight.
    pub fn triangles(&self, p: &Primitive, indices: &[u32]) -> Vec<u32> {
        let none = MorphDelta::default();
        let targets: Vec<&Vec<MorphDelta>> = p.targets.iter().filter(|t| !t.is_empty()).collect();
        let seen = |tri: &[u32], target: Option<&Vec<MorphDelta>>| {
            let [a, b, c] = [tri[0], tri[1], tri[2]].map(|i| {
                let d = target.and_then(|t| t.get(i as usize)).unwrap_or(&none);
                Vec3::from(p.vertices[i as usize].position) + Vec3::from(d.position)
            });
            let n = (b - a).cross(c - a);
            let n_len = n.length();
            self.0.iter().any(|&e| {
                let v = e - a;
                v.dot(n) > -EDGE_ON_MARGIN * v.length() * n_len
            })
        };
        let moves = |tri: &[u32], target: &Vec<MorphDelta>| {
            tri.iter().any(|&i| {
                target
                    .get(i as usize)
                    .is_some_and(|d| d.position != none.position)
            })
        };
        indices
            .chunks_exact(3)
            .filter(|tri| {
                seen(tri, None) || targets.iter().any(|t| moves(tri, t) && seen(tri, Some(t)))
            })
            .flatten()
            .copied()
            .collect()
    }
}
