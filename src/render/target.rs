//! Where heads are drawn when they are not drawn straight into someone else's pass: a colour and
//! depth target, multisampled on real GPUs, resolved into one sRGB texture that can be read back
//! (offscreen frames) or shown by egui (the app's tiles).

use super::renderer::DEPTH_FORMAT;

/// Colour format of head targets: sRGB, so the shader writes linear light and PNG bytes or egui
/// see display-ready values.
pub const TARGET_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;

/// The same bytes seen without sRGB decoding: egui samples textures as already gamma-encoded.
pub const TARGET_VIEW_UNORM: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// Whether `adapter` renders on the CPU (lavapipe, llvmpipe), where every pixel and vertex
/// costs frame rate.
pub fn is_software(adapter: &wgpu::Adapter) -> bool {
    adapter.get_info().device_type == wgpu::DeviceType::Cpu
}

/// Samples per pixel for heads on `adapter`: 4 on GPUs, 1 on software adapters, where 4x
/// multisampling costs more fragment work than the frame rate allows.
pub fn sample_count_for(adapter: &wgpu::Adapter) -> u32 {
    if is_software(adapter) {
        return 1;
    }
    let flags = |format| adapter.get_texture_format_features(format).flags;
    if flags(TARGET_FORMAT).sample_count_supported(4)
        && flags(DEPTH_FORMAT).sample_count_supported(4)
    {
        4
    } else {
        1
    }
}

/// A head-sized render target.
pub struct HeadTarget {
    width: u32,
    height: u32,
    samples: u32,
    /// The multisampled colour attachment, resolved into `resolved` (none at 1 sample).
    msaa_view: Option<wgpu::TextureView>,
    resolved: wgpu::Texture,
    resolved_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
}

impl HeadTarget {
    /// A target of `width` x `height` pixels at `samples` per pixel (1 or 4). The resolved texture
    /// can be sampled, copied from and viewed as [`TARGET_VIEW_UNORM`].
    pub fn new(device: &wgpu::Device, width: u32, height: u32, samples: u32, label: &str) -> Self {
        let size = wgpu::Extent3d {
            width: width.max(1),
            height: height.max(1),
            depth_or_array_layers: 1,
        };
        let texture = |format, sample_count, usage, view_formats: &[wgpu::TextureFormat], what| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(&format!("{label} {what}")),
                size,
                mip_level_count: 1,
                sample_count,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats,
            })
        };
        let resolved = texture(
            TARGET_FORMAT,
            1,
            wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
            &[TARGET_VIEW_UNORM],
            "colour",
        );
        let msaa_view = (samples > 1).then(|| {
            texture(
                TARGET_FORMAT,
                samples,
                wgpu::TextureUsages::RENDER_ATTACHMENT,
                &[],
                "multisampled colour",
            )
            .create_view(&Default::default())
        });
        let depth_view = texture(
            DEPTH_FORMAT,
            samples,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
            &[],
            "depth",
        )
        .create_view(&Default::default());
        Self {
            width: size.width,
            height: size.height,
            samples,
            msaa_view,
            resolved_view: resolved.create_view(&Default::default()),
            resolved,
            depth_view,
        }
    }

    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// The resolved image (sRGB).
    pub fn texture(&self) -> &wgpu::Texture {
        &self.resolved
    }

    /// A view of the resolved image whose samples are the stored (gamma-encoded) bytes, as egui
    /// expects of the textures it is given.
    pub fn unorm_view(&self) -> wgpu::TextureView {
        self.resolved.create_view(&wgpu::TextureViewDescriptor {
            format: Some(TARGET_VIEW_UNORM),
            ..Default::default()
        })
    }

    /// Begins a pass that clears to `background` (linear RGB) and resolves into the texture.
    pub fn begin_pass<'e>(
        &self,
        encoder: &'e mut wgpu::CommandEncoder,
        background: [f64; 3],
    ) -> wgpu::RenderPass<'e> {
        let [r, g, b] = background;
        let (view, resolve_target) = match &self.msaa_view {
            Some(msaa) => (msaa, Some(&self.resolved_view)),
            None => (&self.resolved_view, None),
        };
        encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("lipcall head pass"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color { r, g, b, a: 1.0 }),
                    // The multisampled image is only needed until it is resolved.
                    store: if self.msaa_view.is_some() {
                        wgpu::StoreOp::Discard
                    } else {
                        wgpu::StoreOp::Store
                    },
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        })
    }
}
