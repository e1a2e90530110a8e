//! Morph target names resolved to what they drive: a viseme (`viseme_aa` or `aa`), an ARKit
//! blendshape, an eye expression, or nothing.

use crate::render::arkit;
use crate::render::head::Expression;
use crate::vocab::VISEME_NAMES;

/// A morph target's name resolved to what it drives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum TargetKind {
    Viseme(usize),
    Arkit(usize),
    /// An eye shape: `own` for lipcall's slot names (`eyeBlink`, `eyeLookLeft`, ...), which
    /// hold both eyes; otherwise one eye's ARKit shape, added to its side's partner.
    Expression {
        expression: Expression,
        own: bool,
    },
    Unused,
}

/// ARKit's per-eye shapes and the expression slot each adds to. Looking to the head's left is
/// the left eye looking out and the right eye looking in; to its right, the reverse.
const ARKIT_EYES: [(&str, Expression); 10] = [
    ("eyeBlinkLeft", Expression::Blink),
    ("eyeBlinkRight", Expression::Blink),
    ("eyeLookUpLeft", Expression::LookUp),
    ("eyeLookUpRight", Expression::LookUp),
    ("eyeLookDownLeft", Expression::LookDown),
    ("eyeLookDownRight", Expression::LookDown),
    ("eyeLookOutLeft", Expression::LookLeft),
    ("eyeLookInRight", Expression::LookLeft),
    ("eyeLookOutRight", Expression::LookRight),
    ("eyeLookInLeft", Expression::LookRight),
];

/// The eye expression a target name drives, if any: ARKit names (also with the `_L`/`_R`
/// suffixes some exporters write) or lipcall's own slot names, ignoring case.
pub(super) fn classify_expression(base: &str) -> Option<TargetKind> {
    if let Some(&expression) = Expression::ALL
        .iter()
        .find(|e| e.name().eq_ignore_ascii_case(base))
    {
        return Some(TargetKind::Expression {
            expression,
            own: true,
        });
    }
    let side = |suffix: &str, full: &str| {
        base.strip_suffix(suffix)
            .or_else(|| base.strip_suffix(&suffix.to_ascii_lowercase()))
            .map(|stem| format!("{stem}{full}"))
    };
    let spelled = side("_L", "Left")
        .or_else(|| side("_R", "Right"))
        .unwrap_or_else(|| base.to_owned());
    ARKIT_EYES
        .iter()
        .find(|(name, _)| name.eq_ignore_ascii_case(&spelled))
        .map(|&(_, expression)| TargetKind::Expression {
            expression,
            own: false,
        })
}

/// Resolves a target name: `viseme_aa`, `aa`, `Viseme_AA`, `mesh.viseme_aa` and ARKit names.
pub(super) fn classify(name: &str) -> TargetKind {
    let base = name.rsplit('.').next().unwrap_or(name);
    let stripped = base
        .strip_prefix("viseme_")
        .or_else(|| base.strip_prefix("Viseme_"))
        .or_else(|| base.strip_prefix("VISEME_"))
        .unwrap_or(base);
    if let Some(v) = VISEME_NAMES.iter().position(|v| *v == stripped) {
        return TargetKind::Viseme(v);
    }
    if let Some(v) = VISEME_NAMES
        .iter()
        .position(|v| v.eq_ignore_ascii_case(stripped))
    {
        return TargetKind::Viseme(v);
    }
    if let Some(kind) = classify_expression(base) {
        return kind;
    }
    match arkit::arkit_index(base) {
        Some(a) => TargetKind::Arkit(a),
        None => TargetKind::Unused,
    }
}
