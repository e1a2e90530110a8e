//! Whether a head's picture changes between two frames: a bound on how far any vertex moves,
//! in pixels. A face whose weights and pose moved it by less than a quarter of a pixel since it
//! was last drawn looks the same drawn again; the app's tiles then show the last picture. A
//! talking face moves more than that nearly every frame, a listening one (blinks aside: a head
//! drifting a fraction of a degree, a settled mouth) rarely does.

use glam::Vec3;

use crate::render::head::{HeadModel, TARGET_COUNT, slot_weights};
use crate::vocab::{FacePose, VisemeWeights};

/// Largest movement, in pixels, of a picture that is shown again rather than drawn.
pub const UNSEEN_MOTION_PX: f32 = 0.25;
/// Largest change of any slot's weight too: a shape turns normals (light and shade) by more than
/// it moves vertices where a surface folds.
const UNSEEN_WEIGHT_STEP: f32 = 0.02;

/// How far a head's shapes and rotation can move its vertices.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct MotionReach {
    /// Per target slot, the longest position delta (metres).
    slot_m: [f32; TARGET_COUNT],
    /// The farthest vertex from the neck pivot (metres), moved by a full shape too.
    pivot_m: f32,
}

impl MotionReach {
    /// The reach of `model`'s shapes, and of its turns about `pivot` (its neck pivot).
    pub(super) fn of(model: &HeadModel, pivot: Vec3) -> Self {
        let mut reach = Self::default();
        for p in &model.primitives {
            for (slot, target) in p.targets.iter().enumerate().take(TARGET_COUNT) {
                for d in target {
                    reach.slot_m[slot] = reach.slot_m[slot].max(Vec3::from(d.position).length());
                }
            }
            for v in &p.vertices {
                reach.pivot_m = reach.pivot_m.max((Vec3::from(v.position) - pivot).length());
            }
        }
        reach.pivot_m += reach.slot_m.iter().fold(0.0f32, |m, &r| m.max(r));
        reach
    }

    /// See [`super::GpuHead::looks_the_same`].
    pub(super) fn looks_the_same(
        &self,
        a: (&VisemeWeights, &FacePose),
        b: (&VisemeWeights, &FacePose),
        pixels_per_metre: f32,
    ) -> bool {
        let (wa, wb) = (slot_weights(a.0, a.1), slot_weights(b.0, b.1));
        let mut metres = 0.0;
        for ((x, y), reach) in wa.iter().zip(wb).zip(self.slot_m) {
            let step = (x - y).abs();
            if step > UNSEEN_WEIGHT_STEP {
                return false;
            }
            metres += step * reach;
        }
        let turn = a.1.head_rotation().angle_between(b.1.head_rotation());
        metres += turn * self.pivot_m;
        let pixels = metres * pixels_per_metre;
        pixels.is_finite() && pixels < UNSEEN_MOTION_PX
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vocab::Viseme;

    fn reach() -> MotionReach {
        let model = crate::render::default_head().expect("bundled head");
        MotionReach::of(&model, model.face_frame().neck_pivot())
    }

    fn open(aa: f32) -> VisemeWeights {
        let mut w = VisemeWeights::neutral();
        w.0[Viseme::Sil as usize] = 1.0 - aa;
        w.0[Viseme::Aa as usize] = aa;
        w
    }

    #[test]
    fn the_default_head_moves_its_vertices_by_centimetres() {
        let r = reach();
        let aa = r.slot_m[Viseme::Aa as usize];
        assert!((0.005..0.05).contains(&aa), "aa reaches {aa} m");
        assert!(
            (0.1..0.5).contains(&r.pivot_m),
            "{} m from the pivot",
            r.pivot_m
        );
    }

    #[test]
    fn a_step_below_a_quarter_pixel_looks_the_same_and_a_larger_one_does_not() {
        let r = reach();
        let rest = FacePose::REST;
        // Eight peers' tiles: about 900 pixels a metre.
        let ppm = 900.0;
        let aa = r.slot_m[Viseme::Aa as usize];
        let small = 0.2 / (ppm * aa) * 0.5;
        assert!(r.looks_the_same((&open(0.3), &rest), (&open(0.3), &rest), ppm));
        assert!(r.looks_the_same((&open(0.3), &rest), (&open(0.3 + small), &rest), ppm));
        assert!(!r.looks_the_same((&open(0.3), &rest), (&open(0.3 + 4.0 * small), &rest), ppm));
        // The same step is seen on a head shown ten times larger.
        assert!(!r.looks_the_same((&open(0.3), &rest), (&open(0.3 + small), &rest), 10.0 * ppm));
        // Head motion: a hundredth of a degree is unseen, a tenth is not.
        let turned = |deg: f32| FacePose {
            yaw: deg.to_radians(),
            ..rest
        };
        assert!(r.looks_the_same((&open(0.3), &rest), (&open(0.3), &turned(0.01)), ppm));
        assert!(!r.looks_the_same((&open(0.3), &rest), (&open(0.3), &turned(0.1)), ppm));
        // A blink's start is drawn.
        let blink = FacePose {
            blink: 0.05,
            ..rest
        };
        assert!(!r.looks_the_same((&open(0.3), &rest), (&open(0.3), &blink), ppm));
        assert!(!r.looks_the_same((&open(0.3), &rest), (&open(0.3), &rest), f32::NAN));
    }
}
