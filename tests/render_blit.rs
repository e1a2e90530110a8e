//! The blit that puts a rendered head into the window's pass (the app's tiles): pixel for pixel,
//! opaque, also when the tile is cut at the window's edge. Runs on whatever adapter wgpu finds
//! (lavapipe on CI); when there is none it fails under CI and skips, saying why, elsewhere.

mod common;

use lipcall::render::blit::Blit;
use lipcall::render::offscreen::GpuContext;
use lipcall::render::renderer::{DEPTH_FORMAT, HeadRenderer};
use lipcall::render::target::{HeadTarget, TARGET_FORMAT};
use lipcall::render::{Camera, Framing};
use lipcall::vocab::{FacePose, VisemeWeights};

const WINDOW: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// Reads a 4-byte-per-pixel texture back, rows unpadded.
fn read(ctx: &GpuContext, texture: &wgpu::Texture) -> Vec<[u8; 4]> {
    let (w, h) = (texture.width(), texture.height());
    let row =
        (w * 4).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("test readback"),
        size: u64::from(row * h),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    encoder.copy_texture_to_buffer(
        texture.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(row),
                rows_per_image: Some(h),
            },
        },
        texture.size(),
    );
    ctx.queue.submit([encoder.finish()]);
    buffer.map_async(wgpu::MapMode::Read, .., |r| r.expect("buffer maps"));
    ctx.device
        .poll(wgpu::PollType::wait_indefinitely())
        .unwrap();
    let bytes = buffer.get_mapped_range(..).expect("mapped").to_vec();
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let at = (y * row + x * 4) as usize;
            [bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]
        })
        .collect()
}

#[test]
fn a_head_is_copied_into_the_window_pixel_for_pixel_and_cut_at_its_edge() {
    let Some(ctx) = common::gpu() else { return };
    let device = &ctx.device;
    let (w, h) = (64u32, 48u32);
    let renderer = HeadRenderer::new(device, TARGET_FORMAT, Some(DEPTH_FORMAT));
    let model = lipcall::render::default_head().unwrap();
    let head = renderer
        .upload(device, &ctx.queue, &model, "test head")
        .unwrap();
    let mut instance = renderer.new_instance(device, head.clone(), "test head");
    let camera = Camera::framing(head.face_frame(), Framing::Face);
    let weights = VisemeWeights::single("aa").unwrap();
    renderer.prepare(
        &ctx.queue,
        &mut instance,
        &camera,
        w as f32 / h as f32,
        &weights,
        &FacePose::REST,
    );
    let target = HeadTarget::new(device, w, h, 1, "test tile");
    let mut encoder = device.create_command_encoder(&Default::default());
    {
        let mut pass = target.begin_pass(&mut encoder, [0.02, 0.3, 0.02]);
        renderer.paint(&mut pass, &instance);
    }
    ctx.queue.submit([encoder.finish()]);
    let head_pixels = read(&ctx, target.texture());

    // A "window" of 100 x 80 with two copies: one whole at (20, 10), one at (-10, 50), cut by
    // the left and bottom edges (the viewport egui gives a callback is cut alike).
    let window = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("test window"),
        size: wgpu::Extent3d {
            width: 100,
            height: 80,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: WINDOW,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    });
    let view = window.create_view(&Default::default());
    let blit = Blit::new(device, WINDOW);
    let whole = blit.image(device, &target);
    let cut = blit.image(device, &target);
    blit.place(&ctx.queue, &whole, [20, 10], [20, 10, w as i32, h as i32]);
    blit.place(&ctx.queue, &cut, [-10, 50], [0, 50, w as i32 - 10, 30]);
    let mut encoder = device.create_command_encoder(&Default::default());
    {
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("test window pass"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_viewport(20.0, 10.0, w as f32, h as f32, 0.0, 1.0);
        blit.draw(&mut pass, &whole);
        pass.set_viewport(0.0, 50.0, (w - 10) as f32, 30.0, 0.0, 1.0);
        blit.draw(&mut pass, &cut);
    }
    ctx.queue.submit([encoder.finish()]);
    let shown = read(&ctx, &window);

    let head_at = |x: i32, y: i32| head_pixels[(y as u32 * w + x as u32) as usize];
    let mut face = 0;
    for y in 0..80i32 {
        for x in 0..100i32 {
            let got = shown[(y * 100 + x) as usize];
            let in_whole = (20..20 + w as i32).contains(&x) && (10..10 + h as i32).contains(&y);
            let in_cut = x < w as i32 - 10 && y >= 50;
            let want = if in_cut {
                head_at(x + 10, y - 50)
            } else if in_whole {
                head_at(x - 20, y - 10)
            } else {
                [0, 0, 0, 255]
            };
            assert_eq!(got, want, "pixel ({x}, {y})");
            face += usize::from(in_whole && want[1] < want[0]);
        }
    }
    assert!(face > 200, "the head shows ({face} skin pixels)");
}
