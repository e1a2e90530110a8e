//! The wgpu head renderer: one pipeline per kind of material, heads uploaded once, weights and pose written per frame.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3};
use wgpu::util::DeviceExt;

use super::RenderError;
use super::camera::Camera;
use super::head::{FaceFrame, HeadModel, MorphDelta, TARGET_COUNT, Vertex, slot_weights};
use crate::vocab::{FacePose, VisemeWeights};

/// The WGSL source of the head shader (`shaders/head.wgsl`).
pub const SHADER_SOURCE: &str = include_str!("../../shaders/head.wgsl");

/// Depth format used by the offscreen target; any depth format works with [`HeadRenderer::new`].
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
struct ViewUniform {
    view_proj: [[f32; 4]; 4],
    model: [[f32; 4]; 4],
    eye: [f32; 4],
    light_dir: [f32; 4],
    counts: [u32; 4],
}

#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
struct WeightsUniform {
    /// x: how many slots carry weight; the first `x` entries of `slots` and `w` are they, so the
    /// vertex stage loops over those alone.
    active: [u32; 4],
    slots: [u32; TARGET_COUNT],
    w: [f32; TARGET_COUNT],
}

impl WeightsUniform {
    fn new(weights: &VisemeWeights, pose: &FacePose) -> Self {
        let mut u = Self {
            active: [0; 4],
            slots: [0; TARGET_COUNT],
            w: [0.0; TARGET_COUNT],
        };
        let mut n = 0;
        for (slot, w) in slot_weights(weights, pose).into_iter().enumerate() {
            if w != 0.0 {
                u.slots[n] = slot as u32;
                u.w[n] = w;
                n += 1;
            }
        }
        u.active[0] = n as u32;
        u
    }
}

#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
struct MaterialUniform {
    base_color: [f32; 4],
}

/// Which of [`HeadRenderer`]'s pipelines draws a material.
fn pipeline_index(double_sided: bool, textured: bool) -> usize {
    usize::from(double_sided) * 2 + usize::from(textured)
}

/// The inverse of [`pipeline_index`]: (double-sided, textured).
fn pipeline_kind(index: usize) -> (bool, bool) {
    (index & 2 != 0, index & 1 != 0)
}

/// Pipeline, layouts and sampler shared by every head drawn into one kind of target.
pub struct HeadRenderer {
    /// One per kind of material (see [`pipeline_index`]): back faces culled unless the material
    /// is `doubleSided`, as glTF says (half the triangles never reach a software rasteriser), and
    /// the texture sampled only where there is one.
    pipelines: [wgpu::RenderPipeline; 4],
    shader: wgpu::ShaderModule,
    head_layout: wgpu::BindGroupLayout,
    material_layout: wgpu::BindGroupLayout,
    sampler: wgpu::Sampler,
    color_format: wgpu::TextureFormat,
    depth_format: Option<wgpu::TextureFormat>,
}

/// A draw call of one primitive.
#[derive(Debug, Clone)]
struct DrawRange {
    indices: std::ops::Range<u32>,
    material: usize,
}

struct GpuMaterial {
    bind_group: wgpu::BindGroup,
    pipeline: usize,
    _uniform: wgpu::Buffer,
    _texture: Option<wgpu::Texture>,
}

/// A head's meshes and morph deltas on the GPU, uploaded once and shareable between instances.
pub struct GpuHead {
    label: String,
    vertex_buffer: wgpu::Buffer,
    index_buffer: wgpu::Buffer,
    delta_buffer: wgpu::Buffer,
    materials: Vec<GpuMaterial>,
    draws: Vec<DrawRange>,
    morph_vertices: u32,
    vertex_count: u32,
    /// Where each vertex of the model (primitives in order) sits in the GPU vertex buffer.
    model_to_gpu: Vec<u32>,
    frame: FaceFrame,
}

impl GpuHead {
    /// Where the mouth is and how big the head is, for [`Camera::framing`].
    pub fn face_frame(&self) -> &FaceFrame {
        &self.frame
    }

    pub fn vertex_count(&self) -> u32 {
        self.vertex_count
    }

    pub fn label(&self) -> &str {
        &self.label
    }
}

/// One head on screen: its own uniforms (camera, placement, weights) over a shared [`GpuHead`].
pub struct HeadInstance {
    head: Arc<GpuHead>,
    view_buffer: wgpu::Buffer,
    weights_buffer: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    last_view: Option<ViewUniform>,
    last_weights: Option<WeightsUniform>,
    /// Placement of the head in the scene (rotation, uniform scale, translation).
    pub model: Mat4,
}

impl HeadInstance {
    pub fn head(&self) -> &Arc<GpuHead> {
        &self.head
    }
}

impl HeadRenderer {
    /// Limits a device must be created with for this renderer: WebGPU's downlevel defaults, which
    /// (unlike the WebGL2 limits egui-wgpu asks for on GL by default) allow storage buffers in the
    /// vertex stage. Combine with the adapter's own limits via `.using_resolution(adapter.limits())`
    /// if textures larger than 2048 px are needed.
    pub fn required_limits() -> wgpu::Limits {
        wgpu::Limits::downlevel_defaults()
    }

    /// Downlevel capabilities the adapter must have (checked by [`Self::check_adapter`]).
    pub fn required_downlevel_flags() -> wgpu::DownlevelFlags {
        wgpu::DownlevelFlags::VERTEX_STORAGE | wgpu::DownlevelFlags::COMPUTE_SHADERS
    }

    /// Tells whether an adapter can run this renderer, and what it lacks if not.
    pub fn check_adapter(adapter: &wgpu::Adapter) -> Result<(), RenderError> {
        let caps = adapter.get_downlevel_capabilities();
        let limits = adapter.limits();
        let need = Self::required_limits();
        let mut missing = Vec::new();
        if !caps.flags.contains(wgpu::DownlevelFlags::VERTEX_STORAGE) {
            missing.push("storage buffers in the vertex stage".to_owned());
        }
        if limits.max_storage_buffers_per_shader_stage < need.max_storage_buffers_per_shader_stage {
            missing.push(format!(
                "max_storage_buffers_per_shader_stage {} < {}",
                limits.max_storage_buffers_per_shader_stage,
                need.max_storage_buffers_per_shader_stage
            ));
        }
        if missing.is_empty() {
            Ok(())
        } else {
            Err(RenderError::AdapterUnsuitable {
                adapter: adapter.get_info().name,
                missing: missing.join(", "),
            })
        }
    }

    /// Builds the pipeline for targets of `color_format`, with a depth attachment of
    /// `depth_format` if given (heads need one to look right; egui tiles may have none).
    pub fn new(
        device: &wgpu::Device,
        color_format: wgpu::TextureFormat,
        depth_format: Option<wgpu::TextureFormat>,
    ) -> Self {
        Self::with_samples(device, color_format, depth_format, 1)
    }

    /// Like [`Self::new`], for targets of `samples` per pixel (see [`super::target::HeadTarget`]).
    pub fn with_samples(
        device: &wgpu::Device,
        color_format: wgpu::TextureFormat,
        depth_format: Option<wgpu::TextureFormat>,
        samples: u32,
    ) -> Self {
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("lipcall head shader"),
            source: wgpu::ShaderSource::Wgsl(SHADER_SOURCE.into()),
        });
        let uniform_entry = |binding, visibility| wgpu::BindGroupLayoutEntry {
            binding,
            visibility,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let storage_entry = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::VERTEX | wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let stages = wgpu::ShaderStages::VERTEX_FRAGMENT | wgpu::ShaderStages::COMPUTE;
        let head_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("lipcall head bind group layout"),
            entries: &[
                uniform_entry(0, stages),
                // The weights are a storage buffer, not a uniform: lavapipe specialises a shader
                // on uniform values that steer its loops, and the number of slots in use changes
                // from frame to frame (a shader compile per draw).
                storage_entry(1),
                storage_entry(2),
            ],
        });
        let material_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("lipcall head material bind group layout"),
            entries: &[
                uniform_entry(0, wgpu::ShaderStages::FRAGMENT),
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("lipcall head pipeline layout"),
            bind_group_layouts: &[Some(&head_layout), Some(&material_layout)],
            immediate_size: 0,
        });
        let attributes = wgpu::vertex_attr_array![
            0 => Float32x3, 1 => Float32x3, 2 => Float32x2, 3 => Float32x4
        ];
        let pipeline = |index: usize| {
            let (double_sided, textured) = pipeline_kind(index);
            let constants = [("TEXTURED", f64::from(u8::from(textured)))];
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(&format!(
                    "lipcall head pipeline ({}, {})",
                    if double_sided {
                        "double-sided"
                    } else {
                        "one-sided"
                    },
                    if textured { "textured" } else { "untextured" }
                )),
                layout: Some(&layout),
                vertex: wgpu::VertexState {
                    module: &shader,
                    entry_point: Some("vs_main"),
                    compilation_options: Default::default(),
                    buffers: &[Some(wgpu::VertexBufferLayout {
                        array_stride: std::mem::size_of::<Vertex>() as u64,
                        step_mode: wgpu::VertexStepMode::Vertex,
                        attributes: &attributes,
                    })],
                },
                primitive: wgpu::PrimitiveState {
                    topology: wgpu::PrimitiveTopology::TriangleList,
                    cull_mode: if double_sided {
                        None
                    } else {
                        Some(wgpu::Face::Back)
                    },
                    ..Default::default()
                },
                depth_stencil: depth_format.map(|format| wgpu::DepthStencilState {
                    format,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(wgpu::CompareFunction::Less),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: wgpu::MultisampleState {
                    count: samples.max(1),
                    ..Default::default()
                },
                fragment: Some(wgpu::FragmentState {
                    module: &shader,
                    entry_point: Some("fs_main"),
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants: &constants,
                        ..Default::default()
                    },
                    targets: &[Some(wgpu::ColorTargetState {
                        format: color_format,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let pipelines = std::array::from_fn(pipeline);
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("lipcall head base colour sampler"),
            address_mode_u: wgpu::AddressMode::Repeat,
            address_mode_v: wgpu::AddressMode::Repeat,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        Self {
            pipelines,
            shader,
            head_layout,
            material_layout,
            sampler,
            color_format,
            depth_format,
        }
    }

    pub fn color_format(&self) -> wgpu::TextureFormat {
        self.color_format
    }

    pub fn depth_format(&self) -> Option<wgpu::TextureFormat> {
        self.depth_format
    }

    /// Uploads a head's meshes, materials and morph deltas (once).
    pub fn upload(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        model: &HeadModel,
        label: &str,
    ) -> Result<Arc<GpuHead>, RenderError> {
        model.validate()?;
        let vertex_count = model.vertex_count();
        let index_count: usize = model.primitives.iter().map(|p| p.indices.len()).sum();
        if vertex_count >= u32::MAX as usize / 16 || index_count >= u32::MAX as usize {
            return Err(RenderError::InvalidHead("too many vertices".into()));
        }
        // Vertices that some target moves come first and alone get delta storage: the vertex
        // stage then blends only them (on a software adapter, most of a frame's time).
        let moves = |p: &super::head::Primitive, i: usize| {
            p.targets
                .iter()
                .any(|t| t.get(i).is_some_and(|d| *d != MorphDelta::default()))
        };
        let moving: Vec<bool> = model
            .primitives
            .iter()
            .flat_map(|p| (0..p.vertices.len()).map(move |i| moves(p, i)))
            .collect();
        let morph_vertices = moving.iter().filter(|&&m| m).count();
        let (mut next_moving, mut next_still) = (0u32, morph_vertices as u32);
        let model_to_gpu: Vec<u32> = moving
            .iter()
            .map(|&m| {
                let next = if m { &mut next_moving } else { &mut next_still };
                *next += 1;
                *next - 1
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
        let mut draws = Vec::new();
        let mut base = 0usize;
        for p in &model.primitives {
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
            let first = indices.len() as u32;
            indices.extend(p.indices.iter().map(|&i| gpu[i as usize]));
            draws.push(DrawRange {
                indices: first..indices.len() as u32,
                material: p.material,
            });
            base += p.vertices.len();
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
            draws,
            morph_vertices: morph_vertices as u32,
            vertex_count: vertex_count as u32,
            model_to_gpu,
            frame: model.face_frame(),
        }))
    }

    fn upload_material(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        material: &super::head::Material,
        label: &str,
    ) -> GpuMaterial {
        let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(&format!("{label} uniform")),
            contents: bytemuck::bytes_of(&MaterialUniform {
                base_color: material.base_color,
            }),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let white = super::head::Texture {
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

    /// Creates the per-head uniforms for drawing `head` (many instances may share one head).
    pub fn new_instance(
        &self,
        device: &wgpu::Device,
        head: Arc<GpuHead>,
        label: &str,
    ) -> HeadInstance {
        let view_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(&format!("{label} view uniform")),
            size: std::mem::size_of::<ViewUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let weights_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(&format!("{label} target weights")),
            size: std::mem::size_of::<WeightsUniform>() as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(&format!("{label} bind group")),
            layout: &self.head_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: view_buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: weights_buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: head.delta_buffer.as_entire_binding(),
                },
            ],
        });
        HeadInstance {
            head,
            view_buffer,
            weights_buffer,
            bind_group,
            last_view: None,
            last_weights: None,
            model: Mat4::IDENTITY,
        }
    }

    /// Writes this frame's uniforms: the weights of the 20 slots (the 15 visemes and the pose's
    /// eyes) and, only when the camera, aspect, placement or head rotation changed, the view.
    /// The pose's head rotation turns the head about its neck pivot
    /// ([`FaceFrame::neck_pivot`]) on top of `instance.model`. Call before the render pass is
    /// begun.
    pub fn prepare(
        &self,
        queue: &wgpu::Queue,
        instance: &mut HeadInstance,
        camera: &Camera,
        aspect: f32,
        weights: &VisemeWeights,
        pose: &FacePose,
    ) {
        let light = Vec3::new(-0.45, -0.55, -0.7).normalize();
        let model = instance.model * pose.head_matrix(instance.head.frame.neck_pivot());
        let view = ViewUniform {
            view_proj: camera.view_proj(aspect).to_cols_array_2d(),
            model: model.to_cols_array_2d(),
            eye: camera.eye.extend(1.0).into(),
            light_dir: light.extend(0.0).into(),
            counts: [
                instance.head.morph_vertices,
                instance.head.vertex_count,
                0,
                0,
            ],
        };
        if instance.last_view != Some(view) {
            queue.write_buffer(&instance.view_buffer, 0, bytemuck::bytes_of(&view));
            instance.last_view = Some(view);
        }
        let w = WeightsUniform::new(weights, pose);
        if instance.last_weights != Some(w) {
            queue.write_buffer(&instance.weights_buffer, 0, bytemuck::bytes_of(&w));
            instance.last_weights = Some(w);
        }
    }

    /// Records the head's draws into `pass` (whose viewport the caller has set).
    pub fn paint(&self, pass: &mut wgpu::RenderPass<'_>, instance: &HeadInstance) {
        let head = &instance.head;
        pass.set_bind_group(0, &instance.bind_group, &[]);
        pass.set_vertex_buffer(0, head.vertex_buffer.slice(..));
        pass.set_index_buffer(head.index_buffer.slice(..), wgpu::IndexFormat::Uint32);
        let mut bound = None;
        for draw in &head.draws {
            if let Some(material) = head.materials.get(draw.material) {
                if bound != Some(material.pipeline) {
                    bound = Some(material.pipeline);
                    pass.set_pipeline(&self.pipelines[material.pipeline]);
                }
                pass.set_bind_group(1, &material.bind_group, &[]);
                pass.draw_indexed(draw.indices.clone(), 0, 0..1);
            }
        }
    }

    /// Runs the vertex shader's blend function in a compute pass and reads back the blended
    /// positions and normals (all slots, in head space: before the model matrix), in the model's
    /// primitive/vertex order (for tests and debugging). Uses the weights and pose last written
    /// by [`Self::prepare`]; [`HeadModel::blend_cpu_posed`] is its CPU reference.
    pub fn blend_on_gpu(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        instance: &HeadInstance,
    ) -> Result<Vec<MorphDelta>, RenderError> {
        let head = &instance.head;
        let blend_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("lipcall blend readback layout"),
            entries: &[storage_entry(0, true), storage_entry(1, false)],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("lipcall blend readback pipeline layout"),
            bind_group_layouts: &[Some(&self.head_layout), None, Some(&blend_layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("lipcall blend readback pipeline"),
            layout: Some(&layout),
            module: &self.shader,
            entry_point: Some("cs_blend"),
            compilation_options: Default::default(),
            cache: None,
        });
        let out_size = (head.vertex_count as u64 * std::mem::size_of::<MorphDelta>() as u64).max(4);
        let out = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lipcall blend readback output"),
            size: out_size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let staging = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lipcall blend readback staging"),
            size: out_size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("lipcall blend readback bind group"),
            layout: &blend_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: head.vertex_buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: out.as_entire_binding(),
                },
            ],
        });
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("lipcall blend readback encoder"),
        });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("lipcall blend readback pass"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &instance.bind_group, &[]);
            pass.set_bind_group(2, &bind_group, &[]);
            pass.dispatch_workgroups(head.vertex_count.div_ceil(64), 1, 1);
        }
        encoder.copy_buffer_to_buffer(&out, 0, &staging, 0, out_size);
        queue.submit([encoder.finish()]);
        let bytes = super::readback::read_buffer(device, &staging)?;
        let used = head.vertex_count as usize * std::mem::size_of::<MorphDelta>();
        let gpu: Vec<MorphDelta> = bytemuck::pod_collect_to_vec(
            bytes
                .get(..used)
                .ok_or_else(|| RenderError::Readback("short blend readback".into()))?,
        );
        Ok(head.model_to_gpu.iter().map(|&g| gpu[g as usize]).collect())
    }
}

fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}
