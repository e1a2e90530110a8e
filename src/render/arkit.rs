//! The viseme-to-ARKit recipe: each viseme is a fixed combination of ARKit blendshapes, so an
//! avatar that only has ARKit shapes (e.g. a Ready Player Me head exported with ARKit targets)
//! animates without editing. The weights follow the design brief's viseme table (jaw opening,
//! lip aperture, width, protrusion); Left/Right pairs are always used together.
//!
//! | viseme | ARKit shapes |
//! |---|---|
//! | sil | (none: the neutral face) |
//! | PP | mouthClose 0.2, mouthPress 0.6, mouthRollLower 0.3, mouthRollUpper 0.3 |
//! | FF | jawOpen 0.12, mouthRollLower 0.8, mouthUpperUp 0.25 |
//! | TH | jawOpen 0.25, tongueOut 0.6, mouthUpperUp 0.15 |
//! | DD | jawOpen 0.25, mouthStretch 0.15, mouthUpperUp 0.2, mouthLowerDown 0.2 |
//! | kk | jawOpen 0.35, mouthStretch 0.1, mouthLowerDown 0.15 |
//! | CH | jawOpen 0.15, mouthFunnel 0.6, mouthPucker 0.2, mouthUpperUp 0.3, mouthLowerDown 0.3 |
//! | SS | jawOpen 0.1, mouthStretch 0.35, mouthSmile 0.1, mouthUpperUp 0.3, mouthLowerDown 0.3 |
//! | nn | jawOpen 0.25, mouthStretch 0.1, mouthUpperUp 0.15, tongueOut 0.1 |
//! | RR | jawOpen 0.2, mouthFunnel 0.35, mouthPucker 0.3 |
//! | aa | jawOpen 0.75, mouthLowerDown 0.3, mouthUpperUp 0.15 |
//! | E | jawOpen 0.4, mouthStretch 0.4, mouthSmile 0.15, mouthUpperUp 0.2, mouthLowerDown 0.3 |
//! | I | jawOpen 0.15, mouthStretch 0.55, mouthSmile 0.35, mouthUpperUp 0.35, mouthLowerDown 0.3 |
//! | O | jawOpen 0.45, mouthFunnel 0.7, mouthPucker 0.25 |
//! | U | jawOpen 0.15, mouthPucker 0.85, mouthFunnel 0.4 |
//!
//! (`mouthPress`, `mouthStretch`, `mouthSmile`, `mouthUpperUp` and `mouthLowerDown` mean both the
//! `Left` and `Right` shapes at that weight.)

use super::head::VISEME_COUNT;

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

/// Index in [`ARKIT_NAMES`] of a morph target name, ignoring case and any exporter prefix
/// before a '.' (such as `blendShape1.jawOpen`).
pub fn arkit_index(name: &str) -> Option<usize> {
    let base = name.rsplit('.').next().unwrap_or(name);
    ARKIT_NAMES
        .iter()
        .position(|a| a.eq_ignore_ascii_case(base))
}

/// The recipe: for each viseme, (ARKit shape, weight) pairs; `Left/Right` pairs spelled out.
pub fn recipe() -> [Vec<(&'static str, f32)>; VISEME_COUNT] {
    let both = |name: &'static str, w: f32| -> [(&'static str, f32); 2] {
        match name {
            "mouthPress" => [("mouthPressLeft", w), ("mouthPressRight", w)],
            "mouthStretch" => [("mouthStretchLeft", w), ("mouthStretchRight", w)],
            "mouthSmile" => [("mouthSmileLeft", w), ("mouthSmileRight", w)],
            "mouthUpperUp" => [("mouthUpperUpLeft", w), ("mouthUpperUpRight", w)],
            _ => [("mouthLowerDownLeft", w), ("mouthLowerDownRight", w)],
        }
    };
    let mut v: [Vec<(&'static str, f32)>; VISEME_COUNT] = Default::default();
    v[1] = vec![
        ("mouthClose", 0.2),
        ("mouthRollLower", 0.3),
        ("mouthRollUpper", 0.3),
    ];
    v[1].extend(both("mouthPress", 0.6));
    v[2] = vec![("jawOpen", 0.12), ("mouthRollLower", 0.8)];
    v[2].extend(both("mouthUpperUp", 0.25));
    v[3] = vec![("jawOpen", 0.25), ("tongueOut", 0.6)];
    v[3].extend(both("mouthUpperUp", 0.15));
    v[4] = vec![("jawOpen", 0.25)];
    v[4].extend(both("mouthStretch", 0.15));
    v[4].extend(both("mouthUpperUp", 0.2));
    v[4].extend(both("mouthLowerDown", 0.2));
    v[5] = vec![("jawOpen", 0.35)];
    v[5].extend(both("mouthStretch", 0.1));
    v[5].extend(both("mouthLowerDown", 0.15));
    v[6] = vec![
        ("jawOpen", 0.15),
        ("mouthFunnel", 0.6),
        ("mouthPucker", 0.2),
    ];
    v[6].extend(both("mouthUpperUp", 0.3));
    v[6].extend(both("mouthLowerDown", 0.3));
    v[7] = vec![("jawOpen", 0.1)];
    v[7].extend(both("mouthStretch", 0.35));
    v[7].extend(both("mouthSmile", 0.1));
    v[7].extend(both("mouthUpperUp", 0.3));
    v[7].extend(both("mouthLowerDown", 0.3));
    v[8] = vec![("jawOpen", 0.25), ("tongueOut", 0.1)];
    v[8].extend(both("mouthStretch", 0.1));
    v[8].extend(both("mouthUpperUp", 0.15));
    v[9] = vec![
        ("jawOpen", 0.2),
        ("mouthFunnel", 0.35),
        ("mouthPucker", 0.3),
    ];
    v[10] = vec![("jawOpen", 0.75)];
    v[10].extend(both("mouthLowerDown", 0.3));
    v[10].extend(both("mouthUpperUp", 0.15));
    v[11] = vec![("jawOpen", 0.4)];
    v[11].extend(both("mouthStretch", 0.4));
    v[11].extend(both("mouthSmile", 0.15));
    v[11].extend(both("mouthUpperUp", 0.2));
    v[11].extend(both("mouthLowerDown", 0.3));
    v[12] = vec![("jawOpen", 0.15)];
    v[12].extend(both("mouthStretch", 0.55));
    v[12].extend(both("mouthSmile", 0.35));
    v[12].extend(both("mouthUpperUp", 0.35));
    v[12].extend(both("mouthLowerDown", 0.3));
    v[13] = vec![
        ("jawOpen", 0.45),
        ("mouthFunnel", 0.7),
        ("mouthPucker", 0.25),
    ];
    v[14] = vec![
        ("jawOpen", 0.15),
        ("mouthPucker", 0.85),
        ("mouthFunnel", 0.4),
    ];
    v
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
