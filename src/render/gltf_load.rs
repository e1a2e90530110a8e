//! Loading glTF 2.0 / GLB heads: meshes and primitives under their node transforms, base colour
//! factors and PNG or JPEG base colour textures, and morph targets matched by name to the visemes
//! (`viseme_aa` or `aa`) or to ARKit blendshapes combined through [`super::arkit`], and to the
//! eye expressions (ARKit's `eyeBlink*` and `eyeLook*`, or lipcall's own slot names).
//!
//! Every accessor is bounds-checked before it is read, so malformed files give errors, not panics.
//! Skinned meshes are taken in their bind pose (their node transform is ignored, as the glTF
//! specification says). Every mesh's own targets are combined by the same rules (teeth and tongue
//! meshes with `jawOpen` or `viseme_aa` of their own move with the face); a mesh skinned to a
//! joint named like a jaw that has no mouth targets follows the face's jaw ([`follow_the_jaw`]).

use std::path::Path;

use glam::{Mat3, Mat4, Vec3};
use gltf::accessor::{DataType, Dimensions};

use super::RenderError;
use super::arkit::{self, ARKIT_NAMES};
use super::head::{
    EXPRESSION_COUNT, Expression, HeadModel, Material, MorphDelta, Primitive, TargetSource,
    Texture, Vertex, smooth_normals,
};
use crate::vocab::{VISEME_COUNT, VISEME_NAMES};

/// Refuse absurd sizes before allocating for them.
const MAX_VERTICES: usize = 4_000_000;
/// Largest coordinate of a vertex or of a morph target's displacement: a head is at most a few
/// metres across in any unit a tool exports (300 in millimetres), and far beyond that the f32
/// sums that frame and blend it overflow (a finite 1e36 displacement gave an infinite mouth).
const MAX_COORDINATE: f32 = 1.0e6;
const MAX_NODE_DEPTH: usize = 64;
/// Vertices, indices and morph deltas read may reach this many plus one per 4 bytes of buffer
/// data: a file reads about one per 4 to 12 buffer bytes, and without this budget one accessor
/// referenced by many meshes or targets would be expanded for each of them.
const ELEMENT_BUDGET_FLOOR: usize = 1 << 20;
/// Largest base colour texture side accepted; larger ones are refused before any pixel is decoded.
const MAX_TEXTURE_SIDE: u32 = 8192;
/// Pixels of all textures decoded together: each material decodes its own, so one small,
/// highly compressed image behind many materials would otherwise be decoded for each.
const MAX_TEXTURE_PIXELS: u64 = 8192 * 8192;

/// Loads a head from a `.glb` or `.gltf` file (external buffers and images are read from beside it).
pub fn load_head(path: &Path) -> Result<HeadModel, RenderError> {
    let bytes = crate::input::read(path, crate::input::MAX_INPUT_BYTES)?;
    load_head_from_slice_in(&bytes, path.parent())
}

/// Loads a head from GLB bytes (or glTF JSON with embedded `data:` buffers).
pub fn load_head_from_slice(bytes: &[u8]) -> Result<HeadModel, RenderError> {
    load_head_from_slice_in(bytes, None)
}

fn coordinate_ok(v: Vec3) -> bool {
    v.is_finite() && v.abs().max_element() <= MAX_COORDINATE
}

fn gltf_err(e: impl std::fmt::Display) -> RenderError {
    RenderError::Gltf(e.to_string())
}

/// A morph target's name resolved to what it drives.
#[derive(Debug, Clone, Copy, PartialEq)]
enum TargetKind {
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
fn classify_expression(base: &str) -> Option<TargetKind> {
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
fn classify(name: &str) -> TargetKind {
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

/// A primitive read from the file, with its raw morph targets.
struct RawPrimitive {
    name: String,
    /// `None`: the default material, the last of the list.
    material: Option<usize>,
    vertices: Vec<Vertex>,
    indices: Vec<u32>,
    targets: Vec<(TargetKind, Vec<MorphDelta>)>,
    /// Per vertex, how much it is skinned to joints named like a jaw (`None`: to none).
    jaw_weights: Option<Vec<f32>>,
}

/// The GLB header's total length, when `bytes` start like a GLB.
fn glb_declared_length(bytes: &[u8]) -> Option<u32> {
    match bytes {
        [b'g', b'l', b'T', b'F', _, _, _, _, a, b, c, d, ..] => {
            Some(u32::from_le_bytes([*a, *b, *c, *d]))
        }
        _ => None,
    }
}

/// `gltf::Gltf::from_slice`, less its panics: the gltf crate (1.4.1) subtracts the GLB header's
/// 12 bytes from the length it gives unchecked (an overflow panic in debug builds), and its
/// validation indexes the accessor a primitive's POSITION names unchecked.
fn parse_validated(bytes: &[u8]) -> Result<gltf::Gltf, RenderError> {
    if let Some(length) = glb_declared_length(bytes).filter(|&length| length < 12) {
        return Err(RenderError::Gltf(format!(
            "the GLB header gives a length of {length} bytes, less than the header itself"
        )));
    }
    let unchecked = gltf::Gltf::from_slice_without_validation(bytes).map_err(gltf_err)?;
    let json = unchecked.document.into_json();
    let positions = gltf::json::validation::Checked::Valid(gltf::json::mesh::Semantic::Positions);
    for (m, mesh) in json.meshes.iter().enumerate() {
        for primitive in &mesh.primitives {
            if let Some(index) = primitive.attributes.get(&positions)
                && index.value() >= json.accessors.len()
            {
                return Err(RenderError::Gltf(format!(
                    "mesh {m}: POSITION names accessor {}, and there are {}",
                    index.value(),
                    json.accessors.len()
                )));
            }
        }
    }
    Ok(gltf::Gltf {
        document: gltf::Document::from_json(json).map_err(gltf_err)?,
        blob: unchecked.blob,
    })
}

fn load_head_from_slice_in(bytes: &[u8], base: Option<&Path>) -> Result<HeadModel, RenderError> {
    let gltf = parse_validated(bytes)?;
    let doc = &gltf.document;
    let buffers = load_buffers(doc, gltf.blob.as_deref(), base)?;
    let buffer_bytes: usize = buffers.iter().map(Vec::len).sum();
    let mut budget = ELEMENT_BUDGET_FLOOR.saturating_add(buffer_bytes / 4);

    let mut materials = load_materials(doc, &buffers, base, MAX_TEXTURE_PIXELS);
    materials.push(Material::default());

    let mut raws = Vec::new();
    let mut all_target_names = Vec::new();
    let mut total_vertices = 0usize;
    let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(scene) => scene.nodes().collect(),
        None => {
            // No scene: every node that is nobody's child.
            let mut is_child = vec![false; doc.nodes().len()];
            for n in doc.nodes() {
                for c in n.children() {
                    if let Some(flag) = is_child.get_mut(c.index()) {
                        *flag = true;
                    }
                }
            }
            doc.nodes().filter(|n| !is_child[n.index()]).collect()
        }
    };
    let mut stack: Vec<(gltf::Node, Mat4, usize)> =
        roots.into_iter().map(|n| (n, Mat4::IDENTITY, 0)).collect();
    // glTF node hierarchies are trees: a node reached twice (shared children, a cycle) would
    // multiply the walk, exponentially with depth.
    let mut visited = vec![false; doc.nodes().len()];
    while let Some((node, parent, depth)) = stack.pop() {
        if depth > MAX_NODE_DEPTH {
            return Err(RenderError::Gltf("node hierarchy too deep (cycle?)".into()));
        }
        match visited.get_mut(node.index()) {
            Some(seen) if !*seen => *seen = true,
            _ => {
                return Err(RenderError::Gltf(format!(
                    "node {} has more than one parent (node hierarchies must be trees)",
                    node.index()
                )));
            }
        }
        let local = Mat4::from_cols_array_2d(&node.transform().matrix());
        let world = parent * local;
        if let Some(mesh) = node.mesh() {
            let transform = if node.skin().is_some() {
                Mat4::IDENTITY
            } else {
                world
            };
            if !transform.is_finite() {
                return Err(RenderError::Gltf(format!(
                    "node {} has a non-finite transform",
                    node.index()
                )));
            }
            let names = target_names(&mesh);
            all_target_names.extend(names.iter().cloned());
            // Which of the skin's joints are a jaw (by name: `jaw`, `Jaw`, `mixamorig:Jaw`, ...).
            let jaw_joints: Vec<bool> = node
                .skin()
                .map(|skin| {
                    skin.joints()
                        .map(|j| {
                            j.name()
                                .is_some_and(|n| n.to_ascii_lowercase().contains("jaw"))
                        })
                        .collect()
                })
                .unwrap_or_default();
            for prim in mesh.primitives() {
                if prim.mode() != gltf::mesh::Mode::Triangles {
                    continue;
                }
                let raw = read_primitive(
                    &prim,
                    &mesh,
                    &names,
                    &jaw_joints,
                    transform,
                    &buffers,
                    &mut budget,
                )?;
                total_vertices += raw.vertices.len();
                if total_vertices > MAX_VERTICES {
                    return Err(RenderError::Unsupported(format!(
                        "more than {MAX_VERTICES} vertices"
                    )));
                }
                raws.push(raw);
            }
        }
        for child in node.children() {
            stack.push((child, world, depth + 1));
        }
    }
    if raws.is_empty() {
        return Err(RenderError::InvalidHead(
            "the file has no triangle meshes".into(),
        ));
    }
    all_target_names.sort();
    all_target_names.dedup();
    build_model(raws, materials, all_target_names)
}

fn build_model(
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
        other => other.map(|()| model),
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

fn target_names(mesh: &gltf::Mesh) -> Vec<String> {
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

fn load_buffers(
    doc: &gltf::Document,
    blob: Option<&[u8]>,
    base: Option<&Path>,
) -> Result<Vec<Vec<u8>>, RenderError> {
    let mut out = Vec::new();
    for buffer in doc.buffers() {
        let data = match buffer.source() {
            gltf::buffer::Source::Bin => blob
                .ok_or_else(|| RenderError::Gltf("GLB binary chunk missing".into()))?
                .to_vec(),
            gltf::buffer::Source::Uri(uri) => read_uri(uri, base)?,
        };
        if data.len() < buffer.length() {
            return Err(RenderError::Gltf(format!(
                "buffer {} has {} bytes, declares {}",
                buffer.index(),
                data.len(),
                buffer.length()
            )));
        }
        out.push(data);
    }
    Ok(out)
}

fn read_uri(uri: &str, base: Option<&Path>) -> Result<Vec<u8>, RenderError> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (_, payload) = rest
            .split_once(";base64,")
            .ok_or_else(|| RenderError::Unsupported("data URI that is not base64".into()))?;
        return decode_base64(payload);
    }
    let base = base.ok_or_else(|| {
        RenderError::Unsupported(format!("external resource {uri:?} without a file path"))
    })?;
    if uri.contains("..") || uri.contains("://") || uri.starts_with('/') {
        return Err(RenderError::Unsupported(format!("resource path {uri:?}")));
    }
    let path = base.join(uri.replace("%20", " "));
    Ok(crate::input::read(&path, crate::input::MAX_INPUT_BYTES)?)
}

fn decode_base64(s: &str) -> Result<Vec<u8>, RenderError> {
    let value = |c: u8| -> Option<u32> {
        Some(match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            _ => return None,
        } as u32)
    };
    let mut out = Vec::with_capacity(s.len() * 3 / 4);
    let mut acc = 0u32;
    let mut bits = 0;
    for &c in s.as_bytes() {
        if c == b'=' || c.is_ascii_whitespace() {
            continue;
        }
        let v = value(c).ok_or_else(|| RenderError::Gltf("bad base64 in data URI".into()))?;
        acc = (acc << 6) | v;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Ok(out)
}

/// The document's materials, decoding textures until `texture_pixels` are spent (later ones
/// keep their base colour factor).
fn load_materials(
    doc: &gltf::Document,
    buffers: &[Vec<u8>],
    base: Option<&Path>,
    mut texture_pixels: u64,
) -> Vec<Material> {
    doc.materials()
        .map(|m| load_material(doc, &m, buffers, base, &mut texture_pixels))
        .collect()
}

fn load_material(
    doc: &gltf::Document,
    m: &gltf::Material,
    buffers: &[Vec<u8>],
    base: Option<&Path>,
    texture_pixels: &mut u64,
) -> Material {
    let name = m.name().unwrap_or("material").to_owned();
    let pbr = m.pbr_metallic_roughness();
    let factor = pbr.base_color_factor();
    // A texture that cannot be used is not fatal: the material keeps its base colour factor.
    let texture = pbr.base_color_texture().and_then(|info| {
        let image = info.texture().source().index();
        match load_texture(doc, image, buffers, base, texture_pixels) {
            Ok(texture) => Some(texture),
            Err(reason) => {
                tracing::warn!(
                    "material {name:?}: base colour texture (image {image}) not used, \
                     drawn with its base colour factor: {reason}"
                );
                None
            }
        }
    });
    Material {
        name,
        base_color: factor.map(|c| {
            if c.is_finite() {
                c.clamp(0.0, 1.0)
            } else {
                1.0
            }
        }),
        texture,
        double_sided: m.double_sided(),
    }
}

/// Reads and decodes image `index` of the document as RGBA8, or says why it cannot.
fn load_texture(
    doc: &gltf::Document,
    index: usize,
    buffers: &[Vec<u8>],
    base: Option<&Path>,
    texture_pixels: &mut u64,
) -> Result<Texture, String> {
    // Read from the JSON: `gltf::Image::source` panics on an image with a buffer view and no
    // MIME type, or with neither a buffer view nor a URI.
    let json = doc.as_json().images.get(index).ok_or("no such image")?;
    let mime = json.mime_type.as_ref().map(|m| m.0.as_str());
    let bytes = if let Some(view) = &json.buffer_view {
        let view = doc
            .views()
            .nth(view.value())
            .ok_or("buffer view out of range")?;
        view_slice(&view, buffers)
            .map_err(|e| e.to_string())?
            .to_vec()
    } else if let Some(uri) = &json.uri {
        read_uri(uri, base).map_err(|e| e.to_string())?
    } else {
        return Err("the image has neither a buffer view nor a URI".into());
    };
    let format = texture_format(mime, &bytes).ok_or_else(|| match mime {
        Some(m) => format!("unsupported image type {m:?} (PNG and JPEG are)"),
        None => "not a PNG or JPEG image".to_owned(),
    })?;
    let (width, height) = image::ImageReader::with_format(std::io::Cursor::new(&bytes), format)
        .into_dimensions()
        .map_err(|e| format!("{format:?} image does not decode: {e}"))?;
    *texture_pixels = texture_pixels
        .checked_sub(u64::from(width) * u64::from(height))
        .ok_or_else(|| {
            format!("the head's textures together would exceed {MAX_TEXTURE_PIXELS} pixels")
        })?;
    decode_texture(&bytes, format)
}

/// Decodes PNG or JPEG bytes as RGBA8, refusing declared sizes over [`MAX_TEXTURE_SIDE`] before
/// allocating for the pixels.
fn decode_texture(bytes: &[u8], format: image::ImageFormat) -> Result<Texture, String> {
    let mut reader = image::ImageReader::with_format(std::io::Cursor::new(bytes), format);
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_TEXTURE_SIDE);
    limits.max_image_height = Some(MAX_TEXTURE_SIDE);
    reader.limits(limits);
    let decoded = reader
        .decode()
        .map_err(|e| format!("{format:?} image does not decode: {e}"))?;
    let rgba = decoded.to_rgba8();
    Ok(Texture {
        width: rgba.width(),
        height: rgba.height(),
        rgba: rgba.into_raw(),
    })
}

/// The format to decode a texture as: its declared MIME type when it has one, else the bytes'
/// signature. `None` for anything but PNG and JPEG.
fn texture_format(mime: Option<&str>, bytes: &[u8]) -> Option<image::ImageFormat> {
    match mime {
        Some(m) => match m.trim().to_ascii_lowercase().as_str() {
            "image/png" => Some(image::ImageFormat::Png),
            "image/jpeg" | "image/jpg" => Some(image::ImageFormat::Jpeg),
            _ => None,
        },
        None if bytes.starts_with(b"\x89PNG\r\n\x1a\n") => Some(image::ImageFormat::Png),
        None if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) => Some(image::ImageFormat::Jpeg),
        None => None,
    }
}

fn view_slice<'a>(
    view: &gltf::buffer::View,
    buffers: &'a [Vec<u8>],
) -> Result<&'a [u8], RenderError> {
    let data = buffers
        .get(view.buffer().index())
        .ok_or_else(|| RenderError::Gltf("buffer view of a missing buffer".into()))?;
    let end = view
        .offset()
        .checked_add(view.length())
        .ok_or_else(|| RenderError::Gltf("buffer view overflows".into()))?;
    data.get(view.offset()..end)
        .ok_or_else(|| RenderError::Gltf(format!("buffer view {} out of range", view.index())))
}

/// Checks that an accessor of `count` elements fits its buffer view (and sparse parts fit theirs),
/// and that its element type is one of `allowed`.
fn check_accessor(
    a: &gltf::Accessor,
    buffers: &[Vec<u8>],
    allowed: &[(DataType, Dimensions)],
    what: &str,
) -> Result<(), RenderError> {
    let bad = |msg: String| RenderError::Gltf(format!("{what} accessor {}: {msg}", a.index()));
    if !allowed.contains(&(a.data_type(), a.dimensions())) {
        return Err(bad(format!(
            "unsupported type {:?} {:?}",
            a.data_type(),
            a.dimensions()
        )));
    }
    if a.count() == 0 || a.count() > MAX_VERTICES * 3 {
        return Err(bad(format!("count {}", a.count())));
    }
    let fits = |view: &gltf::buffer::View,
                offset: usize,
                count: usize,
                size: usize|
     -> Result<(), RenderError> {
        let slice = view_slice(view, buffers)?;
        let stride = view.stride().unwrap_or(size);
        if stride < size {
            return Err(bad(format!("stride {stride} < element size {size}")));
        }
        let end = stride
            .checked_mul(count - 1)
            .and_then(|x| x.checked_add(offset))
            .and_then(|x| x.checked_add(size))
            .ok_or_else(|| bad("size overflows".into()))?;
        if end > slice.len() {
            return Err(bad(format!("needs {end} bytes, view has {}", slice.len())));
        }
        Ok(())
    };
    match a.view() {
        Some(view) => fits(&view, a.offset(), a.count(), a.size())?,
        None if a.sparse().is_none() => return Err(bad("no buffer view".into())),
        None => {}
    }
    if let Some(sparse) = a.sparse() {
        let n = sparse.count();
        if n == 0 || n > a.count() {
            return Err(bad(format!("sparse count {n}")));
        }
        let idx = sparse.indices();
        fits(&idx.view(), idx.offset(), n, idx.index_type().size())?;
        let vals = sparse.values();
        fits(&vals.view(), vals.offset(), n, a.size())?;
    }
    Ok(())
}

fn read_primitive(
    prim: &gltf::Primitive,
    mesh: &gltf::Mesh,
    names: &[String],
    jaw_joints: &[bool],
    transform: Mat4,
    buffers: &[Vec<u8>],
    budget: &mut usize,
) -> Result<RawPrimitive, RenderError> {
    use DataType::{F32, U8, U16, U32};
    use Dimensions::{Scalar, Vec2, Vec4};
    let vec3 = [(F32, Dimensions::Vec3)];
    let get = |b: gltf::Buffer| buffers.get(b.index()).map(|v| v.as_slice());
    let reader = prim.reader(get);

    let pos_acc = prim
        .get(&gltf::Semantic::Positions)
        .ok_or_else(|| RenderError::Gltf("primitive without POSITION".into()))?;
    check_accessor(&pos_acc, buffers, &vec3, "POSITION")?;
    let n = pos_acc.count();
    let attr_ok = |sem: gltf::Semantic,
                   allowed: &[(DataType, Dimensions)],
                   what: &str|
     -> Result<bool, RenderError> {
        match prim.get(&sem) {
            Some(acc) => {
                check_accessor(&acc, buffers, allowed, what)?;
                if acc.count() != n {
                    return Err(RenderError::Gltf(format!(
                        "{what} count differs from POSITION"
                    )));
                }
                Ok(true)
            }
            None => Ok(false),
        }
    };
    let has_normals = attr_ok(gltf::Semantic::Normals, &vec3, "NORMAL")?;
    let has_uv = attr_ok(
        gltf::Semantic::TexCoords(0),
        &[(F32, Vec2), (U8, Vec2), (U16, Vec2)],
        "TEXCOORD_0",
    )?;
    let has_color = attr_ok(
        gltf::Semantic::Colors(0),
        &[
            (F32, Dimensions::Vec3),
            (F32, Vec4),
            (U8, Dimensions::Vec3),
            (U8, Vec4),
            (U16, Dimensions::Vec3),
            (U16, Vec4),
        ],
        "COLOR_0",
    )?;

    let mut targets = Vec::new();
    for (t, target) in prim.morph_targets().enumerate() {
        let name = names.get(t).map(String::as_str).unwrap_or("");
        let kind = classify(name);
        if kind == TargetKind::Unused {
            continue;
        }
        if let Some(acc) = target.positions() {
            check_accessor(&acc, buffers, &vec3, "morph POSITION")?;
            if acc.count() != n {
                return Err(RenderError::Gltf(
                    "morph target count differs from POSITION".into(),
                ));
            }
        }
        if let Some(acc) = target.normals() {
            check_accessor(&acc, buffers, &vec3, "morph NORMAL")?;
            if acc.count() != n {
                return Err(RenderError::Gltf(
                    "morph target count differs from POSITION".into(),
                ));
            }
        }
        targets.push((kind, t));
    }
    // Checked before any vertex or delta is made: the accessors fit their buffers, but one
    // accessor may stand behind many targets and many nodes' meshes.
    let index_count = prim.indices().map_or(0, |a| a.count());
    let elements = n
        .saturating_mul(targets.len() + 1)
        .saturating_add(index_count);
    *budget = budget.checked_sub(elements).ok_or_else(|| {
        RenderError::Unsupported(
            "the meshes and morph targets expand to far more data than the file holds \
             (accessors shared by many meshes or targets?)"
                .into(),
        )
    })?;
    let missing = || RenderError::Gltf("accessor data missing".into());
    let linear = Mat3::from_mat4(transform);
    let normal_matrix = if linear.determinant().abs() > 1e-12 {
        linear.inverse().transpose()
    } else {
        Mat3::IDENTITY
    };
    let positions: Vec<Vec3> = reader
        .read_positions()
        .ok_or_else(missing)?
        .map(|p| transform.transform_point3(Vec3::from(p)))
        .collect();
    if positions.len() != n || positions.iter().any(|&p| !coordinate_ok(p)) {
        return Err(RenderError::Gltf(format!(
            "POSITION has values that are not finite or beyond {MAX_COORDINATE:e}"
        )));
    }

    let indices: Vec<u32> = match prim.indices() {
        Some(acc) => {
            check_accessor(
                &acc,
                buffers,
                &[(U8, Scalar), (U16, Scalar), (U32, Scalar)],
                "indices",
            )?;
            let idx: Vec<u32> = reader
                .read_indices()
                .ok_or_else(missing)?
                .into_u32()
                .collect();
            if idx.iter().any(|&i| i as usize >= n) {
                return Err(RenderError::Gltf("triangle index out of range".into()));
            }
            idx
        }
        None => (0..n as u32).collect(),
    };
    let indices: Vec<u32> = indices[..indices.len() - indices.len() % 3].to_vec();

    let normals: Vec<Vec3> = if has_normals {
        reader
            .read_normals()
            .ok_or_else(missing)?
            .map(|v| (normal_matrix * Vec3::from(v)).normalize_or_zero())
            .collect()
    } else {
        smooth_normals(&positions, &indices)
    };
    let uvs: Vec<[f32; 2]> = if has_uv {
        reader
            .read_tex_coords(0)
            .ok_or_else(missing)?
            .into_f32()
            .collect()
    } else {
        vec![[0.0; 2]; n]
    };
    let colors: Vec<[f32; 4]> = if has_color {
        reader
            .read_colors(0)
            .ok_or_else(missing)?
            .into_rgba_f32()
            .collect()
    } else {
        vec![[1.0; 4]; n]
    };
    if normals.len() != n || uvs.len() != n || colors.len() != n {
        return Err(RenderError::Gltf("attribute lengths differ".into()));
    }
    let vertices: Vec<Vertex> = (0..n)
        .map(|i| Vertex {
            position: positions[i].into(),
            normal: normals[i].into(),
            uv: uvs[i],
            color: colors[i],
        })
        .collect();

    let mut out_targets = Vec::new();
    if !targets.is_empty() {
        // Only the checked accessors of the targets used are read: the reader's
        // `read_morph_targets` opens every target's, unused ones and tangents too, unchecked
        // (a debug assertion in the gltf crate on their element size).
        let morph_targets: Vec<gltf::mesh::MorphTarget> = prim.morph_targets().collect();
        let read = |a: Option<gltf::Accessor>| {
            a.and_then(|a| gltf::accessor::Iter::<[f32; 3]>::new(a, get))
        };
        for (kind, t) in targets {
            let target = morph_targets.get(t).ok_or_else(missing)?;
            let mut deltas = vec![MorphDelta::default(); n];
            if let Some(p) = read(target.positions()) {
                for (d, v) in deltas.iter_mut().zip(p) {
                    d.position = (linear * Vec3::from(v)).into();
                }
            }
            if let Some(nrm) = read(target.normals()) {
                for (d, v) in deltas.iter_mut().zip(nrm) {
                    d.normal = (normal_matrix * Vec3::from(v)).into();
                }
            }
            if deltas.iter().any(|d| {
                !coordinate_ok(Vec3::from(d.position)) || !coordinate_ok(Vec3::from(d.normal))
            }) {
                return Err(RenderError::Gltf(format!(
                    "a morph target has values that are not finite or beyond {MAX_COORDINATE:e}"
                )));
            }
            out_targets.push((kind, deltas));
        }
    }
    let jaw_weights = if jaw_joints.iter().any(|&j| j)
        && attr_ok(
            gltf::Semantic::Joints(0),
            &[(U8, Vec4), (U16, Vec4)],
            "JOINTS_0",
        )?
        && attr_ok(
            gltf::Semantic::Weights(0),
            &[(F32, Vec4), (U8, Vec4), (U16, Vec4)],
            "WEIGHTS_0",
        )? {
        let joints = reader.read_joints(0).ok_or_else(missing)?.into_u16();
        let weights = reader.read_weights(0).ok_or_else(missing)?.into_f32();
        let jaw: Vec<f32> = joints
            .zip(weights)
            .map(|(j, w)| {
                (0..4)
                    .filter(|&k| jaw_joints.get(j[k] as usize).copied().unwrap_or(false))
                    .map(|k| w[k].clamp(0.0, 1.0))
                    .sum::<f32>()
                    .min(1.0)
            })
            .collect();
        (jaw.len() == n && jaw.iter().any(|&w| w > 0.0)).then_some(jaw)
    } else {
        None
    };
    Ok(RawPrimitive {
        name: mesh.name().unwrap_or("mesh").to_owned(),
        material: prim.material().index(),
        vertices,
        indices,
        targets: out_targets,
        jaw_weights,
    })
}

#[cfg(test)]
mod tests {
    use super::{
        Expression, TargetKind, classify, decode_texture, load_buffers, load_materials,
        texture_format,
    };
    use image::ImageFormat;

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

    const PNG: &[u8] = b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR";
    const JPEG: &[u8] = &[0xFF, 0xD8, 0xFF, 0xE0, 0, 16, b'J', b'F', b'I', b'F'];

    #[test]
    fn declared_mime_type_wins_over_the_signature() {
        assert_eq!(
            texture_format(Some("image/jpeg"), PNG),
            Some(ImageFormat::Jpeg)
        );
        assert_eq!(
            texture_format(Some("image/png"), JPEG),
            Some(ImageFormat::Png)
        );
        assert_eq!(texture_format(Some("image/webp"), PNG), None);
        assert_eq!(texture_format(Some("image/ktx2"), JPEG), None);
    }

    #[test]
    fn signature_decides_without_a_mime_type() {
        assert_eq!(texture_format(None, PNG), Some(ImageFormat::Png));
        assert_eq!(texture_format(None, JPEG), Some(ImageFormat::Jpeg));
        assert_eq!(texture_format(None, b"RIFF\0\0\0\0WEBPVP8 "), None);
        assert_eq!(texture_format(None, b""), None);
    }

    #[test]
    fn oversized_textures_are_refused_before_decoding() {
        let img = image::RgbImage::from_pixel(8, 8, image::Rgb([0, 0, 255]));
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new(&mut jpeg)
            .encode_image(&img)
            .unwrap();
        let ok = decode_texture(&jpeg, ImageFormat::Jpeg).unwrap();
        assert_eq!((ok.width, ok.height), (8, 8));
        // Declare 60000 x 60000 in the frame header (SOF0: FF C0, length, precision, height, width).
        let sof = jpeg.windows(2).position(|w| w == [0xFF, 0xC0]).unwrap();
        jpeg[sof + 5..sof + 9].copy_from_slice(&[0xEA, 0x60, 0xEA, 0x60]);
        let err = decode_texture(&jpeg, ImageFormat::Jpeg).unwrap_err();
        assert!(err.to_lowercase().contains("limit"), "{err}");
    }

    #[test]
    fn one_image_behind_many_materials_is_decoded_within_the_pixel_budget() {
        let img = image::RgbaImage::from_pixel(16, 16, image::Rgba([200, 100, 50, 255]));
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), ImageFormat::Png)
            .unwrap();
        // A data URI in base64, as exporters write it.
        const ABC: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut b64 = String::new();
        for chunk in png.chunks(3) {
            let n = chunk
                .iter()
                .enumerate()
                .fold(0u32, |n, (i, &b)| n | u32::from(b) << (16 - 8 * i));
            for k in 0..4 {
                b64.push(if k <= chunk.len() {
                    ABC[(n >> (18 - 6 * k) & 63) as usize] as char
                } else {
                    '='
                });
            }
        }
        let materials = [r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}"#; 5];
        let json = format!(
            r#"{{"asset":{{"version":"2.0"}},
            "buffers":[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{b64}"}}],
            "bufferViews":[{{"buffer":0,"byteLength":{}}}],
            "images":[{{"bufferView":0,"mimeType":"image/png"}}],
            "textures":[{{"source":0}}],
            "materials":[{}]}}"#,
            png.len(),
            png.len(),
            materials.join(",")
        );
        let gltf = gltf::Gltf::from_slice(json.as_bytes()).unwrap();
        let buffers = load_buffers(&gltf.document, None, None).unwrap();
        let loaded = load_materials(&gltf.document, &buffers, None, 2 * 16 * 16);
        let textured: Vec<bool> = loaded.iter().map(|m| m.texture.is_some()).collect();
        assert_eq!(textured, [true, true, false, false, false]);
        let all = load_materials(&gltf.document, &buffers, None, 5 * 16 * 16);
        assert!(all.iter().all(|m| m.texture.is_some()));
    }
}
