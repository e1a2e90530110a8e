//! A head's upload to the GPU, once: vertices (those some target moves first), the indices of
//! each level of detail, the moving vertices' morph deltas and each material's uniform, texture
//! and bind group.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

use super::motion::MotionReach;
use super::pipelines::{HeadRenderer, Shading, pipeline_index};
use crate::render::RenderError;
use crate::render::facing;
use crate::render::head::{FaceFrame, HeadModel, MorphDelta, TARGET_COUNT, Vertex};
use crate::render::lod::DetailLevels;
use crate::render::variant::is_skin_material;
use crate::vocab::{FacePose, VISEME_COUNT, VisemeWeights};

#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
struct MaterialUniform {
    base_color: [f32; 4],
    /// x: 1 where a head variant recolours this material (its skin), else 0.
    recolour: [f32; 4],
}

/// A draw call of one primitive.
#[derive(Debug, Clone)]
pub(super) struct DrawRange {
    pub(super) indices: std::ops::Range<u32>,
    pub(super) material: usize,
}

/// One level of detail: its error bound and the draws of its triangles, all of them or only
/// those a frontal camera can see ([`crate::render::facing`]).
pub(super) struct GpuLevel {
    pub(super) error_m: f32,
    pub(super) triangles: usize,
    pub(super) draws: Vec<DrawRange>,
    pub(super) frontal_triangles: usize,
    pub(super) frontal_draws: Vec<DrawRange>,
}

pub(super) struct GpuMaterial {
    pub(super) bind_group: wgpu::BindGroup,
    pub(super) pipeline: usize,
    _uniform: wgpu::Buffer,
    _texture: Option<wgpu::Texture>,
}

/// A head's meshes and morph deltas on the GPU, uploaded once and shareable between instances.
pub struct GpuHead {
    label: String,
    pub(super) vertex_buffer: wgpu::Buffer,
    pub(super) index_buffer: wgpu::Buffer,
    pub(super) delta_buffer: wgpu::Buffer,
    pub(super) materials: Vec<GpuMaterial>,
    /// Finest (the full mesh) first.
    pub(super) levels: Vec<GpuLevel>,
    pub(super) morph_vertices: u32,
    /// The first of the moving vertices that the eye shapes move too, and the first that only
    /// they move (the visemes move those before).
    pub(super) mouth_and_eyes_from: u32,
    pub(super) eyes_only_from: u32,
    pub(super) vertex_count: u32,
    /// Where each vertex of the model (primitives in order) sits in the GPU vertex buffer.
    pub(super) model_to_gpu: Vec<u32>,
    pub(super) frame: FaceFrame,
    /// Where the frontal framings put the eye ([`crate::render::facing::frontal_eyes`]).
    pub(super) frontal_eyes: [glam::Vec3; 2],
    /// How far its shapes and rotation can move its vertices.
    pub(super) reach: MotionReach,
    /// Median length of the full mesh's triangle edges, in metres.
    median_edge_m: f32,
}

/// Lighting per vertex pays where a head's typical triangle edge is at most this many pixels:
/// smaller than the highlights and shadows the lights draw across a face.
pub const VERTEX_LIT_MAX_EDGE_PX: f32 = 6.0;

/// Median length of `model`'s triangle edges (0 for a head without triangles).
fn median_edge(model: &HeadModel) -> f32 {
    let mut edges: Vec<f32> = model
        .primitives
        .iter()
        .flat_map(|p| {
            p.indices.chunks_exact(3).flat_map(move |t| {
                let at = |i: u32| glam::Vec3::from(p.vertices[i as usize].position);
                [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])].map(|(a, b)| at(a).distance(at(b)))
            })
        })
        .collect();
    if edges.is_empty() {
        return 0.0;
    }
    let middle = edges.len() / 2;
    *edges.select_nth_unstable_by(middle, f32::total_cmp).1
}

impl GpuHead {
    /// Where the mouth is and how big the head is, for [`Camera::framing`].
    ///
    /// [`Camera::framing`]: crate::render::Camera::framing
    pub fn face_frame(&self) -> &FaceFrame {
        &self.frame
    }

    pub fn vertex_count(&self) -> u32 {
        self.vertex_count
    }

    pub fn label(&self) -> &str {
        &self.label
    }

    /// Number of levels of detail (1: the full mesh alone).
    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    /// Triangles drawn at `level` (clamped to the coarsest).
    pub fn triangle_count(&self, level: usize) -> usize {
        self.level(level).triangles
    }

    /// The coarsest level that stays under [`crate::render::lod::MAX_ERROR_PX`] where a metre
    /// at the head's distance is `pixels_per_metre` pixels ([`Camera::pixels_per_metre`]).
    ///
    /// [`Camera::pixels_per_metre`]: crate::render::Camera::pixels_per_metre
    pub fn level_for(&self, pixels_per_metre: f32) -> usize {
        crate::render::lod::level_for(self.levels.iter().map(|l| l.error_m), pixels_per_metre)
    }

    /// How to light the head where a metre at its distance is `pixels_per_metre` pixels: per
    /// vertex once its typical triangle is at most [`VERTEX_LIT_MAX_EDGE_PX`] pixels across.
    pub fn shading_for(&self, pixels_per_metre: f32) -> Shading {
        if pixels_per_metre.is_finite()
            && self.median_edge_m * pixels_per_metre <= VERTEX_LIT_MAX_EDGE_PX
        {
            Shading::PerVertex
        } else {
            Shading::PerPixel
        }
    }

    /// True when the head drawn with `b` would differ from the head drawn with `a` by less than
    /// [`super::UNSEEN_MOTION_PX`] anywhere (every vertex, where a metre spans
    /// `pixels_per_metre` pixels) and no slot's weight changed by more than a small step.
    pub fn looks_the_same(
        &self,
        a: (&VisemeWeights, &FacePose),
        b: (&VisemeWeights, &FacePose),
        pixels_per_metre: f32,
    ) -> bool {
        self.reach.looks_the_same(a, b, pixels_per_metre)
    }

    pub(super) fn level(&self, level: usize) -> &GpuLevel {
        &self.levels[level.min(self.levels.len() - 1)]
    }
}

impl HeadRenderer {
    /// Uploads a head's meshes, materials and morph deltas (once), the full mesh alone.
    pub fn upload(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        model: &HeadModel,
        label: &str,
    ) -> Result<Arc<GpuHead>, RenderError> {
        self.upload_with_levels(device, queue, model, &DetailLevels::full(model), label)
    }

    /// [`Self::upload`] with the levels of detail `levels` (built from `model`), drawn as
    /// [`super::HeadInstance::level`] says.
    pub fn upload_with_levels(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        model: &HeadModel,
        levels: &DetailLevels,
        label: &str,
    ) -> Result<Arc<GpuHead>, RenderError> {
        model.validate()?;
        let levels = levels.levels();
        if levels.is_empty()
            || levels.iter().any(|l| {
                l.indices.len() != model.primitives.len()
                    || l.indices.iter().zip(&model.primitives).any(|(ix, p)| {
                        ix.len() % 3 != 0 || ix.iter().any(|&i| i as usize >= p.vertices.len())
                    })
            })
        {
            return Err(RenderError::InvalidHead(
                "levels of detail that do not fit the head".into(),
            ));
        }
        let vertex_count = model.vertex_count();
        let index_count: usize = levels.iter().flat_map(|l| &l.indices).map(Vec::len).sum();
        // Each level's indices are stored twice: all triangles, and the frontal ones.
        let index_count = 2 * index_count;
        if vertex_count >= u32::MAX as usize / 16 || index_count >= u32::MAX as usize {
            return Err(RenderError::InvalidHead("too many vertices".into()));
        }
        // Vertices that some target moves come first and alone get delta storage: the vertex
        // stage then blends only them (on a software adapter, most of a frame's time). Among
        // them, those only the visemes move, then those both the visemes and the eye shapes
        // move, then those only the eye shapes move: each blends only its own kind of slots.
        let class = |p: &crate::render::head::Primitive, i: usize| {
            let moved_by = |slots: std::ops::Range<usize>| {
                p.targets[slots]
                    .iter()
                    .any(|t| t.get(i).is_some_and(|d| *d != MorphDelta::default()))
            };
            match (
                moved_by(0..VISEME_COUNT),
                moved_by(VISEME_COUNT..TARGET_COUNT),
            ) {
                (true, false) => 0,
                (true, true) => 1,
                (false, true) => 2,
                (false, false) => 3,
            }
        };
        let classes: Vec<usize> = model
            .primitives
            .iter()
            .flat_map(|p| (0..p.vertices.len()).map(move |i| class(p, i)))
            .collect();
        let mut next = [0u32; 4];
        for &c in &classes {
            next[c] += 1;
        }
        let mut start = 0;
        for n in &mut next {
            (*n, start) = (start, start + *n);
        }
        let [_, mouth_and_eyes_from, eyes_only_from, morph_vertices] = next;
        let morph_vertices = morph_vertices as usize;
        let model_to_gpu: Vec<u32> = classes
            .iter()
            .map(|&c| {
                next[c] += 1;
                next[c] - 1
            })
            .collect();
        let delta_bytes =
            (TARGET_COUNT * morph_vertices * std::mem::size_of::<MorphDelta>()) as u64;
        let max_binding = device.limits().max_storage_buffer_binding_size;
        if delta_bytes > max_binding {
            return Err(RenderError::Unsupported(format!(
                "{morph_vertices} morphing vertices need {delta_bytes} bytes of deltas, more than \
                 the device's storage binding limit of {max_binding}"
            )));
        }

        let mut vertices = vec![Vertex::default(); vertex_count];
        let mut indices: Vec<u32> = Vec::with_capacity(index_count);
        let mut deltas = vec![MorphDelta::default(); TARGET_COUNT * morph_vertices];
        let mut gpu_levels: Vec<GpuLevel> = levels
            .iter()
            .map(|l| GpuLevel {
                error_m: l.error_m,
                triangles: l.triangle_count(),
                draws: Vec::new(),
                frontal_triangles: 0,
                frontal_draws: Vec::new(),
            })
            .collect();
        let frame = model.face_frame();
        let seen_from = facing::FrontalEyes::of(&frame);
        let mut base = 0usize;
        for (k, p) in model.primitives.iter().enumerate() {
            let gpu = &model_to_gpu[base..base + p.vertices.len()];
            for (i, v) in p.vertices.iter().enumerate() {
                vertices[gpu[i] as usize] = *v;
            }
            for (t, target) in p.targets.iter().enumerate() {
                for (i, d) in target.iter().enumerate() {
                    if (gpu[i] as usize) < morph_vertices {
                        deltas[t * morph_vertices + gpu[i] as usize] = *d;
                    }
                }
            }
            let double_sided = model
                .materials
                .get(p.material)
                .is_some_and(|m| m.double_sided);
            for (level, gpu_level) in levels.iter().zip(&mut gpu_levels) {
                let all = &level.indices[k];
                // A double-sided part shows its back faces too.
                let frontal = if double_sided {
                    all.clone()
                } else {
                    seen_from.triangles(p, all)
                };
                gpu_level.frontal_triangles += frontal.len() / 3;
                let mut push = |triangles: &[u32]| {
                    let first = indices.len() as u32;
                    // In the order that reuses the most shaded vertices.
                    let ordered = meshopt::optimize_vertex_cache(triangles, p.vertices.len());
                    indices.extend(ordered.iter().map(|&i| gpu[i as usize]));
                    DrawRange {
                        indices: first..indices.len() as u32,
                        material: p.material,
                    }
                };
                let draw = push(all);
                let frontal_draw = if frontal.len() == all.len() {
                    draw.clone()
                } else {
                    push(&frontal)
                };
                gpu_level.draws.push(draw);
                gpu_level.frontal_draws.push(frontal_draw);
            }
            base += p.vertices.len();
        }

        // The largest part (the face's skin) first: the parts it hides (teeth, tongue, the backs
        // of the eyes) then fail the depth test before they are shaded, where drawn first they
        // were shaded and then covered. The picture is the same.
        for level in &mut gpu_levels {
            for draws in [&mut level.draws, &mut level.frontal_draws] {
                draws.sort_by_key(|d| std::cmp::Reverse(d.indices.len()));
            }
        }

        let vertex_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(&format!("{label} vertices")),
            contents: bytemuck::cast_slice(&vertices),
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::STORAGE,
        });
        let index_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(&format!("{label} indices")),
            contents: bytemuck::cast_slice(&indices),
            usage: wgpu::BufferUsages::INDEX,
        });
        // A zero-sized storage binding is invalid; keep one dummy delta.
        if deltas.is_empty() {
            deltas.push(MorphDelta::default());
        }
        let delta_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(&format!("{label} morph deltas")),
            contents: bytemuck::cast_slice(&deltas),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let materials = model
            .materials
            .iter()
            .enumerate()
            .map(|(i, m)| self.upload_material(device, queue, m, &format!("{label} material {i}")))
            .collect();
        Ok(Arc::new(GpuHead {
            label: label.to_owned(),
            vertex_buffer,
            index_buffer,
            delta_buffer,
            materials,
            levels: gpu_levels,
            morph_vertices: morph_vertices as u32,
            mouth_and_eyes_from,
            eyes_only_from,
            vertex_count: vertex_count as u32,
            model_to_gpu,
            frontal_eyes: facing::frontal_eyes(&frame),
            frame,
            reach: MotionReach::of(model, frame.neck_pivot()),
            median_edge_m: median_edge(model),
        }))
    }

    fn upload_material(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        material: &crate::render::head::Material,
        label: &str,
    ) -> GpuMaterial {
        let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(&format!("{label} uniform")),
            contents: bytemuck::bytes_of(&MaterialUniform {
                base_color: material.base_color,
                recolour: [
                    f32::from(u8::from(is_skin_material(&material.name))),
                    0.0,
                    0.0,
                    0.0,
                ],
            }),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let white = crate::render::head::Texture {
            width: 1,
            height: 1,
            rgba: vec![255; 4],
        };
        let image = material
            .texture
            .as_ref()
            .filter(|t| {
                let max = device.limits().max_texture_dimension_2d;
                t.width > 0
                    && t.height > 0
                    && t.width <= max
                    && t.height <= max
                    && t.rgba.len() == 4 * t.width as usize * t.height as usize
            })
            .unwrap_or(&white);
        let texture = device.create_texture_with_data(
            queue,
            &wgpu::TextureDescriptor {
                label: Some(&format!("{label} base colour")),
                size: wgpu::Extent3d {
                    width: image.width,
                    height: image.height,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::Rgba8UnormSrgb,
                usage: wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            },
            wgpu::util::TextureDataOrder::LayerMajor,
            &image.rgba,
        );
        let view = texture.create_view(&wgpu::TextureViewDescriptor {
            label: Some(&format!("{label} base colour view")),
            ..Default::default()
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(&format!("{label} bind group")),
            layout: &self.material_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: uniform.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&view),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(&self.sampler),
                },
            ],
        });
        GpuMaterial {
            bind_group,
            pipeline: pipeline_index(material.double_sided, material.texture.is_some()),
            _uniform: uniform,
            _texture: Some(texture),
        }
    }
}
