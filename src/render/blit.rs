//! Puts a rendered head ([`HeadTarget`]) into someone else's render pass (the window's, egui's)
//! pixel for pixel: a rectangle over the pass's viewport (which may be cut at the window's edge)
//! whose fragments each take the nearest texel at their offset from the image's corner. The
//! image is opaque, and is copied as it is stored.
//! egui's own path for images (filtered sampling, vertex colour, blending) costs a software
//! adapter tens of nanoseconds a pixel, most of a frame when the tiles fill the window. Drawn as
//! a rectangle of two triangles with a plain texture read, the blits of eight still heads cost
//! llvmpipe half what one large triangle whose fragments looked their texel up from the pixel
//! position did (about 2 of 4 ms a frame).

use super::target::{HeadTarget, TARGET_FORMAT, TARGET_VIEW_UNORM};

const SHADER: &str = r"
@group(0) @binding(0) var image: texture_2d<f32>;
@group(0) @binding(1) var texel: sampler;
// xy: the image coordinates at the viewport's top left corner, zw: their change across it.
@group(0) @binding(2) var<uniform> span: vec4<f32>;

struct Corner {
    @builtin(position) position: vec4<f32>,
    @location(0) uv: vec2<f32>,
}

// Two triangles covering the viewport: a rectangle, cheaper for llvmpipe than one triangle cut
// to the viewport.
@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> Corner {
    let corner = vec2<f32>(f32((0x32u >> i) & 1u), f32((0x2cu >> i) & 1u));
    var out: Corner;
    out.position = vec4<f32>(corner.x * 2.0 - 1.0, 1.0 - corner.y * 2.0, 0.0, 1.0);
    out.uv = span.xy + corner * span.zw;
    return out;
}

@fragment
fn fs_main(at: Corner) -> @location(0) vec4<f32> {
    return textureSample(image, texel, at.uv);
}
";

/// A head image as [`Blit::draw`] binds it, with where it goes.
pub struct BlitImage {
    bind_group: wgpu::BindGroup,
    span: wgpu::Buffer,
    /// The image's width and height in texels.
    size: [f32; 2],
}

/// The pipeline that copies head images into passes of one colour format.
pub struct Blit {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    /// Nearest texel, clamped at the image's edges.
    sampler: wgpu::Sampler,
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
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::NonFiltering),
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::VERTEX,
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
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("lipcall head blit sampler"),
            ..Default::default()
        });
        Self {
            pipeline,
            layout,
            sampler,
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
        let span = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lipcall head blit span"),
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
                    resource: wgpu::BindingResource::Sampler(&self.sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: span.as_entire_binding(),
                },
            ],
        });
        let size = target.texture().size();
        BlitImage {
            bind_group,
            span,
            size: [size.width as f32, size.height as f32],
        }
    }

    /// Puts `image`'s top left texel at pixel `origin` of the passes it is drawn into, whose
    /// viewport is `viewport` (x, y, width, height in pixels), before the pass is recorded.
    pub fn place(
        &self,
        queue: &wgpu::Queue,
        image: &BlitImage,
        origin: [i32; 2],
        viewport: [i32; 4],
    ) {
        let [w, h] = image.size;
        let span = [
            (viewport[0] - origin[0]) as f32 / w,
            (viewport[1] - origin[1]) as f32 / h,
            viewport[2] as f32 / w,
            viewport[3] as f32 / h,
        ];
        queue.write_buffer(&image.span, 0, bytemuck::cast_slice(&span));
    }

    /// Draws `image` where [`Self::place`] put it, over (only) `pass`'s viewport: the image's
    /// rectangle, or its part within the pass.
    pub fn draw(&self, pass: &mut wgpu::RenderPass<'_>, image: &BlitImage) {
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &image.bind_group, &[]);
        pass.draw(0..6, 0..1);
    }
}
