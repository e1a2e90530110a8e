//! Puts a rendered head ([`HeadTarget`]) into someone else's render pass (the window's, egui's)
//! pixel for pixel: one triangle over the pass's viewport (which may be cut at the window's
//! edge), each fragment the texel at its offset from the image's corner, opaque.
//! egui's own path for images (filtered sampling, vertex colour, blending) costs a software
//! adapter tens of nanoseconds a pixel, most of a frame when the tiles fill the window.

use super::target::{HeadTarget, TARGET_FORMAT, TARGET_VIEW_UNORM};

const SHADER: &str = r"
@group(0) @binding(0) var image: texture_2d<f32>;
// xy: the pass's pixel where the image's top left texel goes.
@group(0) @binding(1) var<uniform> origin: vec4<f32>;

// One triangle covering the viewport.
@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let corner = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    return vec4<f32>(corner.x * 2.0 - 1.0, 1.0 - corner.y * 2.0, 0.0, 1.0);
}

@fragment
fn fs_main(@builtin(position) pixel: vec4<f32>) -> @location(0) vec4<f32> {
    let last = vec2<i32>(textureDimensions(image)) - vec2<i32>(1);
    let texel = clamp(vec2<i32>(floor(pixel.xy - origin.xy)), vec2<i32>(0), last);
    return vec4<f32>(textureLoad(image, texel, 0).rgb, 1.0);
}
";

/// A head image as [`Blit::draw`] binds it, with where it goes.
pub struct BlitImage {
    bind_group: wgpu::BindGroup,
    origin: wgpu::Buffer,
}

/// The pipeline that copies head images into passes of one colour format.
pub struct Blit {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    /// Whether the passes' format is sRGB (the image is then read decoded, and encoded again on
    /// write); otherwise its stored bytes are copied.
    srgb: bool,
}

impl Blit {
    /// A pipeline for passes whose colour attachment is `format`, single-sampled, without depth.
    pub fn new(device: &wgpu::Device, format: wgpu::TextureFormat) -> Self {
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("lipcall head blit shader"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("lipcall head blit bind group layout"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("lipcall head blit pipeline layout"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("lipcall head blit pipeline"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &shader,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            fragment: Some(wgpu::FragmentState {
                module: &shader,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            multiview_mask: None,
            cache: None,
        });
        Self {
            pipeline,
            layout,
            srgb: format.is_srgb(),
        }
    }

    /// What [`Self::draw`] binds to show `target`'s image (made again when the target is).
    pub fn image(&self, device: &wgpu::Device, target: &HeadTarget) -> BlitImage {
        let view = target.texture().create_view(&wgpu::TextureViewDescriptor {
            label: Some("lipcall head blit view"),
            format: Some(if self.srgb {
                TARGET_FORMAT
            } else {
                TARGET_VIEW_UNORM
            }),
            ..Default::default()
        });
        let origin = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lipcall head blit origin"),
            size: 16,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("lipcall head blit bind group"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&view),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: origin.as_entire_binding(),
                },
            ],
        });
        BlitImage { bind_group, origin }
    }

    /// Puts `image`'s top left texel at pixel `origin` of the passes it is drawn into (before
    /// the pass is recorded).
    pub fn place(&self, queue: &wgpu::Queue, image: &BlitImage, origin: [i32; 2]) {
        let origin = [origin[0] as f32, origin[1] as f32, 0.0, 0.0];
        queue.write_buffer(&image.origin, 0, bytemuck::cast_slice(&origin));
    }

    /// Draws `image` where [`Self::place`] put it, over (only) `pass`'s viewport: the image's
    /// rectangle, or its part within the pass.
    pub fn draw(&self, pass: &mut wgpu::RenderPass<'_>, image: &BlitImage) {
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &image.bind_group, &[]);
        pass.draw(0..3, 0..1);
    }
}
