//! One triangle primitive read from its checked accessors: vertices under the node transform,
//! indices, the deltas of the morph targets it uses and its vertices' weights on a jaw joint.

use glam::{Mat3, Mat4, Vec3};
use gltf::accessor::{DataType, Dimensions};

use super::target_names::{TargetKind, classify};
use super::validate::{MAX_COORDINATE, check_accessor, coordinate_ok};
use crate::render::RenderError;
use crate::render::head::{MorphDelta, Vertex, smooth_normals};

/// A primitive read from the file, with its raw morph targets.
pub(super) struct RawPrimitive {
    pub(super) name: String,
    /// `None`: the default material, the last of the list.
    pub(super) material: Option<usize>,
    pub(super) vertices: Vec<Vertex>,
    pub(super) indices: Vec<u32>,
    pub(super) targets: Vec<(TargetKind, Vec<MorphDelta>)>,
    /// Per vertex, how much it is skinned to joints named like a jaw (`None`: to none).
    pub(super) jaw_weights: Option<Vec<f32>>,
}

pub(super) fn read_primitive(
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
