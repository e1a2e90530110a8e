//! Writes a [`HeadModel`] as a binary glTF 2.0 file (GLB), with one mesh per primitive, the
//! viseme shapes as morph targets named `viseme_<name>` and the eye expressions a primitive has
//! under their slot names (`eyeBlink`, `eyeLookUp`, ...; listed in `mesh.extras.targetNames`);
//! [`write_meshes`] writes avatars as other tools make them (several primitives per mesh, any
//! target names, skins), for tests of the loader.

use serde_json::{Value, json};

use lipcall::render::head::{HeadModel, Material, MorphDelta, Primitive, Vertex, slot_name};
use lipcall::vocab::{VISEME_COUNT, VISEME_NAMES};

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const UNSIGNED_SHORT: u32 = 5123;

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

/// One mesh for [`write_meshes`]: its primitives share the mesh's morph target names.
#[derive(Debug, Clone, Default)]
pub struct MeshOut {
    pub name: String,
    pub primitives: Vec<PrimitiveOut>,
    /// `mesh.extras.targetNames`; each primitive holds one delta list per name.
    pub target_names: Vec<String>,
    /// Names of the joint nodes of the mesh's skin (none: not skinned). Joints are written as
    /// root nodes at the origin with identity inverse bind matrices.
    pub joint_names: Vec<String>,
}

impl MeshOut {
    /// `part` of a head as a mesh of its own, unskinned, with these morph targets.
    pub fn unskinned(part: &Primitive, names: Vec<String>, targets: Vec<Vec<MorphDelta>>) -> Self {
        Self {
            name: part.name.clone(),
            primitives: vec![PrimitiveOut {
                vertices: part.vertices.clone(),
                indices: part.indices.clone(),
                material: part.material,
                targets,
                joints: Vec::new(),
            }],
            target_names: names,
            joint_names: Vec::new(),
        }
    }
}

/// One triangle primitive for [`write_meshes`].
#[derive(Debug, Clone, Default)]
pub struct PrimitiveOut {
    pub vertices: Vec<Vertex>,
    pub indices: Vec<u32>,
    pub material: usize,
    /// One delta list per target name of the mesh (empty lists are written as zeros).
    pub targets: Vec<Vec<MorphDelta>>,
    /// Per vertex (only for a skinned mesh): four (joint index into the mesh's `joint_names`,
    /// weight) pairs, written as `JOINTS_0` and `WEIGHTS_0`.
    pub joints: Vec<[(u16, f32); 4]>,
}

/// Serialises a head to GLB bytes: one mesh per primitive, named after it.
pub fn write_glb(model: &HeadModel) -> Vec<u8> {
    let meshes: Vec<MeshOut> = model
        .primitives
        .iter()
        .map(|p| {
            let mut names = Vec::new();
            let mut targets = Vec::new();
            if p.has_targets() {
                for (t, deltas) in p.targets.iter().enumerate() {
                    // Every viseme is written (empty ones as zeros); expressions only where
                    // present.
                    if t >= VISEME_COUNT && deltas.is_empty() {
                        continue;
                    }
                    names.push(match VISEME_NAMES.get(t) {
                        Some(v) => format!("viseme_{v}"),
                        None => slot_name(t).unwrap_or("unused").to_owned(),
                    });
                    targets.push(deltas.clone());
                }
            }
            MeshOut::unskinned(p, names, targets)
        })
        .collect();
    write_meshes(&meshes, &model.materials)
}

/// Serialises meshes (one node each, all in the scene) with their materials' base colour
/// factors to GLB bytes: avatars for tests, with several primitives per mesh, named morph
/// targets of any kind (ARKit, visemes) and skins.
pub fn write_meshes(meshes: &[MeshOut], materials: &[Material]) -> Vec<u8> {
    let mut b = Builder {
        bin: Vec::new(),
        views: Vec::new(),
        accessors: Vec::new(),
    };
    let mut out_meshes = Vec::new();
    let mut nodes = Vec::new();
    let mut skins = Vec::new();
    for m in meshes {
        let mut primitives = Vec::new();
        for p in &m.primitives {
            let pos: Vec<[f32; 3]> = p.vertices.iter().map(|v| v.position).collect();
            let nrm: Vec<[f32; 3]> = p.vertices.iter().map(|v| v.normal).collect();
            let uv: Vec<[f32; 2]> = p.vertices.iter().map(|v| v.uv).collect();
            let col: Vec<[f32; 4]> = p.vertices.iter().map(|v| v.color).collect();
            let mut attributes = json!({
                "POSITION": b.vec_accessor(&pos, true),
                "NORMAL": b.vec_accessor(&nrm, false),
                "TEXCOORD_0": b.vec_accessor(&uv, false),
                "COLOR_0": b.vec_accessor(&col, false),
            });
            if !m.joint_names.is_empty() {
                let joints: Vec<u8> = (0..p.vertices.len())
                    .flat_map(|i| p.joints.get(i).copied().unwrap_or_default())
                    .flat_map(|(j, _)| j.to_le_bytes())
                    .collect();
                let jv = b.view(&joints, Some(ARRAY_BUFFER));
                b.accessors
                    .push(json!({"bufferView": jv, "componentType": UNSIGNED_SHORT,
                                        "count": p.vertices.len(), "type": "VEC4"}));
                attributes["JOINTS_0"] = json!(b.accessors.len() - 1);
                let weights: Vec<[f32; 4]> = (0..p.vertices.len())
                    .map(|i| {
                        let j = p.joints.get(i).copied().unwrap_or_default();
                        [j[0].1, j[1].1, j[2].1, j[3].1]
                    })
                    .collect();
                attributes["WEIGHTS_0"] = json!(b.vec_accessor(&weights, false));
            }
            let idx_bytes: Vec<u8> = p.indices.iter().flat_map(|i| i.to_le_bytes()).collect();
            let iv = b.view(&idx_bytes, Some(ELEMENT_ARRAY_BUFFER));
            b.accessors
                .push(json!({"bufferView": iv, "componentType": UNSIGNED_INT,
                                    "count": p.indices.len(), "type": "SCALAR"}));
            let indices = b.accessors.len() - 1;
            let mut primitive = json!({"attributes": attributes, "indices": indices,
                                       "material": p.material, "mode": 4});
            if !m.target_names.is_empty() {
                let n = p.vertices.len();
                let targets: Vec<Value> = (0..m.target_names.len())
                    .map(|t| {
                        let deltas = p.targets.get(t).filter(|d| d.len() == n);
                        let dp: Vec<[f32; 3]> = match deltas {
                            Some(d) => d.iter().map(|d| d.position).collect(),
                            None => vec![[0.0; 3]; n],
                        };
                        let dn: Vec<[f32; 3]> = match deltas {
                            Some(d) => d.iter().map(|d| d.normal).collect(),
                            None => vec![[0.0; 3]; n],
                        };
                        json!({"POSITION": b.sparse_vec3(&dp), "NORMAL": b.sparse_vec3(&dn)})
                    })
                    .collect();
                primitive["targets"] = json!(targets);
            }
            primitives.push(primitive);
        }
        let mut mesh = json!({"name": m.name, "primitives": primitives});
        if !m.target_names.is_empty() {
            mesh["weights"] = json!(vec![0.0; m.target_names.len()]);
            mesh["extras"] = json!({"targetNames": m.target_names});
        }
        out_meshes.push(mesh);
        nodes.push(json!({"name": m.name, "mesh": out_meshes.len() - 1}));
    }
    // Joint nodes after the mesh nodes, one skin per skinned mesh.
    for (mi, m) in meshes.iter().enumerate() {
        if m.joint_names.is_empty() {
            continue;
        }
        let first = nodes.len();
        for name in &m.joint_names {
            nodes.push(json!({"name": name}));
        }
        skins.push(json!({"joints": (first..nodes.len()).collect::<Vec<_>>()}));
        nodes[mi]["skin"] = json!(skins.len() - 1);
    }
    let materials: Vec<Value> = materials
        .iter()
        .map(|m| {
            json!({"name": m.name, "doubleSided": m.double_sided, "pbrMetallicRoughness": {
                "baseColorFactor": m.base_color.to_vec(), "metallicFactor": 0.0, "roughnessFactor": 0.7}})
        })
        .collect();
    while !b.bin.len().is_multiple_of(4) {
        b.bin.push(0);
    }
    let mut doc = json!({
        "asset": {"version": "2.0", "generator": "lipcall head builder"},
        "scene": 0,
        "scenes": [{"name": "head", "nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes,
        "meshes": out_meshes,
        "materials": materials,
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": [{"byteLength": b.bin.len()}],
    });
    if !skins.is_empty() {
        doc["skins"] = json!(skins);
    }
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
