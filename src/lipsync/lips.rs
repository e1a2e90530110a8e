//! Visual lip targets from tracked face landmarks (MediaPipe face mesh points, as in the GRID
//! tracks): head motion taken out as the seed paper takes it out of its markers (the nose tip
//! is the origin, the outer-eye line is horizontal, the outer-eye distance is the unit), then
//! the measures a lip-sync face must reproduce.

/// Face-mesh landmark indices the targets use.
pub mod landmark {
    pub const NOSE_TIP: usize = 1;
    pub const RIGHT_EYE_OUTER: usize = 33;
    pub const LEFT_EYE_OUTER: usize = 263;
    pub const RIGHT_MOUTH_CORNER: usize = 61;
    pub const LEFT_MOUTH_CORNER: usize = 291;
    pub const UPPER_LIP_TOP: usize = 0;
    pub const LOWER_LIP_BOTTOM: usize = 17;
    pub const UPPER_LIP_INNER: usize = 13;
    pub const LOWER_LIP_INNER: usize = 14;
    /// Every landmark a [`LipFrame`] needs, in its order.
    pub const USED: [usize; 9] = [
        NOSE_TIP,
        RIGHT_EYE_OUTER,
        LEFT_EYE_OUTER,
        RIGHT_MOUTH_CORNER,
        LEFT_MOUTH_CORNER,
        UPPER_LIP_TOP,
        LOWER_LIP_BOTTOM,
        UPPER_LIP_INNER,
        LOWER_LIP_INNER,
    ];
}

/// One landmark: x right and y down in image pixels, z the tracker's depth in the same scale
/// (smaller is nearer the camera).
pub type Point = [f32; 3];

/// The landmarks of one video frame, in the order of [`landmark::USED`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LipFrame(pub [Point; landmark::USED.len()]);

/// What the lips do in one frame, in outer-eye distances.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LipTargets {
    /// The gap between the inner lips' midpoints, across the eye line.
    pub aperture: f32,
    /// Corner to corner.
    pub width: f32,
    /// How far the lips' midpoints stand forward of the nose tip's depth (larger: pouted).
    pub protrusion: f32,
    /// How far the lower lip stands behind the upper one in depth (larger: lower lip drawn in,
    /// as under the teeth for /f v/).
    pub lower_lip_back: f32,
}

impl LipTargets {
    pub const NAMES: [&'static str; 4] = ["aperture", "width", "protrusion", "lower_lip_back"];

    pub fn values(&self) -> [f32; 4] {
        [
            self.aperture,
            self.width,
            self.protrusion,
            self.lower_lip_back,
        ]
    }
}

#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum LipError {
    #[error("the outer eye corners coincide: no unit to measure the face in")]
    NoEyeDistance,
    #[error("a landmark coordinate is not a finite number")]
    NotFinite,
}

impl LipFrame {
    fn get(&self, index: usize) -> Point {
        let slot = landmark::USED
            .iter()
            .position(|&i| i == index)
            .expect("only landmarks of USED are asked for");
        self.0[slot]
    }

    /// The targets with head position, in-plane rotation and size taken out.
    pub fn targets(&self) -> Result<LipTargets, LipError> {
        use landmark::*;
        if self.0.iter().flatten().any(|c| !c.is_finite()) {
            return Err(LipError::NotFinite);
        }
        let nose = self.get(NOSE_TIP);
        let (right_eye, left_eye) = (self.get(RIGHT_EYE_OUTER), self.get(LEFT_EYE_OUTER));
        let (dx, dy) = (left_eye[0] - right_eye[0], left_eye[1] - right_eye[1]);
        let unit = dx.hypot(dy);
        if unit < 1e-3 {
            return Err(LipError::NoEyeDistance);
        }
        // Rotating by the eye line's angle makes it horizontal; (c, s) is its unit vector.
        let (c, s) = (dx / unit, dy / unit);
        let face = |index: usize| -> Point {
            let p = self.get(index);
            let (x, y) = (p[0] - nose[0], p[1] - nose[1]);
            [
                (c * x + s * y) / unit,
                (-s * x + c * y) / unit,
                (p[2] - nose[2]) / unit,
            ]
        };
        let (upper_inner, lower_inner) = (face(UPPER_LIP_INNER), face(LOWER_LIP_INNER));
        let (right, left) = (face(RIGHT_MOUTH_CORNER), face(LEFT_MOUTH_CORNER));
        let (upper, lower) = (face(UPPER_LIP_TOP), face(LOWER_LIP_BOTTOM));
        Ok(LipTargets {
            // y points down the face once the eye line is level: the lower lip lies below.
            aperture: lower_inner[1] - upper_inner[1],
            width: (left[0] - right[0]).hypot(left[1] - right[1]),
            protrusion: -0.5 * (upper[2] + lower[2]),
            lower_lip_back: lower[2] - upper[2],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plausible frontal face: eyes 60 px apart, mouth 45 px wide and 5 px open.
    fn face() -> LipFrame {
        LipFrame([
            [160.0, 160.0, -20.0], // nose tip
            [130.0, 130.0, 5.0],   // right eye outer
            [190.0, 130.0, 5.0],   // left eye outer
            [137.0, 205.0, 8.0],   // right mouth corner
            [182.0, 205.0, 8.0],   // left mouth corner
            [160.0, 197.0, -9.0],  // upper lip top
            [160.0, 214.0, -5.0],  // lower lip bottom
            [160.0, 204.0, -4.0],  // upper lip inner
            [160.0, 209.0, -4.0],  // lower lip inner
        ])
    }

    fn transformed(frame: &LipFrame, angle: f32, scale: f32, shift: [f32; 2]) -> LipFrame {
        let (s, c) = angle.sin_cos();
        LipFrame(frame.0.map(|[x, y, z]| {
            [
                scale * (c * x - s * y) + shift[0],
                scale * (s * x + c * y) + shift[1],
                scale * z + 3.0,
            ]
        }))
    }

    fn assert_close(a: LipTargets, b: LipTargets) {
        for (x, y) in a.values().iter().zip(b.values()) {
            assert!((x - y).abs() < 1e-4, "{a:?} vs {b:?}");
        }
    }

    #[test]
    fn targets_are_measured_in_eye_distances() {
        let t = face().targets().unwrap();
        assert!((t.aperture - 5.0 / 60.0).abs() < 1e-6, "{t:?}");
        assert!((t.width - 45.0 / 60.0).abs() < 1e-6);
        // The lips stand 13 px behind the nose tip.
        assert!((t.protrusion + 13.0 / 60.0).abs() < 1e-6);
        assert!((t.lower_lip_back - 4.0 / 60.0).abs() < 1e-6);
    }

    #[test]
    fn a_moved_rotated_scaled_face_gives_the_same_targets() {
        let base = face().targets().unwrap();
        for (angle, scale, shift) in [
            (0.3, 1.0, [0.0, 0.0]),
            (-0.5, 1.7, [-40.0, 25.0]),
            (0.0, 0.4, [100.0, -3.0]),
            (3.0, 2.2, [7.0, 7.0]),
        ] {
            assert_close(
                transformed(&face(), angle, scale, shift).targets().unwrap(),
                base,
            );
        }
    }

    #[test]
    fn opening_and_spreading_move_their_own_targets() {
        let mut open = face();
        open.0[8][1] += 6.0;
        let (a, b) = (face().targets().unwrap(), open.targets().unwrap());
        assert!(b.aperture > a.aperture + 0.09 && (b.width - a.width).abs() < 1e-6);
        let mut spread = face();
        spread.0[3][0] -= 6.0;
        spread.0[4][0] += 6.0;
        let c = spread.targets().unwrap();
        assert!((c.width - a.width - 0.2).abs() < 1e-5 && (c.aperture - a.aperture).abs() < 1e-6);
        let mut pout = face();
        for p in [5, 6] {
            pout.0[p][2] -= 6.0;
        }
        assert!((pout.targets().unwrap().protrusion - a.protrusion - 0.1).abs() < 1e-5);
    }

    #[test]
    fn degenerate_faces_are_errors() {
        let mut f = face();
        f.0[2] = f.0[1];
        assert_eq!(f.targets(), Err(LipError::NoEyeDistance));
        let mut f = face();
        f.0[4][2] = f32::NAN;
        assert_eq!(f.targets(), Err(LipError::NotFinite));
    }
}
