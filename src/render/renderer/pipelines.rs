//! The pipelines and layouts of the head renderer ([`HeadRenderer`]): one pipeline per kind of
//! material, built once.

use crate::render::RenderError;
use crate::render::head::Vertex;

/// The WGSL source of the head shader (`shaders/head.wgsl`).
pub const SHADER_SOURCE: &str = include_str!("../../../shaders/head.wgsl");

/// Depth format used by the offscreen target; any depth format works with [`HeadRenderer::new`].
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Which of [`HeadRenderer`]'s pipelines draws a material.
pub(super) fn pipeline_index(double_sided: bool, textured: bool) -> usize {
    usize::from(double_sided) * 2 + usize::from(textured)
}

/// The inverse of [`pipeline_index`]: (double-sided, textured).
pub(super) fn pipeline_kind(index: usize) -> (bool, bool) {
    (index & 2 != 0, index & 1 != 0)
}

/// Where a head's lighting is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Shading {
    /// Per pixel: the full look, at any size.
    #[default]
    PerPixel,
    /// Per vertex, interpolated across each triangle: the same look where triangles are a few
    /// pixels across (a small head), for a fraction of a software adapter's fragment work.
    /// Double-sided materials stay lit per pixel (their back faces turn the normal round).
    PerVertex,
}

/// Pipeline, layouts and sampler shared by every head drawn into one kind of target.
pub struct HeadRenderer {
    /// One per kind of material (see [`pipeline_index`]): back faces culled unless the material
    /// is `doubleSided`, as glTF says (half the triangles never reach a software rasteriser), and
    /// the texture sampled only where there is one.
    pub(super) pipelines: [wgpu::RenderPipeline; 4],
    /// The one-sided kinds again (untextured, textured) with lighting per vertex, when built
    /// ([`Self::add_vertex_lighting`]) for instances drawn with [`Shading::PerVertex`].
    pub(super) vertex_lit: Option<[wgpu::RenderPipeline; 2]>,
    pub(super) shader: wgpu::ShaderModule,
    layout: wgpu::PipelineLayout,
    samples: u32,
    pub(super) head_layout: wgpu::BindGroupLayout,
    pub(super) material_layout: wgpu::BindGroupLayout,
    pub(super) sampler: wgpu::Sampler,
    pub(super) color_format: wgpu::TextureFormat,
    pub(super) depth_format: Option<wgpu::TextureFormat>,
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
                // The vertex stage reads the base colour where it lights per vertex.
                uniform_entry(0, wgpu::ShaderStages::VERTEX_FRAGMENT),
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
        let target = TargetKind {
            color_format,
            depth_format,
            samples,
        };
        let pipelines = std::array::from_fn(|index| {
            head_pipeline(
                device,
                &shader,
                &layout,
                &target,
                pipeline_kind(index),
                false,
            )
        });
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
            vertex_lit: None,
            shader,
            layout,
            samples,
            head_layout,
            material_layout,
            sampler,
            color_format,
            depth_format,
        }
    }

    /// Builds the pipelines that light per vertex ([`Shading::PerVertex`]), once; until then
    /// such instances are lit per pixel. On demand: each pipeline is a shader compile, which a
    /// software adapter pays for in time.
    pub fn add_vertex_lighting(&mut self, device: &wgpu::Device) {
        if self.vertex_lit.is_some() {
            return;
        }
        let target = TargetKind {
            color_format: self.color_format,
            depth_format: self.depth_format,
            samples: self.samples,
        };
        self.vertex_lit = Some([false, true].map(|textured| {
            head_pipeline(
                device,
                &self.shader,
                &self.layout,
                &target,
                (false, textured),
                true,
            )
        }));
    }

    /// The pipeline that draws a material of kind `index` ([`pipeline_index`]) with `shading`.
    pub(super) fn pipeline(&self, index: usize, shading: Shading) -> &wgpu::RenderPipeline {
        let (double_sided, textured) = pipeline_kind(index);
        match (&self.vertex_lit, shading) {
            (Some(lit), Shading::PerVertex) if !double_sided => &lit[usize::from(textured)],
            _ => &self.pipelines[index],
        }
    }

    pub fn color_format(&self) -> wgpu::TextureFormat {
        self.color_format
    }

    pub fn depth_format(&self) -> Option<wgpu::TextureFormat> {
        self.depth_format
    }
}

/// What a pipeline draws into.
struct TargetKind {
    color_format: wgpu::TextureFormat,
    depth_format: Option<wgpu::TextureFormat>,
    samples: u32,
}

/// One head pipeline: back faces culled unless `double_sided`, the base colour texture sampled
/// if `textured`, lighting per vertex if `vertex_lit`.
fn head_pipeline(
    device: &wgpu::Device,
    shader: &wgpu::ShaderModule,
    layout: &wgpu::PipelineLayout,
    target: &TargetKind,
    (double_sided, textured): (bool, bool),
    vertex_lit: bool,
) -> wgpu::RenderPipeline {
    let constants = [("TEXTURED", f64::from(u8::from(textured)))];
    let compilation_options = wgpu::PipelineCompilationOptions {
        constants: &constants,
        ..Default::default()
    };
    let attributes = wgpu::vertex_attr_array![
        0 => Float32x3, 1 => Float32x3, 2 => Float32x2, 3 => Float32x4
    ];
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(&format!(
            "lipcall head pipeline ({}, {}, lit per {})",
            if double_sided {
                "double-sided"
            } else {
                "one-sided"
            },
            if textured { "textured" } else { "untextured" },
            if vertex_lit { "vertex" } else { "pixel" }
        )),
        layout: Some(layout),
        vertex: wgpu::VertexState {
            module: shader,
            entry_point: Some(if vertex_lit {
                "vs_vertex_lit"
            } else {
                "vs_main"
            }),
            compilation_options: compilation_options.clone(),
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
        depth_stencil: target.depth_format.map(|format| wgpu::DepthStencilState {
            format,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Less),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: wgpu::MultisampleState {
            count: target.samples.max(1),
            ..Default::default()
        },
        fragment: Some(wgpu::FragmentState {
            module: shader,
            entry_point: Some(if vertex_lit {
                "fs_vertex_lit"
            } else {
                "fs_main"
            }),
            compilation_options: compilation_options.clone(),
            targets: &[Some(wgpu::ColorTargetState {
                format: target.color_format,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    })
}
