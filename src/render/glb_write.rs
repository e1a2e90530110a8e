//! Writes a [`HeadModel`] as a binary glTF 2.0 file (GLB), with one mesh per primitive, the
//! viseme shapes as morph targets named `viseme_<name>` and the eye expressions a primitive has
//! under their slot names (`eyeBlink`, `eyeLookUp`, ...; listed in `mesh.extras.targetNames`).

use serde_json::{Value, json};

use super::head::{HeadModel, VISEME_COUNT, VISEME_NAMES, slot_name};

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;

struct Builder {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Builder {
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        let mut v = json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.views.push(v);
        self.views.len() - 1
    }

    fn vec_accessor<const N: usize>(&mut self, items: &[[f32; N]], with_bounds: bool) -> usize {
        let bytes: Vec<u8> = items
            .iter()
            .flatten()
            .flat_map(|f| f.to_le_bytes())
            .collect();
        let view = self.view(&bytes, Some(ARRAY_BUFFER));
        let kind = match N {
            2 => "VEC2",
            3 => "VEC3",
            _ => "VEC4",
        };
        let mut a =
            json!({"bufferView": view, "componentType": FLOAT, "count": items.len(), "type": kind});
        if with_bounds {
            let mut min = [f32::INFINITY; N];
            let mut max = [f32::NEG_INFINITY; N];
            for item in items {
                for k in 0..N {
                    min[k] = min[k].min(item[k]);
                    max[k] = max[k].max(item[k]);
                }
            }
            if !items.is_empty() {
                a["min"] = json!(min.to_vec());
                a["max"] = json!(max.to_vec());
            }
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    /// A VEC3 accessor that stores only the non-zero entries (glTF sparse accessor).
    fn sparse_vec3(&mut self, items: &[[f32; 3]]) -> usize {
        let mut nonzero: Vec<u32> = (0..items.len() as u32)
            .filter(|&i| items[i as usize] != [0.0; 3])
            .collect();
        // An accessor needs a buffer view or sparse data: an all-zero target keeps one entry.
        if nonzero.is_empty() && !items.is_empty() {
            nonzero.push(0);
        }
        let mut min = [f32::INFINITY; 3];
        let mut max = [f32::NEG_INFINITY; 3];
        for item in items {
            for k in 0..3 {
                min[k] = min[k].min(item[k]);
                max[k] = max[k].max(item[k]);
            }
        }
        let mut a = json!({"componentType": FLOAT, "count": items.len(), "type": "VEC3",
                           "min": min.to_vec(), "max": max.to_vec()});
        if !nonzero.is_empty() {
            let idx: Vec<u8> = nonzero.iter().flat_map(|i| i.to_le_bytes()).collect();
            let vals: Vec<u8> = nonzero
                .iter()
                .flat_map(|&i| items[i as usize])
                .flat_map(|f| f.to_le_bytes())
                .collect();
            let iv = self.view(&idx, None);
            let vv = self.view(&vals, None);
            a["sparse"] = json!({"count": nonzero.len(),
                "indices": {"bufferView": iv, "componentType": UNSIGNED_INT},
                "values": {"bufferView": vv}});
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }
}

/// Serialises a head to GLB bytes.
pub fn write_glb(model: &HeadModel) -> Vec<u8> {
    let mut b = Builder {
        bin: Vec::new(),
        views: Vec::new(),
        accessors: Vec::new(),
    };
    let mut meshes = Vec::new();
    let mut nodes = Vec::new();
    for (mi, p) in model.primitives.iter().enumerate() {
        let pos: Vec<[f32; 3]> = p.vertices.iter().map(|v| v.position).collect();
        let nrm: Vec<[f32; 3]> = p.vertices.iter().map(|v| v.normal).collect();
        let uv: Vec<[f32; 2]> = p.vertices.iter().map(|v| v.uv).collect();
        let col: Vec<[f32; 4]> = p.vertices.iter().map(|v| v.color).collect();
        let attributes = json!({
            "POSITION": b.vec_accessor(&pos, true),
            "NORMAL": b.vec_accessor(&nrm, false),
            "TEXCOORD_0": b.vec_accessor(&uv, false),
            "COLOR_0": b.vec_accessor(&col, false),
        });
        let idx_bytes: Vec<u8> = p.indices.iter().flat_map(|i| i.to_le_bytes()).collect();
        let iv = b.view(&idx_bytes, Some(ELEMENT_ARRAY_BUFFER));
        b.accessors
            .push(json!({"bufferView": iv, "componentType": UNSIGNED_INT,
                                "count": p.indices.len(), "type": "SCALAR"}));
        let indices = b.accessors.len() - 1;
        let mut primitive = json!({"attributes": attributes, "indices": indices,
                                   "material": p.material, "mode": 4});
        let mut mesh = json!({"name": p.name});
        if p.has_targets() {
            let mut targets = Vec::new();
            let mut names = Vec::new();
            for (t, deltas) in p.targets.iter().enumerate() {
                // Every viseme is written (empty ones as zeros); expressions only where present.
                if t >= VISEME_COUNT && deltas.is_empty() {
                    continue;
                }
                let dp: Vec<[f32; 3]> = deltas.iter().map(|d| d.position).collect();
                let dn: Vec<[f32; 3]> = deltas.iter().map(|d| d.normal).collect();
                let (dp, dn) = if deltas.is_empty() {
                    (
                        vec![[0.0; 3]; p.vertices.len()],
                        vec![[0.0; 3]; p.vertices.len()],
                    )
                } else {
                    (dp, dn)
                };
                targets.push(json!({"POSITION": b.sparse_vec3(&dp), "NORMAL": b.sparse_vec3(&dn)}));
                names.push(match VISEME_NAMES.get(t) {
                    Some(v) => format!("viseme_{v}"),
                    None => slot_name(t).unwrap_or("unused").to_owned(),
                });
            }
            primitive["targets"] = json!(targets);
            mesh["weights"] = json!(vec![0.0; targets.len()]);
            mesh["extras"] = json!({"targetNames": names});
        }
        mesh["primitives"] = json!([primitive]);
        meshes.push(mesh);
        nodes.push(json!({"name": p.name, "mesh": mi}));
    }
    let materials: Vec<Value> = model
        .materials
        .iter()
        .map(|m| {
            json!({"name": m.name, "pbrMetallicRoughness": {
                "baseColorFactor": m.base_color.to_vec(), "metallicFactor": 0.0, "roughnessFactor": 0.7}})
        })
        .collect();
    while !b.bin.len().is_multiple_of(4) {
        b.bin.push(0);
    }
    let doc = json!({
        "asset": {"version": "2.0", "generator": "lipcall head builder"},
        "scene": 0,
        "scenes": [{"name": "head", "nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": [{"byteLength": b.bin.len()}],
    });
    glb_container(doc.to_string().as_bytes(), &b.bin)
}

/// Wraps a JSON chunk and a binary chunk into a GLB container (padding both to 4 bytes).
pub fn glb_container(json_chunk: &[u8], bin_chunk: &[u8]) -> Vec<u8> {
    let mut json_chunk = json_chunk.to_vec();
    while !json_chunk.len().is_multiple_of(4) {
        json_chunk.push(b' ');
    }
    let mut bin_chunk = bin_chunk.to_vec();
    while !bin_chunk.len().is_multiple_of(4) {
        bin_chunk.push(0);
    }
    let (json_chunk, bin_chunk) = (&json_chunk[..], &bin_chunk[..]);
    let total = 12
        + 8
        + json_chunk.len()
        + if bin_chunk.is_empty() {
            0
        } else {
            8 + bin_chunk.len()
        };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json_chunk.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(json_chunk);
    if !bin_chunk.is_empty() {
        out.extend_from_slice(&(bin_chunk.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(bin_chunk);
    }
    out
}
