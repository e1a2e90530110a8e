//! Head tiles: the head renderer lives in egui-wgpu's callback resources; each tile is a paint
//! callback that writes its weights in `prepare` and draws in `paint` (egui's pass has a depth
//! buffer, see `run`).

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use eframe::egui;
use eframe::egui_wgpu::{self, CallbackResources, CallbackTrait};

use crate::render::{Camera, Framing, GpuHead, HeadInstance, HeadRenderer, VisemeWeights};

/// Depth format the app asks eframe for (`NativeOptions::depth_buffer = 32`).
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// GPU time spent writing tile uniforms and recording draws, for the CPU report.
#[derive(Debug, Default)]
pub struct RenderCounters {
    pub record_ns: AtomicU64,
    pub tiles_drawn: AtomicU64,
}

pub struct TileResources {
    renderer: HeadRenderer,
    head: Arc<GpuHead>,
    instances: HashMap<u64, HeadInstance>,
    counters: Arc<RenderCounters>,
}

/// Builds the renderer and uploads the default head into egui-wgpu's callback resources.
pub fn install(
    state: &egui_wgpu::RenderState,
    counters: Arc<RenderCounters>,
) -> anyhow::Result<()> {
    HeadRenderer::check_adapter(&state.adapter)?;
    let renderer = HeadRenderer::new(&state.device, state.target_format, Some(DEPTH_FORMAT));
    let model = crate::render::default_head()?;
    let head = renderer.upload(&state.device, &state.queue, &model, "default head")?;
    state
        .renderer
        .write()
        .callback_resources
        .insert(TileResources {
            renderer,
            head,
            instances: HashMap::new(),
            counters,
        });
    Ok(())
}

/// One head tile for one frame.
pub struct HeadTile {
    pub id: u64,
    pub framing: Framing,
    pub aspect: f32,
    pub weights: VisemeWeights,
}

impl CallbackTrait for HeadTile {
    fn prepare(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        _screen: &egui_wgpu::ScreenDescriptor,
        _encoder: &mut wgpu::CommandEncoder,
        resources: &mut CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        let Some(res) = resources.get_mut::<TileResources>() else {
            return Vec::new();
        };
        let t0 = Instant::now();
        let TileResources {
            renderer,
            head,
            instances,
            counters,
        } = res;
        let instance = instances.entry(self.id).or_insert_with(|| {
            renderer.new_instance(device, head.clone(), &format!("tile {}", self.id))
        });
        let camera = Camera::framing(head.face_frame(), self.framing);
        renderer.prepare(
            queue,
            instance,
            &camera,
            self.aspect,
            &self.weights,
            &crate::render::head::FacePose::REST,
        );
        counters
            .record_ns
            .fetch_add(t0.elapsed().as_nanos() as u64, Ordering::Relaxed);
        Vec::new()
    }

    fn paint(
        &self,
        _info: egui::PaintCallbackInfo,
        pass: &mut wgpu::RenderPass<'static>,
        resources: &CallbackResources,
    ) {
        let Some(res) = resources.get::<TileResources>() else {
            return;
        };
        let t0 = Instant::now();
        if let Some(instance) = res.instances.get(&self.id) {
            res.renderer.paint(pass, instance);
            res.counters.tiles_drawn.fetch_add(1, Ordering::Relaxed);
        }
        res.counters
            .record_ns
            .fetch_add(t0.elapsed().as_nanos() as u64, Ordering::Relaxed);
    }
}

/// Paints a head into `rect` (a no-op where there is no wgpu renderer, as in UI tests).
pub fn head_ui(ui: &mut egui::Ui, rect: egui::Rect, tile: HeadTile) {
    ui.painter()
        .add(egui_wgpu::Callback::new_paint_callback(rect, tile));
}
