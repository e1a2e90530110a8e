//! The viseme-to-ARKit recipe: each viseme is a fixed combination of ARKit blendshapes, so an
//! avatar that only has ARKit shapes (e.g. a Ready Player Me head exported with ARKit targets)
//! animates without editing. [`RECIPE`] is the table, one row per viseme with the reason for each
//! ingredient; `Left/Right` pairs are named without the side and always used together.
//!
//! Tuned with the face tracker (`tools/face_track.py`, MediaPipe face mesh) on `lipcall animate`
//! frames of TIMIT dr1-dr4 utterances rendered with an ARKit-only head (the MakeHuman / Face Units
//! rig written by `tools/build_head.py --arkit-only`): each viseme's rendered lip gap goes with the
//! design brief's openness (jaw and aperture: `aa` about 0.24 eye widths, `E` and `O` about half
//! that, the consonants 0.05-0.08, `PP` and `sil` shut) and its mouth width with the brief's width
//! (spread `I` widest, rounded `O` and `U` narrowest, everything else near the neutral width).
//! The results are in `docs/rendering.md`. Two things the tracker showed: `jawOpen` and the
//! rounding shapes narrow the mouth and `mouthPress` widens it, so the open and closed visemes
//! carry a little stretch or pucker to stay at the neutral width; and the lip gap only opens with
//! the jaw (`mouthUpperUp`/`mouthLowerDown` alone leave the lips touching), so every viseme that
//! shows a gap has some `jawOpen`.

use crate::vocab::VISEME_COUNT;

/// The ARKit blendshapes the recipe uses (names as Apple spells them).
pub const ARKIT_NAMES: [&str; 19] = [
    "jawOpen",
    "mouthClose",
    "mouthFunnel",
    "mouthPucker",
    "mouthPressLeft",
    "mouthPressRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "tongueOut",
    "mouthShrugLower",
    "mouthShrugUpper",
];

/// Shapes that come as a `Left`/`Right` pair; the recipe names them without the side.
const PAIRED: [&str; 5] = [
    "mouthPress",
    "mouthStretch",
    "mouthSmile",
    "mouthUpperUp",
    "mouthLowerDown",
];

/// Index in [`ARKIT_NAMES`] of a morph target name, ignoring case and any exporter prefix
/// before a '.' (such as `blendShape1.jawOpen`).
pub fn arkit_index(name: &str) -> Option<usize> {
    let base = name.rsplit('.').next().unwrap_or(name);
    ARKIT_NAMES
        .iter()
        .position(|a| a.eq_ignore_ascii_case(base))
}

/// The recipe, in viseme order: (viseme, [(ARKit shape, weight)]), pairs named without the side.
#[rustfmt::skip]
pub const RECIPE: [(&str, &[(&str, f32)]); VISEME_COUNT] = [
    // The neutral face.
    ("sil", &[]),
    // Lips shut and pressed: roll both lips in and press them (the visible closure); the lower
    // lip pushed up (shrug) seals the gap; a little pucker cancels the width press adds.
    ("PP", &[("mouthPress", 0.25), ("mouthRollLower", 0.35), ("mouthRollUpper", 0.3),
             ("mouthShrugLower", 0.2), ("mouthPucker", 0.3)]),
    // Lower lip rolled in under the upper teeth, the upper lip raised off them to show them;
    // the jaw barely open.
    ("FF", &[("jawOpen", 0.12), ("mouthRollLower", 0.8), ("mouthUpperUp", 0.25)]),
    // Tongue tip between the teeth: jaw open enough for it, upper lip up a little.
    ("TH", &[("jawOpen", 0.28), ("tongueOut", 0.6), ("mouthUpperUp", 0.15)]),
    // t d: a small opening (jaw, both lips off the teeth), slightly spread.
    ("DD", &[("jawOpen", 0.28), ("mouthStretch", 0.3), ("mouthUpperUp", 0.2),
             ("mouthLowerDown", 0.2)]),
    // k g: the jaw a little open; stretch keeps the width the jaw takes away.
    ("kk", &[("jawOpen", 0.28), ("mouthStretch", 0.35), ("mouthLowerDown", 0.15)]),
    // sh ch: lips pushed forward in a funnel with the teeth showing (both lips off them),
    // jaw nearly shut.
    ("CH", &[("jawOpen", 0.1), ("mouthFunnel", 0.5), ("mouthPucker", 0.15), ("mouthUpperUp", 0.3),
             ("mouthLowerDown", 0.3)]),
    // s z: teeth nearly together and showing (lips off them), spread.
    ("SS", &[("jawOpen", 0.1), ("mouthStretch", 0.35), ("mouthSmile", 0.1), ("mouthUpperUp", 0.3),
             ("mouthLowerDown", 0.3)]),
    // n l: a small opening, the tongue tip just visible.
    ("nn", &[("jawOpen", 0.25), ("mouthStretch", 0.1), ("mouthUpperUp", 0.15),
             ("tongueOut", 0.1)]),
    // r: a small rounded opening (funnel), a touch of stretch against over-narrowing.
    ("RR", &[("jawOpen", 0.25), ("mouthFunnel", 0.35), ("mouthPucker", 0.1),
             ("mouthStretch", 0.15)]),
    // The widest opening: the jaw most of the way, both lips off the teeth; stretch and a
    // little smile hold the corners out against the jaw's narrowing.
    ("aa", &[("jawOpen", 0.7), ("mouthStretch", 0.5), ("mouthSmile", 0.15),
             ("mouthLowerDown", 0.3), ("mouthUpperUp", 0.15)]),
    // A mid opening, spread.
    ("E", &[("jawOpen", 0.37), ("mouthStretch", 0.45), ("mouthSmile", 0.25), ("mouthUpperUp", 0.2),
            ("mouthLowerDown", 0.3)]),
    // The widest spread, a small opening with the teeth showing.
    ("I", &[("jawOpen", 0.15), ("mouthStretch", 0.55), ("mouthSmile", 0.35), ("mouthUpperUp", 0.35),
            ("mouthLowerDown", 0.3)]),
    // A mid, round opening: jaw open, lips in a funnel, a little pucker.
    ("O", &[("jawOpen", 0.42), ("mouthFunnel", 0.65), ("mouthPucker", 0.1)]),
    // The narrowest: lips puckered forward around a small round opening (funnel and some jaw
    // keep it from shutting).
    ("U", &[("jawOpen", 0.22), ("mouthPucker", 0.6), ("mouthFunnel", 0.6)]),
];

/// The recipe: for each viseme, (ARKit shape, weight) pairs; `Left/Right` pairs spelled out.
pub fn recipe() -> [Vec<(&'static str, f32)>; VISEME_COUNT] {
    std::array::from_fn(|v| {
        let mut out = Vec::new();
        for &(name, w) in RECIPE[v].1 {
            if PAIRED.contains(&name) {
                for side in ["Left", "Right"] {
                    let full = ARKIT_NAMES
                        .iter()
                        .find(|a| a.strip_suffix(side) == Some(name))
                        .copied()
                        .unwrap_or(name);
                    out.push((full, w));
                }
            } else {
                out.push((name, w));
            }
        }
        out
    })
}

/// The recipe as a matrix: `matrix()[viseme][arkit index]`.
pub fn matrix() -> [[f32; ARKIT_NAMES.len()]; VISEME_COUNT] {
    let mut m = [[0.0; ARKIT_NAMES.len()]; VISEME_COUNT];
    for (v, shapes) in recipe().iter().enumerate() {
        for (name, w) in shapes {
            if let Some(i) = arkit_index(name) {
                m[v][i] += w;
            }
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vocab::VISEME_NAMES;

    #[test]
    fn the_recipe_names_every_viseme_in_order_and_only_known_shapes() {
        for (v, (name, shapes)) in RECIPE.iter().enumerate() {
            assert_eq!(*name, VISEME_NAMES[v]);
            for (shape, w) in *shapes {
                assert!(*w > 0.0 && *w <= 1.0, "{name}: {shape} {w}");
                assert!(
                    PAIRED.contains(shape) || arkit_index(shape).is_some(),
                    "{name}: {shape}"
                );
            }
        }
        let m = matrix();
        // Pairs are used together; sil is the neutral face; aa opens the jaw most.
        let l = arkit_index("mouthStretchLeft").unwrap();
        let r = arkit_index("mouthStretchRight").unwrap();
        assert!(m.iter().all(|row| row[l] == row[r]));
        assert!(m[0].iter().all(|&w| w == 0.0));
        let jaw = arkit_index("jawOpen").unwrap();
        assert!((0..VISEME_COUNT).all(|v| v == 10 || m[v][jaw] < m[10][jaw]));
        assert_eq!(recipe()[1].len(), 6);
    }
}
