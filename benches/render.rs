//! Head renderer benchmarks on whatever adapter wgpu finds (lavapipe when there is no GPU):
//! - `head_frame_cpu`: CPU time per head per frame, weights upload + draw encoding;
//! - `offscreen_frame/N`: a whole 480x480 offscreen frame with N heads (1, 4, 16), GPU included;
//!   frames per second = 1 / time;
//! - `app_tiles/8_full`, `app_tiles/8_detail`: eight heads each rendered into its own 249x192
//!   target (the app's tiles with eight peers in its 1280x720 window), as the full mesh and at the
//!   level of detail that size picks; `app_tiles/8_detail_lit_per_vertex` as the app draws them
//!   on a software adapter.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use lipcall::render::lod::DetailLevels;
use lipcall::render::offscreen::{FrameOptions, GpuContext, OffscreenRenderer};
use lipcall::render::renderer::{DEPTH_FORMAT, HeadRenderer, Shading};
use lipcall::render::target::HeadTarget;
use lipcall::render::{Camera, Framing};
use lipcall::vocab::FacePose;
use lipcall::vocab::VisemeWeights;

/// Weights over the shipped network's five visemes (PP FF aa I U), all in use as in speech.
fn weights_at(i: usize) -> VisemeWeights {
    let t = (i % 50) as f32 / 50.0 * std::f32::consts::TAU;
    let raw = [0.0, 1.0, 2.0, 3.0, 4.0].map(|k: f32| (1.0 + (t + k * 1.3).sin()).powi(2) + 0.05);
    let sum: f32 = raw.iter().sum();
    let names = ["PP", "FF", "aa", "I", "U"];
    VisemeWeights::from_named(names.into_iter().zip(raw.map(|r| r / sum))).unwrap_or_default()
}

fn bench(c: &mut Criterion) {
    let ctx = match GpuContext::new_headless() {
        Ok(ctx) => ctx,
        Err(e) => {
            eprintln!("SKIPPED: no GPU adapter: {e}");
            return;
        }
    };
    eprintln!("adapter: {}", ctx.adapter_description());
    let model = lipcall::render::default_head().expect("bundled head");

    {
        let device = &ctx.device;
        let format = lipcall::render::target::TARGET_FORMAT;
        let renderer = HeadRenderer::new(device, format, Some(DEPTH_FORMAT));
        let head = renderer
            .upload(device, &ctx.queue, &model, "bench head")
            .unwrap();
        let mut instance = renderer.new_instance(device, head.clone(), "bench instance");
        let camera = Camera::framing(head.face_frame(), Framing::Face);
        let size = wgpu::Extent3d {
            width: 64,
            height: 64,
            depth_or_array_layers: 1,
        };
        let target = |format, label| {
            device
                .create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size,
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
                    view_formats: &[],
                })
                .create_view(&Default::default())
        };
        let color = target(format, "bench colour");
        let depth = target(DEPTH_FORMAT, "bench depth");
        let mut i = 0usize;
        c.bench_function("head_frame_cpu (weights upload + draw encoding)", |b| {
            b.iter(|| {
                i += 1;
                renderer.prepare(
                    &ctx.queue,
                    &mut instance,
                    &camera,
                    1.0,
                    &weights_at(i),
                    &FacePose::REST,
                );
                let mut encoder = device.create_command_encoder(&Default::default());
                {
                    let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                        label: Some("bench pass"),
                        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                            view: &color,
                            depth_slice: None,
                            resolve_target: None,
                            ops: wgpu::Operations::default(),
                        })],
                        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                            view: &depth,
                            depth_ops: Some(wgpu::Operations::default()),
                            stencil_ops: None,
                        }),
                        timestamp_writes: None,
                        occlusion_query_set: None,
                        multiview_mask: None,
                    });
                    renderer.paint(&mut pass, &instance);
                }
                black_box(encoder.finish());
                // Flush the staged weight write so staging memory does not pile up.
                if i.is_multiple_of(64) {
                    ctx.queue.submit([]);
                    let _ = device.poll(wgpu::PollType::wait_indefinitely());
                }
            })
        });
    }

    let mut group = c.benchmark_group("offscreen_frame");
    group.sample_size(10);
    group.measurement_time(std::time::Duration::from_secs(8));
    for heads in [1usize, 4, 16] {
        let options = FrameOptions {
            width: 480,
            height: 480,
            ..Default::default()
        };
        let mut offscreen = OffscreenRenderer::with_heads(&ctx, &model, options, heads).unwrap();
        let mut i = 0usize;
        group.bench_function(format!("{heads}_heads"), |b| {
            b.iter(|| {
                i += 1;
                let weights: Vec<VisemeWeights> =
                    (0..heads).map(|h| weights_at(i + 7 * h)).collect();
                let index = offscreen.draw(&ctx, &weights);
                ctx.device
                    .poll(wgpu::PollType::Wait {
                        submission_index: Some(index),
                        timeout: None,
                    })
                    .unwrap();
            })
        });
    }
    group.finish();
    app_tiles(c, &ctx, &model);
}

/// Eight talking heads as the app draws them: one target and one submission per tile.
fn app_tiles(c: &mut Criterion, ctx: &GpuContext, model: &lipcall::render::HeadModel) {
    const TILES: usize = 8;
    let (width, height) = (249, 192);
    let device = &ctx.device;
    let mut renderer = HeadRenderer::new(
        device,
        lipcall::render::target::TARGET_FORMAT,
        Some(DEPTH_FORMAT),
    );
    renderer.add_vertex_lighting(device);
    let levels = DetailLevels::build(model);
    let head = renderer
        .upload_with_levels(device, &ctx.queue, model, &levels, "bench head")
        .unwrap();
    let camera = Camera::framing(head.face_frame(), Framing::Face);
    let detail = head.level_for(camera.pixels_per_metre(height));
    let targets: Vec<HeadTarget> = (0..TILES)
        .map(|_| HeadTarget::new(device, width, height, 1, "bench tile"))
        .collect();
    let mut instances: Vec<_> = (0..TILES)
        .map(|t| renderer.new_instance(device, head.clone(), &format!("bench tile {t}")))
        .collect();
    let mut group = c.benchmark_group("app_tiles");
    group.sample_size(10);
    group.measurement_time(std::time::Duration::from_secs(8));
    // `every_triangle`: the same level with the triangles no frontal camera sees drawn too
    // (render::facing), the reference for leaving them out.
    for (name, level, leave_out_unseen, shading) in [
        ("full", 0, true, Shading::PerPixel),
        ("detail", detail, true, Shading::PerPixel),
        ("detail_every_triangle", detail, false, Shading::PerPixel),
        ("detail_lit_per_vertex", detail, true, Shading::PerVertex),
    ] {
        for instance in &mut instances {
            instance.leave_out_unseen = leave_out_unseen;
            instance.shading = shading;
        }
        eprintln!(
            "{name}: level {level}, {} triangles per head",
            head.triangle_count(level)
        );
        let mut i = 0usize;
        group.bench_function(format!("{TILES}_{name}"), |b| {
            b.iter(|| {
                i += 1;
                let mut last = None;
                for (t, (instance, target)) in instances.iter_mut().zip(&targets).enumerate() {
                    instance.level = level;
                    let aspect = width as f32 / height as f32;
                    let weights = weights_at(i + 7 * t);
                    renderer.prepare(
                        &ctx.queue,
                        instance,
                        &camera,
                        aspect,
                        &weights,
                        &FacePose::REST,
                    );
                    let mut encoder = device.create_command_encoder(&Default::default());
                    {
                        let mut pass = target.begin_pass(&mut encoder, [0.02; 3]);
                        renderer.paint(&mut pass, instance);
                    }
                    last = Some(ctx.queue.submit([encoder.finish()]));
                }
                device
                    .poll(wgpu::PollType::Wait {
                        submission_index: last,
                        timeout: None,
                    })
                    .unwrap();
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
