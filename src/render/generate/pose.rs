//! Mouth poses of the default head: a few articulatory parameters per viseme, after the design
//! brief's table, and the deformation that turns a pose into vertex positions.

use glam::{Quat, Vec3};

/// Articulatory parameters (0 = rest). `width` is signed: spread +, narrow -.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MouthPose {
    /// Jaw rotation, 1 = wide open.
    pub jaw: f32,
    /// Extra parting of the lips beyond what the jaw gives.
    pub aperture: f32,
    pub width: f32,
    /// Lips pushed forward (and rounded, with negative width).
    pub protrusion: f32,
    /// Lips pressed together and rolled in (bilabial closure).
    pub press: f32,
    /// Lower lip drawn up and back under the upper teeth.
    pub tuck: f32,
    /// Upper lip raised off the upper teeth.
    pub upper_raise: f32,
    /// Lower lip lowered off the lower teeth.
    pub lower_down: f32,
    /// Tongue tip pushed forward between the teeth.
    pub tongue_out: f32,
    /// Tongue tip raised to the ridge behind the upper teeth.
    pub tongue_up: f32,
    /// Back of the tongue raised (velar), tip lowered.
    pub tongue_back: f32,
}

/// The pose of each viseme, in [`crate::render::head::VISEME_NAMES`] order.
pub fn viseme_poses() -> [MouthPose; 15] {
    let p = |jaw, aperture, width, protrusion| MouthPose {
        jaw,
        aperture,
        width,
        protrusion,
        ..MouthPose::default()
    };
    [
        // sil: the rest shape is the base mesh itself.
        MouthPose::default(),
        // PP
        MouthPose {
            press: 1.0,
            ..p(0.0, 0.0, 0.0, 0.0)
        },
        // FF
        MouthPose {
            tuck: 1.0,
            upper_raise: 0.6,
            ..p(0.12, 0.0, 0.1, 0.0)
        },
        // TH
        MouthPose {
            tongue_out: 1.0,
            upper_raise: 0.3,
            ..p(0.22, 0.3, 0.1, 0.0)
        },
        // DD
        MouthPose {
            tongue_up: 1.0,
            upper_raise: 0.35,
            lower_down: 0.3,
            ..p(0.2, 0.3, 0.15, 0.0)
        },
        // kk
        MouthPose {
            tongue_back: 1.0,
            ..p(0.32, 0.35, 0.1, 0.0)
        },
        // CH
        MouthPose {
            upper_raise: 0.5,
            lower_down: 0.5,
            ..p(0.12, 0.45, -0.35, 0.8)
        },
        // SS
        MouthPose {
            upper_raise: 0.55,
            lower_down: 0.55,
            ..p(0.08, 0.2, 0.35, 0.0)
        },
        // nn
        MouthPose {
            tongue_up: 0.8,
            upper_raise: 0.2,
            ..p(0.22, 0.3, 0.1, 0.0)
        },
        // RR
        MouthPose {
            upper_raise: 0.2,
            ..p(0.2, 0.3, -0.35, 0.5)
        },
        // aa
        MouthPose {
            upper_raise: 0.2,
            lower_down: 0.2,
            ..p(1.0, 0.8, 0.1, 0.0)
        },
        // E
        MouthPose {
            upper_raise: 0.4,
            lower_down: 0.4,
            ..p(0.45, 0.5, 0.4, 0.0)
        },
        // I
        MouthPose {
            upper_raise: 0.6,
            lower_down: 0.6,
            ..p(0.18, 0.35, 0.75, 0.0)
        },
        // O
        MouthPose {
            ..p(0.55, 0.75, -0.55, 0.6)
        },
        // U
        MouthPose {
            ..p(0.18, 0.3, -0.85, 1.0)
        },
    ]
}

/// Landmarks of the generated head that the deformation needs.
#[derive(Debug, Clone, Copy)]
pub struct Anatomy {
    /// Height of the mouth line.
    pub mouth_y: f32,
    /// Depth of the lips at the mouth line's centre.
    pub mouth_z: f32,
    /// Half the mouth width (centre to corner).
    pub half_width: f32,
    /// Jaw hinge (temporomandibular joint) height and depth.
    pub hinge: Vec3,
    /// Depth of the front of the upper incisors.
    pub teeth_z: f32,
}

/// Which part of the head a vertex belongs to, and how it moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    /// Face skin above the lip line (or away from the mouth).
    SkinUpper,
    /// Face skin below the lip line, inside the mouth corners.
    SkinLower,
    /// Mouth interior (moves with the jaw below the lip line).
    Cavity,
    UpperTeeth,
    LowerTeeth,
    Tongue,
    /// Eyes and anything else rigid.
    Rigid,
}

const JAW_MAX_DEG: f32 = 17.0;

fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Weight of the jaw rotation for a skin vertex.
fn jaw_weight(p: Vec3, part: Part, a: &Anatomy) -> f32 {
    let hw = a.half_width;
    // Below the lip line the skin follows the jaw; around the corners it stretches.
    let below = smoothstep(a.mouth_y + 0.012, a.mouth_y - 0.014, p.y);
    let corner = smoothstep(0.15 * hw, 1.05 * hw, p.x.abs()).powf(0.8);
    let w = match part {
        Part::SkinLower => 1.0 + (below - 1.0) * corner,
        _ => below * corner,
    };
    // The neck and the back of the head stay put.
    let neck = smoothstep(-0.125, -0.085, p.y + 0.35 * (p.z - 0.06).max(0.0));
    let front = smoothstep(-0.05, 0.0, p.z);
    w * neck * front
}

/// Lip region weight: 1 on the lips, fading over the surrounding skin.
fn lip_weight(p: Vec3, a: &Anatomy, reach_x: f32, reach_y: f32) -> f32 {
    let dx = (p.x.abs() / (a.half_width * reach_x)).powi(2);
    let dy = ((p.y - a.mouth_y) / reach_y).powi(2);
    let front = smoothstep(a.mouth_z - 0.03, a.mouth_z - 0.01, p.z);
    (1.0 - (dx + dy)).max(0.0).powf(1.5) * front
}

/// Moves a base-mesh vertex into `pose`.
pub fn deform(p: Vec3, part: Part, pose: &MouthPose, a: &Anatomy) -> Vec3 {
    let hw = a.half_width;
    let rot = Quat::from_rotation_x((pose.jaw * JAW_MAX_DEG).to_radians());
    let jaw_rotate = |q: Vec3, w: f32| q.lerp(a.hinge + rot * (q - a.hinge), w);
    match part {
        Part::Rigid | Part::UpperTeeth => p,
        Part::LowerTeeth => jaw_rotate(p, 1.0),
        Part::Cavity => {
            let w = smoothstep(a.mouth_y + 0.006, a.mouth_y - 0.012, p.y);
            jaw_rotate(p, w)
        }
        Part::Tongue => {
            let mut q = p;
            // Distance from the tip, front to back, 0 at the tip.
            let from_tip = ((a.teeth_z - 0.004) - p.z).max(0.0);
            let tip = smoothstep(0.022, 0.0, from_tip);
            let back = smoothstep(0.01, 0.035, from_tip);
            let top = smoothstep(a.mouth_y - 0.016, a.mouth_y - 0.006, p.y);
            q += Vec3::new(0.0, 0.003, 0.013) * (pose.tongue_out * tip);
            q.y += pose.tongue_out * tip * 0.005;
            q += Vec3::new(0.0, 0.013, -0.002) * (pose.tongue_up * tip);
            q.y += pose.tongue_back * (0.011 * back * (0.4 + 0.6 * top) - 0.003 * tip);
            // Narrow the tip as it goes out, like a real tongue.
            q.x *= 1.0 - 0.25 * pose.tongue_out * tip;
            // The tongue rides on the jaw, but less so when it is pushed up.
            let ride = 1.0 - 0.75 * pose.tongue_up.max(pose.tongue_back * back) * tip.max(back);
            jaw_rotate(q, ride.clamp(0.0, 1.0))
        }
        Part::SkinUpper | Part::SkinLower => {
            let lower = part == Part::SkinLower || p.y < a.mouth_y - 0.0005;
            let mut q = p;
            let lips = lip_weight(p, a, 1.5, 0.03);
            let near = lip_weight(p, a, 1.2, 0.016);
            let dy = p.y - a.mouth_y;
            // Vermilion: the red of the lips, up to ~8 mm from the lip line.
            let verm =
                smoothstep(0.011, 0.002, dy.abs()) * smoothstep(1.1 * hw, 0.6 * hw, p.x.abs());
            let across = (1.0 - (p.x / hw).powi(2)).max(0.0);
            let sign = if lower { -1.0 } else { 1.0 };
            let xs = p.x / hw;

            // Width: corners move sideways (and back/up when spreading).
            let spread = pose.width.max(0.0);
            let narrow = (-pose.width).max(0.0);
            let wide = lip_weight(p, a, 2.0, 0.035).powf(0.67);
            q.x += (0.008 * spread - 0.0145 * narrow) * xs.clamp(-1.3, 1.3) * wide;
            q.z -= 0.005 * spread * xs.abs().min(1.2) * lips;
            q.y += 0.0025 * spread * xs.abs().min(1.2) * lips;

            // Protrusion and rounding: lips forward, lip edges flare.
            let pushed = lip_weight(p, a, 1.3, 0.03);
            q.z += 0.012 * pose.protrusion * pushed;
            q.y += sign * 0.0025 * pose.protrusion * verm * across;
            q.z += 0.003 * narrow * verm;

            // Aperture: lip edges part in an oval, most at the centre.
            let edge = smoothstep(0.016, 0.0, dy.abs());
            let open_shape = across.powf(0.7) * edge * near.max(0.3 * edge);
            q.y += sign * 0.0065 * pose.aperture * open_shape;
            if lower {
                q.y -= 0.004 * pose.lower_down * open_shape;
                q.z += 0.0015 * pose.lower_down * open_shape;
            } else {
                q.y += 0.0045 * pose.upper_raise * open_shape;
                q.z += 0.0012 * pose.upper_raise * open_shape;
            }

            // Press: lips thin and roll in towards the lip line.
            q.z -= 0.0035 * pose.press * verm * across.sqrt();
            q.y -= 0.35 * dy * pose.press * verm * across.sqrt();

            // Tuck: lower lip up and behind the upper incisors.
            if lower {
                let tuck = pose.tuck * verm * across.powf(0.5);
                q.y += 0.0055 * tuck;
                q.z -= 0.0075 * tuck * smoothstep(0.012, 0.0, dy.abs());
            }

            let w = jaw_weight(p, part, a);
            let moved = q - p;
            jaw_rotate(p, w) + moved
        }
    }
}
