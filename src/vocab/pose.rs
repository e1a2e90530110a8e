//! What a face does besides its mouth, frame by frame: the living face's output and the
//! renderer's input.

use glam::{Mat4, Quat, Vec2, Vec3};

const DEG: f32 = std::f32::consts::PI / 180.0;

/// Largest head angles (radians) the living face makes: pitch, yaw, roll. The renderer leaves
/// out the triangles that cannot face a frontal camera within them (`render::facing`).
pub const HEAD_MAX_RAD: [f32; 3] = [
    5.0 * DEG, // nods
    4.0 * DEG, // turns
    3.0 * DEG, // tilts
];

/// What a face does besides its mouth, for one frame: eyelids, gaze and head rotation. The
/// living face (the living face (`lipsync::life`)) makes one per 20 ms frame; [`FacePose::REST`] is a
/// still head looking ahead with open eyes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FacePose {
    /// Eyelid closure: 0 open .. 1 shut.
    pub blink: f32,
    /// Gaze in head space, as a fraction of the head's full eye-look shapes (-1..1): x > 0 looks
    /// to the head's own left (+X), y > 0 up.
    pub gaze: Vec2,
    /// Head rotation about the neck pivot (the head's neck pivot), in radians: `pitch` about
    /// +X (positive: chin down, a nod), `yaw` about +Y (positive: the face turns to the head's
    /// left), `roll` about +Z (positive: the top of the head tilts to the head's right).
    pub pitch: f32,
    pub yaw: f32,
    pub roll: f32,
}

impl FacePose {
    /// Eyes open and ahead, head still.
    pub const REST: FacePose = FacePose {
        blink: 0.0,
        gaze: Vec2::ZERO,
        pitch: 0.0,
        yaw: 0.0,
        roll: 0.0,
    };

    /// The same eyes with the head still (the lipreading close-up keeps the mouth steady).
    pub fn without_head_motion(self) -> Self {
        Self {
            pitch: 0.0,
            yaw: 0.0,
            roll: 0.0,
            ..self
        }
    }

    /// True when each head angle is within [`HEAD_MAX_RAD`].
    pub fn head_within_bounds(&self) -> bool {
        [self.pitch, self.yaw, self.roll]
            .iter()
            .zip(HEAD_MAX_RAD)
            .all(|(a, max)| a.abs() <= max)
    }

    /// True when the head is not rotated (exactly).
    pub fn head_is_still(&self) -> bool {
        self.pitch == 0.0 && self.yaw == 0.0 && self.roll == 0.0
    }

    /// The head's rotation as a quaternion (yaw, then pitch, then roll); identity for
    /// non-finite angles.
    pub fn head_rotation(&self) -> Quat {
        let finite = |v: f32| if v.is_finite() { v } else { 0.0 };
        Quat::from_euler(
            glam::EulerRot::YXZ,
            finite(self.yaw),
            finite(self.pitch),
            finite(self.roll),
        )
    }

    /// The head rotation about `pivot` as a model matrix (a rigid motion, so it transforms
    /// normals too); exactly the identity for a still head.
    pub fn head_matrix(&self, pivot: Vec3) -> Mat4 {
        if self.head_is_still() {
            return Mat4::IDENTITY;
        }
        Mat4::from_translation(pivot)
            * Mat4::from_quat(self.head_rotation())
            * Mat4::from_translation(-pivot)
    }

    /// Linear interpolation of every component.
    pub fn lerp(&self, other: &Self, t: f32) -> Self {
        let l = |a: f32, b: f32| a + (b - a) * t;
        Self {
            blink: l(self.blink, other.blink),
            gaze: self.gaze.lerp(other.gaze, t),
            pitch: l(self.pitch, other.pitch),
            yaw: l(self.yaw, other.yaw),
            roll: l(self.roll, other.roll),
        }
    }
}
