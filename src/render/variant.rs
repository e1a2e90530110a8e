//! Head variants: one head file drawn as different people. A variant recolours the skin and the
//! hair (and brows) of the skin material and scales the head's proportions a little, per
//! instance (a uniform of `shaders/head.wgsl`), so that every peer of a call can share one
//! uploaded head and still look different. [`HeadVariant::DEFAULT`] changes nothing: a lone
//! head is drawn as it always was, pixel for pixel.
//!
//! Colours are given as the bundled head's palette (`tools/build_head.py`: skin 214,160,130,
//! hair 48,34,26, sRGB) mapped onto the variant's: a colour of the skin material is a mix of
//! skin and hair (the hairline, the brows) or something else (lips, the inside of the mouth),
//! told apart in the shader by its hue and brightness. Only materials named like skin are
//! recoloured (`skin` in the name: the bundled head's, Ready Player Me's `Wolf3D_Skin`); eyes,
//! teeth, tongue and lashes are materials of their own and keep their colours. The vertex stage
//! recolours the vertex colours (a texture's own colours are kept); on a head coloured unlike the
//! bundled one, the recolouring is approximate.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use super::head::HeadModel;

/// The bundled head's skin colour (sRGB), which variants recolour from.
pub const BUNDLED_SKIN: [u8; 3] = [214, 160, 130];
/// The bundled head's hair colour (sRGB; its brows are nearly the same).
pub const BUNDLED_HAIR: [u8; 3] = [48, 34, 26];
/// How far lips follow the skin tone (their own colour is kept for the rest).
const LIPS_FOLLOW_SKIN: f32 = 0.5;

/// A face's proportions: the head scaled about its neck pivot, within 6 % on each axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaceShape {
    /// The head as modelled.
    Average,
    /// Narrower and a little longer.
    Narrow,
    /// Broader and a little shorter.
    Broad,
}

impl FaceShape {
    /// Scale on x (across), y (up) and z (front to back).
    pub fn scale(self) -> Vec3 {
        match self {
            FaceShape::Average => Vec3::ONE,
            FaceShape::Narrow => Vec3::new(0.94, 1.05, 0.97),
            FaceShape::Broad => Vec3::new(1.06, 0.95, 1.03),
        }
    }
}

/// One look of a head: skin tone, hair colour (sRGB) and face shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HeadVariant {
    pub name: &'static str,
    pub skin: [u8; 3],
    pub hair: [u8; 3],
    pub shape: FaceShape,
}

const fn variant(
    name: &'static str,
    skin: [u8; 3],
    hair: [u8; 3],
    shape: FaceShape,
) -> HeadVariant {
    HeadVariant {
        name,
        skin,
        hair,
        shape,
    }
}

/// The named variants, the unchanged head first; skin tones from light to dark are spread over
/// the list so that neighbours differ in tone, hair and shape at once.
pub const VARIANTS: [HeadVariant; 8] = [
    HeadVariant::DEFAULT,
    variant(
        "Fair, blond",
        [238, 200, 176],
        [176, 138, 86],
        FaceShape::Narrow,
    ),
    variant(
        "Deep brown, black hair",
        [92, 58, 40],
        [20, 17, 16],
        FaceShape::Broad,
    ),
    variant(
        "Light, auburn",
        [228, 178, 150],
        [124, 58, 32],
        FaceShape::Broad,
    ),
    variant(
        "Tan, black hair",
        [176, 122, 86],
        [26, 22, 20],
        FaceShape::Narrow,
    ),
    variant(
        "Olive, grey hair",
        [198, 150, 110],
        [152, 150, 146],
        FaceShape::Average,
    ),
    variant(
        "Brown, dark hair",
        [136, 90, 62],
        [36, 26, 20],
        FaceShape::Narrow,
    ),
    variant(
        "Rosy, red hair",
        [232, 176, 160],
        [150, 64, 30],
        FaceShape::Average,
    ),
];

/// What the shader reads of a variant (part of each instance's view uniform).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct LookUniform {
    /// rgb: the skin's colour factor minus one (0 for the unchanged head, so that the shader's
    /// `c + c * gain` is exact); a: the bundled skin's luminance.
    pub skin: [f32; 4],
    /// rgb: the bundled hair colour times (its factor minus the skin's): what a hair colour gains
    /// beyond following the skin; a: the bundled hair's luminance.
    pub hair: [f32; 4],
    /// rgb: the lips' factor minus one.
    pub lips: [f32; 4],
    /// xyz: the face shape's scale minus one; w: the scale of morph motion minus one.
    pub shape: [f32; 4],
    /// xyz: the scale of normals (the inverse of the face shape's).
    pub normal_scale: [f32; 4],
    /// xyz: the point the head is scaled about (its neck pivot).
    pub pivot: [f32; 4],
}

fn srgb_to_linear(c: [u8; 3]) -> Vec3 {
    Vec3::from(c.map(|v| {
        let s = v as f32 / 255.0;
        if s <= 0.04045 {
            s / 12.92
        } else {
            ((s + 0.055) / 1.055).powf(2.4)
        }
    }))
}

fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

impl HeadVariant {
    /// The head as modelled.
    pub const DEFAULT: HeadVariant =
        variant("Default", BUNDLED_SKIN, BUNDLED_HAIR, FaceShape::Average);

    /// The variant called `name` (as [`VARIANTS`] spells it, any case).
    pub fn by_name(name: &str) -> Option<HeadVariant> {
        VARIANTS
            .iter()
            .find(|v| v.name.eq_ignore_ascii_case(name.trim()))
            .copied()
    }

    /// Whether this variant changes nothing.
    pub fn is_default(&self) -> bool {
        self.skin == BUNDLED_SKIN && self.hair == BUNDLED_HAIR && self.shape == FaceShape::Average
    }

    /// How much a mouth's motion is scaled: by the shape's sideways scale on every axis, the
    /// scale of the eye width, so that lip gaps and widths keep their size in eye widths (what
    /// [`crate::render::mouth_gauge`] calibrated).
    fn motion_scale(&self) -> f32 {
        self.shape.scale().x
    }

    /// The uniform for a head whose neck pivot is `pivot`.
    pub fn look(&self, pivot: Vec3) -> LookUniform {
        let (skin_from, hair_from) = (srgb_to_linear(BUNDLED_SKIN), srgb_to_linear(BUNDLED_HAIR));
        let skin_gain = srgb_to_linear(self.skin) / skin_from - Vec3::ONE;
        let hair_gain = srgb_to_linear(self.hair) / hair_from - Vec3::ONE;
        let scale = self.shape.scale();
        LookUniform {
            skin: skin_gain.extend(luminance(skin_from)).into(),
            hair: (hair_from * (hair_gain - skin_gain))
                .extend(luminance(hair_from))
                .into(),
            lips: (LIPS_FOLLOW_SKIN * skin_gain).extend(0.0).into(),
            shape: (scale - Vec3::ONE).extend(self.motion_scale() - 1.0).into(),
            normal_scale: scale.recip().extend(0.0).into(),
            pivot: pivot.extend(1.0).into(),
        }
    }

    /// `head` with this variant's shape applied to its vertices and morph deltas as the vertex
    /// shader applies it (the colours are left alone): what [`crate::render::mouth_gauge`]
    /// measures on a shaped head.
    pub fn shape_head(&self, head: &HeadModel) -> HeadModel {
        let pivot = head.face_frame().neck_pivot();
        let scale = self.shape.scale();
        let motion = self.motion_scale();
        let mut out = head.clone();
        for p in &mut out.primitives {
            for v in &mut p.vertices {
                let at = Vec3::from(v.position);
                v.position = (pivot + (at - pivot) * scale).into();
                v.normal = (Vec3::from(v.normal) / scale).into();
            }
            for deltas in &mut p.targets {
                for d in deltas {
                    d.position = (Vec3::from(d.position) * motion).into();
                    d.normal = (Vec3::from(d.normal) / scale).into();
                }
            }
        }
        out
    }
}

impl Default for HeadVariant {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Whether a material of this name is recoloured by variants.
pub fn is_skin_material(name: &str) -> bool {
    name.to_ascii_lowercase().contains("skin")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_variant_is_an_exact_identity() {
        let look = HeadVariant::DEFAULT.look(Vec3::new(0.0, -0.02, -0.1));
        assert_eq!(&look.skin[..3], &[0.0; 3]);
        assert_eq!(&look.hair[..3], &[0.0; 3]);
        assert_eq!(&look.lips[..3], &[0.0; 3]);
        assert_eq!(look.shape, [0.0; 4]);
        assert_eq!(&look.normal_scale[..3], &[1.0; 3]);
        assert!(HeadVariant::DEFAULT.is_default());
        assert_eq!(VARIANTS[0], HeadVariant::DEFAULT);
    }

    #[test]
    fn variants_have_distinct_names_and_looks_within_the_shape_bounds() {
        for (i, a) in VARIANTS.iter().enumerate() {
            assert_eq!(HeadVariant::by_name(&a.name.to_uppercase()), Some(*a));
            let s = a.shape.scale();
            assert!((s - Vec3::ONE).abs().max_element() <= 0.08, "{}", a.name);
            for b in &VARIANTS[i + 1..] {
                assert_ne!(a.name, b.name);
                assert!(
                    a.skin != b.skin || a.hair != b.hair,
                    "{} and {}",
                    a.name,
                    b.name
                );
            }
            assert_eq!(i == 0, a.is_default());
        }
        assert_eq!(HeadVariant::by_name("nobody"), None);
    }

    #[test]
    fn skin_materials_are_told_by_name() {
        assert!(is_skin_material("skin"));
        assert!(is_skin_material("Wolf3D_Skin"));
        assert!(!is_skin_material("teethUpper"));
        assert!(!is_skin_material("eyeLeft"));
    }
}
