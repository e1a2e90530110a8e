//! Rendering without a window: a headless device (software adapter when there is no GPU),
//! an offscreen colour + depth target, PNG frames for `lipcall animate --frames DIR`.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::RenderError;
use super::camera::{Camera, Framing};
use super::head::HeadModel;
use super::lod::DetailLevels;
use super::readback::read_buffer;
use super::renderer::{DEPTH_FORMAT, GpuHead, HeadInstance, HeadRenderer, Shading};
use super::target::{HeadTarget, TARGET_FORMAT, sample_count_for};
use super::variant::HeadVariant;
use crate::vocab::{FacePose, VISEME_COUNT, Viseme, VisemeWeights};

/// A device and queue made without a window.
pub struct GpuContext {
    pub instance: wgpu::Instance,
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
}

impl GpuContext {
    /// Picks an adapter that can run the head renderer: a real GPU if one qualifies, otherwise the
    /// software one (lavapipe / llvmpipe). `WGPU_BACKEND` (vulkan, gl, ...) restricts the search.
    pub fn new_headless() -> Result<Self, RenderError> {
        // Vulkan first; GL (whose EGL probing is noisy without a display) only if needed.
        let choices = match wgpu::Backends::from_env() {
            Some(b) => vec![b],
            None => vec![wgpu::Backends::VULKAN, wgpu::Backends::GL],
        };
        let mut last_err = None;
        for backends in choices {
            match Self::with_backends(backends) {
                Ok(ctx) => return Ok(ctx),
                Err(e) => last_err = Some(e),
            }
        }
        Err(last_err.unwrap_or_else(|| RenderError::NoAdapter("no backends".into())))
    }

    /// Like [`Self::new_headless`] restricted to `backends`.
    pub fn with_backends(backends: wgpu::Backends) -> Result<Self, RenderError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = backends;
        let instance = wgpu::Instance::new(desc);
        let adapters = pollster::block_on(instance.enumerate_adapters(backends));
        let mut reasons = Vec::new();
        let mut ranked: Vec<wgpu::Adapter> = Vec::new();
        for adapter in adapters {
            match HeadRenderer::check_adapter(&adapter) {
                Ok(()) => ranked.push(adapter),
                Err(e) => reasons.push(e.to_string()),
            }
        }
        // Hardware first, then the CPU (software) adapters, Vulkan before GL.
        ranked.sort_by_key(|a| {
            let info = a.get_info();
            let kind = match info.device_type {
                wgpu::DeviceType::DiscreteGpu => 0,
                wgpu::DeviceType::IntegratedGpu => 1,
                wgpu::DeviceType::VirtualGpu => 2,
                wgpu::DeviceType::Cpu => 3,
                wgpu::DeviceType::Other => 4,
            };
            (kind, info.backend != wgpu::Backend::Vulkan)
        });
        let adapter = ranked.into_iter().next().ok_or_else(|| {
            RenderError::NoAdapter(if reasons.is_empty() {
                "no adapters found (install mesa-vulkan-drivers for a software one)".to_owned()
            } else {
                reasons.join("; ")
            })
        })?;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("lipcall headless device"),
            required_features: wgpu::Features::empty(),
            required_limits: HeadRenderer::required_limits().using_resolution(adapter.limits()),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| RenderError::Device(e.to_string()))?;
        Ok(Self {
            instance,
            adapter,
            device,
            queue,
        })
    }

    /// Adapter name and backend, e.g. "llvmpipe (LLVM 15.0.6, 256 bits) on Vulkan".
    pub fn adapter_description(&self) -> String {
        let info = self.adapter.get_info();
        format!("{} on {:?}", info.name, info.backend)
    }
}

/// Size and view of offscreen frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameOptions {
    pub width: u32,
    pub height: u32,
    /// Output frame rate: 25 or 50 (weights come at 50 per second, one per 20 ms frame).
    pub fps: u32,
    pub framing: Framing,
    /// Background colour, linear RGB.
    pub background: [f64; 3],
}

impl Default for FrameOptions {
    fn default() -> Self {
        Self {
            width: 480,
            height: 480,
            fps: 25,
            framing: Framing::Face,
            background: [0.06, 0.07, 0.09],
        }
    }
}

/// A colour + depth target with a readback buffer, and one head drawn into it.
pub struct OffscreenRenderer {
    renderer: HeadRenderer,
    head: Arc<GpuHead>,
    instances: Vec<HeadInstance>,
    target: HeadTarget,
    readback: wgpu::Buffer,
    padded_row: u32,
    options: FrameOptions,
    pub camera: Camera,
}

impl OffscreenRenderer {
    /// Uploads `model` and builds a target of `options.width` x `options.height`.
    pub fn new(
        ctx: &GpuContext,
        model: &HeadModel,
        options: FrameOptions,
    ) -> Result<Self, RenderError> {
        Self::with_heads(ctx, model, options, 1)
    }

    /// Like [`Self::new`] with `count` instances of the head, drawn side by side in a grid
    /// (used by the benchmarks).
    pub fn with_heads(
        ctx: &GpuContext,
        model: &HeadModel,
        options: FrameOptions,
        count: usize,
    ) -> Result<Self, RenderError> {
        Self::with_levels(ctx, model, &DetailLevels::full(model), options, count)
    }

    /// Like [`Self::with_heads`] with the head's levels of detail `levels` (built from
    /// `model`); the full mesh is drawn until [`Self::set_level`] says otherwise.
    pub fn with_levels(
        ctx: &GpuContext,
        model: &HeadModel,
        levels: &DetailLevels,
        options: FrameOptions,
        count: usize,
    ) -> Result<Self, RenderError> {
        let max = ctx.device.limits().max_texture_dimension_2d;
        if options.width == 0 || options.height == 0 || options.width > max || options.height > max
        {
            return Err(RenderError::Options(format!(
                "frame size {}x{} outside 1..={max}",
                options.width, options.height
            )));
        }
        let device = &ctx.device;
        let samples = sample_count_for(&ctx.adapter);
        let renderer =
            HeadRenderer::with_samples(device, TARGET_FORMAT, Some(DEPTH_FORMAT), samples);
        let head =
            renderer.upload_with_levels(device, &ctx.queue, model, levels, "lipcall head")?;
        let instances = (0..count.max(1))
            .map(|i| {
                renderer.new_instance(device, head.clone(), &format!("lipcall head instance {i}"))
            })
            .collect();
        let target = HeadTarget::new(
            device,
            options.width,
            options.height,
            samples,
            "lipcall offscreen",
        );
        let padded_row = (options.width * 4).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
            * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lipcall offscreen readback"),
            size: padded_row as u64 * options.height as u64,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let camera = Camera::framing(head.face_frame(), options.framing);
        Ok(Self {
            target,
            renderer,
            head,
            instances,
            readback,
            padded_row,
            options,
            camera,
        })
    }

    pub fn options(&self) -> &FrameOptions {
        &self.options
    }

    pub fn head(&self) -> &Arc<GpuHead> {
        &self.head
    }

    /// Draws every head at level of detail `level` from the next frame on.
    pub fn set_level(&mut self, level: usize) {
        for instance in &mut self.instances {
            instance.level = level;
        }
    }

    /// Whether to leave out the triangles a frontal camera cannot see, where the camera and
    /// pose allow ([`crate::render::facing`]; on by default).
    pub fn set_leave_out_unseen(&mut self, on: bool) {
        for instance in &mut self.instances {
            instance.leave_out_unseen = on;
        }
    }

    /// Draws every head as `variant` from the next frame on.
    pub fn set_variant(&mut self, variant: HeadVariant) {
        for instance in &mut self.instances {
            instance.variant = variant;
        }
    }

    /// Triangles the first head's last frame drew (before culling).
    pub fn triangles_drawn(&self) -> usize {
        self.instances[0].triangles_drawn()
    }

    /// Lights every head per vertex or per pixel from the next frame on.
    pub fn set_shading(&mut self, device: &wgpu::Device, shading: Shading) {
        if shading == Shading::PerVertex {
            self.renderer.add_vertex_lighting(device);
        }
        for instance in &mut self.instances {
            instance.shading = shading;
        }
    }

    /// Encodes and submits one frame, head `i` with `weights[i]` (the last entry for heads beyond
    /// the slice), the eyes and head at rest; no readback.
    pub fn draw(&mut self, ctx: &GpuContext, weights: &[VisemeWeights]) -> wgpu::SubmissionIndex {
        self.draw_posed(ctx, weights, &[])
    }

    /// [`Self::draw`] with head `i` in `poses[i]` (the last entry beyond the slice; at rest
    /// when it is empty).
    pub fn draw_posed(
        &mut self,
        ctx: &GpuContext,
        weights: &[VisemeWeights],
        poses: &[FacePose],
    ) -> wgpu::SubmissionIndex {
        let n = self.instances.len();
        let cols = (n as f32).sqrt().ceil() as u32;
        let rows = (n as u32).div_ceil(cols);
        let (tw, th) = (self.options.width / cols, self.options.height / rows);
        let aspect = tw.max(1) as f32 / th.max(1) as f32;
        let neutral = VisemeWeights::neutral();
        for (i, instance) in self.instances.iter_mut().enumerate() {
            let w = weights.get(i).or(weights.last()).unwrap_or(&neutral);
            let pose = poses.get(i).or(poses.last()).unwrap_or(&FacePose::REST);
            self.renderer
                .prepare(&ctx.queue, instance, &self.camera, aspect, w, pose);
        }
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("lipcall offscreen frame encoder"),
            });
        {
            let mut pass = self
                .target
                .begin_pass(&mut encoder, self.options.background);
            for (i, instance) in self.instances.iter().enumerate() {
                let (c, r) = (i as u32 % cols, i as u32 / cols);
                pass.set_viewport(
                    (c * tw) as f32,
                    (r * th) as f32,
                    tw as f32,
                    th as f32,
                    0.0,
                    1.0,
                );
                self.renderer.paint(&mut pass, instance);
            }
        }
        ctx.queue.submit([encoder.finish()])
    }

    /// Renders one frame, eyes and head at rest, and reads it back as RGBA8 (sRGB).
    pub fn render(
        &mut self,
        ctx: &GpuContext,
        weights: &VisemeWeights,
    ) -> Result<image::RgbaImage, RenderError> {
        self.render_posed(ctx, weights, &FacePose::REST)
    }

    /// Renders one frame with the face in `pose` and reads it back as RGBA8 (sRGB).
    pub fn render_posed(
        &mut self,
        ctx: &GpuContext,
        weights: &VisemeWeights,
        pose: &FacePose,
    ) -> Result<image::RgbaImage, RenderError> {
        self.draw_posed(
            ctx,
            std::slice::from_ref(weights),
            std::slice::from_ref(pose),
        );
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("lipcall offscreen readback encoder"),
            });
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: self.target.texture(),
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &self.readback,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(self.padded_row),
                    rows_per_image: Some(self.options.height),
                },
            },
            self.target.texture().size(),
        );
        ctx.queue.submit([encoder.finish()]);
        let bytes = read_buffer(&ctx.device, &self.readback)?;
        let (w, h) = (self.options.width as usize, self.options.height as usize);
        let mut pixels = Vec::with_capacity(w * h * 4);
        for row in 0..h {
            let start = row * self.padded_row as usize;
            pixels.extend_from_slice(&bytes[start..start + w * 4]);
        }
        image::RgbaImage::from_raw(w as u32, h as u32, pixels)
            .ok_or_else(|| RenderError::Readback("frame size mismatch".into()))
    }

    /// The first head's blended vertices as the vertex shader computes them, read back from the
    /// GPU (model order, head space), for the weights and pose of the last frame drawn.
    pub fn blend_on_gpu(
        &self,
        ctx: &GpuContext,
    ) -> Result<Vec<super::head::MorphDelta>, RenderError> {
        self.renderer
            .blend_on_gpu(&ctx.device, &ctx.queue, &self.instances[0])
    }

    /// Direct access for callers that draw extra heads or change uniforms.
    pub fn renderer(&self) -> &HeadRenderer {
        &self.renderer
    }
}

/// Viseme weights and face poses over time: one row per 20 ms frame (or any increasing times).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WeightTrack {
    /// Start time of each row in seconds, increasing.
    pub times: Vec<f64>,
    pub weights: Vec<VisemeWeights>,
    /// The living face's pose of each row ([`FacePose::REST`] for rows pushed without one).
    pub poses: Vec<FacePose>,
}

impl WeightTrack {
    /// Rows of a possibly reduced viseme set: `names` are the columns (names from the 15),
    /// each row is (time_s, one weight per name).
    pub fn from_columns(names: &[&str], rows: &[(f64, Vec<f32>)]) -> Result<Self, RenderError> {
        let idx: Vec<usize> = names
            .iter()
            .map(|n| {
                Viseme::from_name(n)
                    .map(Viseme::index)
                    .ok_or_else(|| RenderError::UnknownViseme((*n).to_owned()))
            })
            .collect::<Result<_, _>>()?;
        let mut track = Self::default();
        for (t, values) in rows {
            if values.len() != idx.len() {
                return Err(RenderError::Options(format!(
                    "row at {t} s has {} weights for {} visemes",
                    values.len(),
                    idx.len()
                )));
            }
            let mut w = [0.0; VISEME_COUNT];
            for (&i, &v) in idx.iter().zip(values) {
                w[i] += v;
            }
            track.push(*t, VisemeWeights(w))?;
        }
        Ok(track)
    }

    /// Appends a row with the face at rest; times must increase.
    pub fn push(&mut self, time_s: f64, weights: VisemeWeights) -> Result<(), RenderError> {
        self.push_posed(time_s, weights, FacePose::REST)
    }

    /// Appends a row with its face pose; times must increase.
    pub fn push_posed(
        &mut self,
        time_s: f64,
        weights: VisemeWeights,
        pose: FacePose,
    ) -> Result<(), RenderError> {
        if !time_s.is_finite() || self.times.last().is_some_and(|&last| time_s <= last) {
            return Err(RenderError::Options(format!(
                "weight row time {time_s} is not increasing"
            )));
        }
        self.times.push(time_s);
        self.weights.push(weights);
        self.poses.push(pose);
        Ok(())
    }

    /// Gives the rows their poses, one per row, in order.
    pub fn set_poses(&mut self, poses: Vec<FacePose>) -> Result<(), RenderError> {
        if poses.len() != self.times.len() {
            return Err(RenderError::Options(format!(
                "{} poses for {} weight rows",
                poses.len(),
                self.times.len()
            )));
        }
        self.poses = poses;
        Ok(())
    }

    /// Duration covered: the last row's start plus one 20 ms frame.
    pub fn duration(&self) -> f64 {
        self.times.last().map_or(0.0, |t| t + 0.02)
    }

    /// Weights at time `t`, linearly interpolated between rows (convex stays convex).
    pub fn sample(&self, t: f64) -> VisemeWeights {
        match self.locate(t) {
            None => VisemeWeights::neutral(),
            Some((i, j, f)) => self.weights[i].lerp(&self.weights[j], f),
        }
    }

    /// The face pose at time `t`, sampled like the weights.
    pub fn sample_pose(&self, t: f64) -> FacePose {
        let pose = |k: usize| self.poses.get(k).copied().unwrap_or(FacePose::REST);
        match self.locate(t) {
            None => FacePose::REST,
            Some((i, j, f)) => pose(i).lerp(&pose(j), f),
        }
    }

    /// The rows around time `t` and the fraction of the way from the first to the second.
    fn locate(&self, t: f64) -> Option<(usize, usize, f32)> {
        let n = self.times.len();
        if n == 0 {
            return None;
        }
        let i = self.times.partition_point(|&x| x <= t);
        if i == 0 {
            return Some((0, 0, 0.0));
        }
        if i >= n {
            return Some((n - 1, n - 1, 0.0));
        }
        let (t0, t1) = (self.times[i - 1], self.times[i]);
        let f = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0) as f32;
        Some((i - 1, i, f))
    }
}

/// What [`render_frames`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct FramesSummary {
    pub frames: usize,
    pub fps: u32,
    pub dir: PathBuf,
    /// printf-style pattern of the file names, for ffmpeg: `frame_%06d.png`.
    pub pattern: String,
    pub adapter: String,
}

/// File name of frame `n` (0-based) in a frames directory.
pub fn frame_file_name(n: usize) -> String {
    format!("frame_{n:06}.png")
}

/// Renders `track` at `options.fps` into `dir/frame_000000.png`, `frame_000001.png`, ...
/// (creating `dir`); frame k shows the weights and pose at time k / fps. The mouth close-up
/// ([`Framing::Mouth`]) keeps the head still (the eyes still move), like the app's lipreading
/// view.
pub fn render_frames(
    model: &HeadModel,
    track: &WeightTrack,
    dir: &Path,
    options: &FrameOptions,
) -> Result<FramesSummary, RenderError> {
    if options.fps != 25 && options.fps != 50 {
        return Err(RenderError::Options(format!(
            "fps must be 25 or 50, not {}",
            options.fps
        )));
    }
    let ctx = GpuContext::new_headless()?;
    render_frames_with(&ctx, model, track, dir, options)
}

/// [`render_frames`] on a device the caller already has.
pub fn render_frames_with(
    ctx: &GpuContext,
    model: &HeadModel,
    track: &WeightTrack,
    dir: &Path,
    options: &FrameOptions,
) -> Result<FramesSummary, RenderError> {
    if options.fps == 0 {
        return Err(RenderError::Options("fps must be positive".into()));
    }
    std::fs::create_dir_all(dir).map_err(|source| RenderError::Io {
        path: dir.to_owned(),
        source,
    })?;
    let mut offscreen = OffscreenRenderer::new(ctx, model, *options)?;
    let count = (track.duration() * options.fps as f64).round() as usize;
    for k in 0..count {
        let t = k as f64 / options.fps as f64;
        let mut pose = track.sample_pose(t);
        if options.framing == Framing::Mouth {
            pose = pose.without_head_motion();
        }
        let image = offscreen.render_posed(ctx, &track.sample(t), &pose)?;
        let path = dir.join(frame_file_name(k));
        image.save(&path).map_err(|e| RenderError::Image {
            path: path.clone(),
            message: e.to_string(),
        })?;
    }
    Ok(FramesSummary {
        frames: count,
        fps: options.fps,
        dir: dir.to_owned(),
        pattern: "frame_%06d.png".into(),
        adapter: ctx.adapter_description(),
    })
}
