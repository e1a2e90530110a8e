//! Validation before anything is read: the limits on a head's size, the GLB header and the
//! references the gltf crate would index unchecked, and each accessor's bounds in its buffer.

use glam::Vec3;
use gltf::accessor::{DataType, Dimensions};

use super::buffers::view_slice;
use crate::render::RenderError;

/// Refuse absurd sizes before allocating for them.
pub(super) const MAX_VERTICES: usize = 4_000_000;
/// Largest coordinate of a vertex or of a morph target's displacement: a head is at most a few
/// metres across in any unit a tool exports (300 in millimetres), and far beyond that the f32
/// sums that frame and blend it overflow (a finite 1e36 displacement gave an infinite mouth).
pub(super) const MAX_COORDINATE: f32 = 1.0e6;
pub(super) const MAX_NODE_DEPTH: usize = 64;
/// Vertices, indices and morph deltas read may reach this many plus one per 4 bytes of buffer
/// data: a file reads about one per 4 to 12 buffer bytes, and without this budget one accessor
/// referenced by many meshes or targets would be expanded for each of them.
pub(super) const ELEMENT_BUDGET_FLOOR: usize = 1 << 20;

pub(super) fn coordinate_ok(v: Vec3) -> bool {
    v.is_finite() && v.abs().max_element() <= MAX_COORDINATE
}

pub(super) fn gltf_err(e: impl std::fmt::Display) -> RenderError {
    RenderError::Gltf(e.to_string())
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
pub(super) fn parse_validated(bytes: &[u8]) -> Result<gltf::Gltf, RenderError> {
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

/// Checks that an accessor of `count` elements fits its buffer view (and sparse parts fit theirs),
/// and that its element type is one of `allowed`.
pub(super) fn check_accessor(
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
