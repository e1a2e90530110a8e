//! Morph targets: their names matched to the visemes (`viseme_aa` or `aa`), to ARKit
//! blendshapes (combined into visemes through [`crate::render::arkit`]) and to the eye
//! expressions, combined per primitive into the head's slots; meshes skinned to a jaw follow it.

use glam::Vec3;

use super::primitive::RawPrimitive;
use super::target_names::TargetKind;
use crate::render::RenderError;
use crate::render::arkit::{self, ARKIT_NAMES};
use crate::render::head::{
    EXPRESSION_COUNT, Expression, HeadModel, Material, MorphDelta, Primitive, TargetSource,
};
use crate::render::mouth_gauge;
use crate::vocab::{VISEME_COUNT, VISEME_NAMES};

pub(super) fn build_model(
    raws: Vec<RawPrimitive>,
    materials: Vec<Material>,
    all_target_names: Vec<String>,
) -> Result<HeadModel, RenderError> {
    let mut has_viseme = [false; VISEME_COUNT];
    let mut has_arkit = [false; ARKIT_NAMES.len()];
    // Per expression: whether lipcall's own both-eyes shape exists (it then wins over ARKit's).
    let mut has_own_expression = [false; EXPRESSION_COUNT];
    for raw in &raws {
        for (kind, _) in &raw.targets {
            match *kind {
                TargetKind::Viseme(v) => has_viseme[v] = true,
                TargetKind::Arkit(a) => has_arkit[a] = true,
                TargetKind::Expression {
                    expression,
                    own: true,
                } => has_own_expression[expression.index()] = true,
                TargetKind::Expression { .. } | TargetKind::Unused => {}
            }
        }
    }
    let viseme_mode = has_viseme.iter().skip(1).any(|&h| h);
    let arkit_mode = has_arkit.iter().any(|&h| h);
    if !viseme_mode && !arkit_mode {
        return Err(RenderError::NoUsableTargets {
            found: all_target_names,
        });
    }
    let recipe = arkit::matrix();
    let mut missing = Vec::new();
    // Per viseme: from its own target, else from the ARKit recipe where those shapes exist.
    let mut use_arkit = [false; VISEME_COUNT];
    for v in 1..VISEME_COUNT {
        if viseme_mode && has_viseme[v] {
            continue;
        }
        if recipe[v]
            .iter()
            .zip(&has_arkit)
            .any(|(&w, &h)| w > 0.0 && h)
        {
            use_arkit[v] = true;
        } else {
            missing.push(VISEME_NAMES[v].to_owned());
        }
    }
    let mut primitives = Vec::with_capacity(raws.len());
    let mut jaw_weights = Vec::with_capacity(raws.len());
    for raw in raws {
        let n = raw.vertices.len();
        // A primitive without viseme targets of its own (teeth or a tongue that carry only
        // ARKit shapes beside a viseme-named face) takes every viseme from the recipe.
        let own_visemes = viseme_mode
            && raw
                .targets
                .iter()
                .any(|(k, _)| matches!(k, TargetKind::Viseme(_)));
        let material = raw.material.unwrap_or(materials.len() - 1);
        let mut prim = Primitive::new(&raw.name, material, raw.vertices, raw.indices);
        for v in 0..VISEME_COUNT {
            let mut acc: Vec<MorphDelta> = Vec::new();
            let mut add = |deltas: &[MorphDelta], w: f32| {
                if acc.is_empty() {
                    acc = vec![MorphDelta::default(); n];
                }
                for (dst, src) in acc.iter_mut().zip(deltas) {
                    for k in 0..3 {
                        dst.position[k] += w * src.position[k];
                        dst.normal[k] += w * src.normal[k];
                    }
                }
            };
            for (kind, deltas) in &raw.targets {
                match *kind {
                    TargetKind::Viseme(t) if t == v && !use_arkit[v] && own_visemes => {
                        add(deltas, 1.0)
                    }
                    TargetKind::Arkit(a)
                        if (use_arkit[v] || !own_visemes) && recipe[v][a] > 0.0 =>
                    {
                        add(deltas, recipe[v][a])
                    }
                    _ => {}
                }
            }
            if acc
                .iter()
                .any(|d| d.position != [0.0; 3] || d.normal != [0.0; 3])
            {
                prim.targets[v] = acc;
            }
        }
        for expression in Expression::ALL {
            let mut acc: Vec<MorphDelta> = Vec::new();
            for (kind, deltas) in &raw.targets {
                let TargetKind::Expression { expression: e, own } = *kind else {
                    continue;
                };
                if e != expression || own != has_own_expression[e.index()] {
                    continue;
                }
                if acc.is_empty() {
                    acc = vec![MorphDelta::default(); n];
                }
                for (dst, src) in acc.iter_mut().zip(deltas) {
                    for k in 0..3 {
                        dst.position[k] += src.position[k];
                        dst.normal[k] += src.normal[k];
                    }
                }
            }
            if acc
                .iter()
                .any(|d| d.position != [0.0; 3] || d.normal != [0.0; 3])
            {
                prim.targets[expression.slot()] = acc;
            }
        }
        primitives.push(prim);
        jaw_weights.push(raw.jaw_weights);
    }
    follow_the_jaw(&mut primitives, &jaw_weights);
    let model = HeadModel {
        primitives,
        materials,
        source: if viseme_mode {
            TargetSource::Visemes
        } else {
            TargetSource::Arkit
        },
        missing_visemes: missing,
    };
    if !model.has_expression(Expression::Blink) {
        tracing::debug!(
            "the head has no eyeBlinkLeft/eyeBlinkRight (or eyeBlink) morph target: it will not \
             blink"
        );
    }
    match model.validate() {
        Err(RenderError::NoUsableTargets { .. }) => Err(RenderError::NoUsableTargets {
            found: all_target_names,
        }),
        Err(e) => Err(e),
        Ok(()) => {
            let mut model = model;
            calibrate_mouth(&mut model);
            Ok(model)
        }
    }
}

/// Opens the head's mouth as far as a real speaker's (see [`mouth_gauge`]) and says so.
fn calibrate_mouth(model: &mut HeadModel) {
    match mouth_gauge::calibrate(model) {
        Some(c) if c.opening_gain > 1.0 || c.width_gain > 1.0 => tracing::info!(
            "the head's mouth opened {:.3} eye widths and its width moved {:.3}: its mouth \
             motion is scaled by {:.2} (sideways {:.2}) to {:.3} and {:.3}",
            c.gap_before,
            c.width_range_before,
            c.opening_gain,
            c.opening_gain * c.width_gain,
            c.gap_after,
            c.width_range_after
        ),
        Some(c) => tracing::debug!(
            "the head's mouth opens {:.3} eye widths and its width moves {:.3}: kept as it is",
            c.gap_before,
            c.width_range_before
        ),
        None => tracing::debug!("the head's lips could not be measured: mouth kept as it is"),
    }
}

/// How many of the face's moving vertices nearest to a jaw-skinned mesh stand for the jaw.
const JAW_NEIGHBOURS: usize = 24;

/// Moves meshes that the file skins to a jaw joint but gives no mouth targets (teeth, a tongue)
/// with the jaw: the face's `aa` delta at its moving vertices nearest to the mesh (the lower lip
/// and chin) gives the jaw's full opening as a translation, and each viseme opens it by how far
/// its own delta there goes along that of `aa` (clamped to 0..1.5; rounding and spreading, which
/// move the lips sideways or forward, open it little). Each vertex follows by its skin weight
/// on jaw joints. Skinned meshes are otherwise drawn in their bind pose.
fn follow_the_jaw(primitives: &mut [Primitive], jaw_weights: &[Option<Vec<f32>>]) {
    const AA: usize = 10;
    for (i, jaw) in jaw_weights.iter().enumerate() {
        let Some(jaw) = jaw else { continue };
        if primitives[i].has_viseme_targets() {
            continue;
        }
        // The face: primitives with an `aa` delta that are not skinned to the jaw themselves.
        let mut moving: Vec<(Vec3, usize, usize)> = Vec::new();
        for (k, p) in primitives.iter().enumerate() {
            if jaw_weights[k].is_some() || p.targets[AA].is_empty() {
                continue;
            }
            let max = p.targets[AA]
                .iter()
                .map(|d| Vec3::from(d.position).length())
                .fold(0.0f32, f32::max);
            for (vi, d) in p.targets[AA].iter().enumerate() {
                if max > 0.0 && Vec3::from(d.position).length() > 0.1 * max {
                    moving.push((Vec3::from(p.vertices[vi].position), k, vi));
                }
            }
        }
        let mesh = &primitives[i];
        let weighted: Vec<Vec3> = mesh
            .vertices
            .iter()
            .zip(jaw)
            .filter(|(_, w)| **w > 0.0)
            .map(|(v, _)| Vec3::from(v.position))
            .collect();
        if moving.is_empty() || weighted.is_empty() {
            continue;
        }
        let centre = weighted.iter().copied().sum::<Vec3>() / weighted.len() as f32;
        moving.sort_by(|a, b| {
            a.0.distance_squared(centre)
                .total_cmp(&b.0.distance_squared(centre))
        });
        moving.truncate(JAW_NEIGHBOURS);
        let delta_at = |v: usize, &(_, k, vi): &(Vec3, usize, usize)| -> Vec3 {
            primitives[k].targets[v]
                .get(vi)
                .map_or(Vec3::ZERO, |d| Vec3::from(d.position))
        };
        let aa: Vec<Vec3> = moving.iter().map(|m| delta_at(AA, m)).collect();
        let opening = aa.iter().copied().sum::<Vec3>() / aa.len() as f32;
        let norm: f32 = aa.iter().map(|d| d.length_squared()).sum();
        if norm <= 0.0 || !opening.is_finite() {
            continue;
        }
        let mut targets = Vec::new();
        for v in 1..VISEME_COUNT {
            let along: f32 = moving
                .iter()
                .zip(&aa)
                .map(|(m, a)| delta_at(v, m).dot(*a))
                .sum::<f32>()
                / norm;
            let amount = along.clamp(0.0, 1.5);
            if amount > 1e-3 {
                let deltas: Vec<MorphDelta> = jaw
                    .iter()
                    .map(|w| MorphDelta {
                        position: (opening * amount * *w).into(),
                        normal: [0.0; 3],
                    })
                    .collect();
                targets.push((v, deltas));
            }
        }
        for (v, deltas) in targets {
            primitives[i].targets[v] = deltas;
        }
    }
}

pub(super) fn target_names(mesh: &gltf::Mesh) -> Vec<String> {
    let parse = |raw: &Option<Box<serde_json::value::RawValue>>| -> Option<Vec<String>> {
        let value: serde_json::Value = serde_json::from_str(raw.as_ref()?.get()).ok()?;
        let names = value.get("targetNames")?.as_array()?;
        Some(
            names
                .iter()
                .map(|n| n.as_str().unwrap_or_default().to_owned())
                .collect(),
        )
    };
    if let Some(names) = parse(mesh.extras()) {
        return names;
    }
    mesh.primitives()
        .find_map(|p| parse(p.extras()))
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::super::target_names::classify;
    use super::{Expression, TargetKind};

    #[test]
    fn eye_targets_map_to_the_expression_slots() {
        let arkit = |expression| TargetKind::Expression {
            expression,
            own: false,
        };
        for (name, expression) in [
            ("eyeBlinkLeft", Expression::Blink),
            ("eyeBlinkRight", Expression::Blink),
            ("blendShape1.eyeBlink_L", Expression::Blink),
            ("eyeLookUpLeft", Expression::LookUp),
            ("EYELOOKUPRIGHT", Expression::LookUp),
            ("eyeLookDownRight", Expression::LookDown),
            ("eyeLookDown_L", Expression::LookDown),
            // The head's own left: its left eye looks out, its right eye in.
            ("eyeLookOutLeft", Expression::LookLeft),
            ("eyeLookInRight", Expression::LookLeft),
            ("eyeLookOutRight", Expression::LookRight),
            ("eyeLookInLeft", Expression::LookRight),
        ] {
            assert_eq!(classify(name), arkit(expression), "{name}");
        }
        for expression in Expression::ALL {
            assert_eq!(
                classify(expression.name()),
                TargetKind::Expression {
                    expression,
                    own: true
                }
            );
        }
        // Names it does not know stay unused, and the mouth's names keep their meaning.
        for name in [
            "eyeSquintLeft",
            "eyeWideRight",
            "eyeBlink_X",
            "eye",
            "",
            "browInnerUp",
        ] {
            assert_eq!(classify(name), TargetKind::Unused, "{name}");
        }
        assert_eq!(classify("viseme_aa"), TargetKind::Viseme(10));
        assert!(matches!(classify("jawOpen"), TargetKind::Arkit(_)));
    }
}
