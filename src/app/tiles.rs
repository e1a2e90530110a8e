//! Head tiles: each peer's head is rendered into its own texture at the size the tile is shown,
//! only when what it shows changed (framing, size, or the face moved by a quarter of a pixel:
//! [`crate::render::renderer::UNSEEN_MOTION_PX`]), with the coarsest level of detail
//! that is exact to half a pixel at that size, and copied into egui's pass pixel for pixel by a
//! paint callback ([`Blit`]: opaque texel loads, which a software adapter does many times faster
//! than egui's filtered, blended image path). The head pass is thus independent of egui's:
//! multisampled on GPUs, sRGB-correct whatever format the window has, and free when a face is
//! still.

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use eframe::egui;
use eframe::egui_wgpu;

use crate::render::blit::{Blit, BlitImage};
use crate::render::lod::DetailLevels;
use crate::render::target::{HeadTarget, TARGET_FORMAT, is_software, sample_count_for};
use crate::render::{Camera, Framing, GpuHead, HeadInstance, HeadRenderer, HeadVariant};
use crate::vocab::FacePose;
use crate::vocab::VisemeWeights;

/// Render work of the head tiles, for the status report.
#[derive(Debug, Default)]
pub struct RenderCounters {
    /// CPU time spent encoding and submitting head renders.
    pub record_ns: AtomicU64,
    /// Head renders (a tile whose face did not change is shown again without one).
    pub tiles_drawn: AtomicU64,
    /// Tiles shown, rendered or not.
    pub tiles_shown: AtomicU64,
    /// Triangles of the head renders (fewer per render in small tiles: levels of detail).
    pub triangles_drawn: AtomicU64,
}

/// One head tile for one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct HeadTile {
    pub id: u64,
    pub framing: Framing,
    pub weights: VisemeWeights,
    pub pose: FacePose,
    /// Linear RGB behind the head (each peer's own).
    pub background: [f64; 3],
    /// The head's look (each peer's own).
    pub variant: HeadVariant,
}

struct Tile {
    instance: HeadInstance,
    target: HeadTarget,
    /// The target's image as the blit binds it.
    image: Arc<BlitImage>,
    /// What the texture shows now.
    shown: Option<(HeadTile, (u32, u32))>,
    seen_this_frame: bool,
}

/// The head renderer, the uploaded head and one render target per visible tile.
pub struct HeadTiles {
    state: egui_wgpu::RenderState,
    renderer: HeadRenderer,
    head: Arc<GpuHead>,
    blit: Arc<Blit>,
    samples: u32,
    tiles: HashMap<u64, Tile>,
    counters: Arc<RenderCounters>,
}

/// egui's paint callback for one tile: the blit of its image into `rect`.
struct TileImage {
    blit: Arc<Blit>,
    image: Arc<BlitImage>,
    rect: egui::Rect,
}

impl egui_wgpu::CallbackTrait for TileImage {
    fn prepare(
        &self,
        _device: &wgpu::Device,
        queue: &wgpu::Queue,
        screen: &egui_wgpu::ScreenDescriptor,
        _encoder: &mut wgpu::CommandEncoder,
        _resources: &mut egui_wgpu::CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        // Where egui puts the callback's viewport, before cutting it at the window's edges.
        let at = |points: f32| (points * screen.pixels_per_point).round() as i32;
        let origin = [at(self.rect.min.x), at(self.rect.min.y)];
        let viewport = egui::epaint::ViewportInPixels::from_points(
            &self.rect,
            screen.pixels_per_point,
            screen.size_in_pixels,
        );
        let viewport = [
            viewport.left_px,
            viewport.top_px,
            viewport.width_px,
            viewport.height_px,
        ];
        self.blit.place(queue, &self.image, origin, viewport);
        Vec::new()
    }

    fn paint(
        &self,
        _info: egui::PaintCallbackInfo,
        pass: &mut wgpu::RenderPass<'static>,
        _resources: &egui_wgpu::CallbackResources,
    ) {
        self.blit.draw(pass, &self.image);
    }
}

impl HeadTiles {
    /// Builds the renderer and uploads the default head.
    pub fn new(
        state: &egui_wgpu::RenderState,
        counters: Arc<RenderCounters>,
    ) -> anyhow::Result<Self> {
        HeadRenderer::check_adapter(&state.adapter)?;
        let samples = sample_count_for(&state.adapter);
        let mut renderer = HeadRenderer::with_samples(
            &state.device,
            TARGET_FORMAT,
            Some(crate::render::renderer::DEPTH_FORMAT),
            samples,
        );
        // A GPU lights every pixel for free; a software adapter pays per pixel, and small heads
        // look the same lit per vertex (tests/render_lod.rs).
        if is_software(&state.adapter) {
            renderer.add_vertex_lighting(&state.device);
        }
        let model = crate::render::default_head()?;
        let levels = DetailLevels::build(&model);
        let head = renderer.upload_with_levels(
            &state.device,
            &state.queue,
            &model,
            &levels,
            "default head",
        )?;
        Ok(Self {
            state: state.clone(),
            renderer,
            head,
            blit: Arc::new(Blit::new(&state.device, state.target_format)),
            samples,
            tiles: HashMap::new(),
            counters,
        })
    }

    /// Shows `tile` in `rect`, rendering it first if its face or size changed.
    pub fn show(&mut self, ui: &mut egui::Ui, rect: egui::Rect, tile: HeadTile) {
        let ppp = ui.ctx().pixels_per_point();
        let max = self.state.device.limits().max_texture_dimension_2d;
        let px = |points: f32| ((points * ppp).round() as u32).clamp(1, max);
        let size = (px(rect.width()), px(rect.height()));
        self.counters.tiles_shown.fetch_add(1, Ordering::Relaxed);
        let image = self.render_if_changed(tile, size);
        ui.painter().add(egui_wgpu::Callback::new_paint_callback(
            rect,
            TileImage {
                blit: self.blit.clone(),
                image,
                rect,
            },
        ));
    }

    /// Frees the targets of tiles not shown since the last call (peers that left).
    pub fn end_frame(&mut self) {
        self.tiles
            .retain(|_, t| std::mem::take(&mut t.seen_this_frame));
    }

    /// The tile's image, rendered first if its face or size changed.
    fn render_if_changed(&mut self, tile: HeadTile, size: (u32, u32)) -> Arc<BlitImage> {
        let Self {
            state,
            renderer,
            head,
            blit,
            samples,
            tiles,
            counters,
        } = self;
        let entry = tiles.entry(tile.id).or_insert_with(|| {
            let target = HeadTarget::new(&state.device, size.0, size.1, *samples, "head tile");
            Tile {
                instance: renderer.new_instance(
                    &state.device,
                    head.clone(),
                    &format!("tile {}", tile.id),
                ),
                image: Arc::new(blit.image(&state.device, &target)),
                target,
                shown: None,
                seen_this_frame: false,
            }
        });
        entry.seen_this_frame = true;
        if entry.target.size() != size {
            entry.target = HeadTarget::new(&state.device, size.0, size.1, *samples, "head tile");
            entry.image = Arc::new(blit.image(&state.device, &entry.target));
            entry.shown = None;
        }
        let camera = Camera::framing(head.face_frame(), tile.framing);
        let pixels_per_metre = camera.pixels_per_metre(size.1);
        // Shown again while the face has moved less than a fraction of a pixel since it was
        // drawn (a listener's drifting head, a settled mouth).
        if entry.shown.as_ref().is_some_and(|(shown, at)| {
            *at == size
                && shown.framing == tile.framing
                && shown.background == tile.background
                && shown.variant == tile.variant
                && head.looks_the_same(
                    (&shown.weights, &shown.pose),
                    (&tile.weights, &tile.pose),
                    pixels_per_metre,
                )
        }) {
            return entry.image.clone();
        }
        let t0 = Instant::now();
        let aspect = size.0 as f32 / size.1 as f32;
        entry.instance.level = head.level_for(pixels_per_metre);
        entry.instance.shading = head.shading_for(pixels_per_metre);
        entry.instance.variant = tile.variant;
        renderer.prepare(
            &state.queue,
            &mut entry.instance,
            &camera,
            aspect,
            &tile.weights,
            &tile.pose,
        );
        let mut encoder = state
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("lipcall head tile"),
            });
        {
            let mut pass = entry.target.begin_pass(&mut encoder, tile.background);
            renderer.paint(&mut pass, &entry.instance);
        }
        state.queue.submit([encoder.finish()]);
        entry.shown = Some((tile, size));
        counters.tiles_drawn.fetch_add(1, Ordering::Relaxed);
        counters
            .triangles_drawn
            .fetch_add(entry.instance.triangles_drawn() as u64, Ordering::Relaxed);
        counters
            .record_ns
            .fetch_add(t0.elapsed().as_nanos() as u64, Ordering::Relaxed);
        entry.image.clone()
    }
}
