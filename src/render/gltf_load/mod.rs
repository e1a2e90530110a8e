//! Loading glTF 2.0 / GLB heads: meshes and primitives under their node transforms, base colour
//! factors and PNG or JPEG base colour textures, and morph targets matched by name to the visemes
//! (`viseme_aa` or `aa`) or to ARKit blendshapes combined through [`super::arkit`], and to the
//! eye expressions (ARKit's `eyeBlink*` and `eyeLook*`, or lipcall's own slot names).
//!
//! Every accessor is bounds-checked before it is read, so malformed files give errors, not panics.
//! Skinned meshes are taken in their bind pose (their node transform is ignored, as the glTF
//! specification says). Every mesh's own targets are combined by the same rules (teeth and tongue
//! meshes with `jawOpen` or `viseme_aa` of their own move with the face); a mesh skinned to a
//! joint named like a jaw that has no mouth targets follows the face's jaw
//! (`targets::follow_the_jaw`).
//!
//! Here the walk of the scene's nodes; beside it the validation of the file and its accessors
//! (`validate`), the buffers (`buffers`), the reading of one primitive's accessors
//! (`primitive`), the materials and textures (`materials`) and the morph targets' mapping to
//! the viseme and expression slots (`targets`).

mod buffers;
mod materials;
mod primitive;
mod target_names;
mod targets;
mod validate;

use std::path::Path;

use glam::Mat4;

use super::RenderError;
use super::head::{HeadModel, Material};
use buffers::load_buffers;
use materials::{MAX_TEXTURE_PIXELS, load_materials};
use primitive::read_primitive;
use targets::{build_model, target_names};
use validate::{ELEMENT_BUDGET_FLOOR, MAX_NODE_DEPTH, MAX_VERTICES, parse_validated};

/// Loads a head from a `.glb` or `.gltf` file (external buffers and images are read from beside it).
pub fn load_head(path: &Path) -> Result<HeadModel, RenderError> {
    let bytes = crate::input::read(path, crate::input::MAX_INPUT_BYTES)?;
    load_head_from_slice_in(&bytes, path.parent())
}

/// Loads a head from GLB bytes (or glTF JSON with embedded `data:` buffers).
pub fn load_head_from_slice(bytes: &[u8]) -> Result<HeadModel, RenderError> {
    load_head_from_slice_in(bytes, None)
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

/// Path of the bundled default head, relative to the repository root.
pub const DEFAULT_HEAD_PATH: &str = "assets/heads/default.glb";

/// The bundled default head (built from the MakeHuman base mesh by `tools/build_head.py`).
pub fn default_head() -> Result<HeadModel, RenderError> {
    load_head_from_slice(include_bytes!("../../../assets/heads/default.glb"))
}

/// Loads `--head FILE.glb` if given, else the bundled default head.
pub fn load_head_or_default(path: Option<&std::path::Path>) -> Result<HeadModel, RenderError> {
    match path {
        Some(p) => load_head(p),
        None => default_head(),
    }
}
