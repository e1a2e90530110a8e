//! Levels of detail of the default head: fewer triangles where the head is shown small, and the
//! same face a lipreader sees. GPU tests run on whatever adapter wgpu finds (lavapipe on CI);
//! when there is none they fail under CI and skip, saying why, elsewhere.

mod common;

use std::sync::OnceLock;

use common::{gpu, visibly_different};

use lipcall::render::head::HeadModel;
use lipcall::render::lod::{DetailLevels, MAX_ERROR_PX};
use lipcall::render::offscreen::{FrameOptions, GpuContext, OffscreenRenderer};
use lipcall::render::renderer::Shading;
use lipcall::render::{Camera, Framing};
use lipcall::vocab::{VISEME_NAMES, VisemeWeights};

fn default_head() -> &'static HeadModel {
    static HEAD: OnceLock<HeadModel> = OnceLock::new();
    HEAD.get_or_init(|| lipcall::render::default_head().expect("bundled head loads"))
}

fn levels() -> &'static DetailLevels {
    static LEVELS: OnceLock<DetailLevels> = OnceLock::new();
    LEVELS.get_or_init(|| DetailLevels::build(default_head()))
}

#[test]
fn coarser_levels_have_fewer_triangles_over_the_same_vertices() {
    let head = default_head();
    let levels = levels().levels();
    let counts: Vec<usize> = levels.iter().map(|l| l.triangle_count()).collect();
    let errors: Vec<f32> = levels.iter().map(|l| l.error_m).collect();
    println!("triangles {counts:?}, errors in metres {errors:?}");
    assert_eq!(counts[0], head.triangle_count(), "level 0 is the full mesh");
    assert_eq!(errors[0], 0.0);
    assert!(levels.len() >= 3, "{} levels", levels.len());
    for k in 1..levels.len() {
        assert!(counts[k] * 10 <= counts[k - 1] * 9, "level {k}: {counts:?}");
        assert!(errors[k] >= errors[k - 1], "level {k}: {errors:?}");
        assert!(errors[k] <= 0.004 * 1.01, "level {k}: {errors:?}");
    }
    assert!(
        counts[levels.len() - 1] * 2 < counts[0],
        "the coarsest level saves more than half: {counts:?}"
    );
    for level in levels {
        assert_eq!(level.indices.len(), head.primitives.len());
        for (ix, p) in level.indices.iter().zip(&head.primitives) {
            assert_eq!(ix.len() % 3, 0);
            assert!(!ix.is_empty(), "{} vanished", p.name);
            assert!(ix.iter().all(|&i| (i as usize) < p.vertices.len()));
        }
    }
}

#[test]
fn the_level_follows_the_size_the_head_is_shown_at() {
    let levels = levels();
    let errors: Vec<f32> = levels.levels().iter().map(|l| l.error_m).collect();
    let camera = Camera::framing(&default_head().face_frame(), Framing::Face);
    let mut last = usize::MAX;
    for height in [2000, 1000, 500, 250, 120, 60, 30] {
        let ppm = camera.pixels_per_metre(height);
        let level = levels.level_for(ppm);
        println!("{height} px high: {ppm:.0} px/m, level {level}");
        assert!(errors[level] * ppm <= MAX_ERROR_PX);
        if level + 1 < errors.len() {
            assert!(errors[level + 1] * ppm > MAX_ERROR_PX, "not the coarsest");
        }
        assert!(last == usize::MAX || level >= last, "smaller, coarser");
        last = level;
    }
    assert!(levels.level_for(camera.pixels_per_metre(120)) > 0);
    assert_eq!(levels.level_for(f32::NAN), 0);
    assert_eq!(levels.level_for(0.0), 0);
    // The lipreading close-up magnifies the mouth: a small tile of it still needs detail.
    let close = Camera::framing(&default_head().face_frame(), Framing::Mouth);
    assert!(
        levels.level_for(close.pixels_per_metre(120))
            < levels.level_for(camera.pixels_per_metre(120))
    );
    // Half the height, twice the error allowed.
    let ppm = camera.pixels_per_metre(400);
    assert!((camera.pixels_per_metre(200) * 2.0 - ppm).abs() < 1e-3 * ppm);
}

type Region = (u32, u32, u32, u32);

/// An offscreen renderer of the default head's levels in a `width` x `height` face tile, and
/// the tile's mouth: about a quarter of the height above the bottom, in the middle.
fn tile(ctx: &GpuContext, width: u32, height: u32) -> (OffscreenRenderer, Region) {
    let options = FrameOptions {
        width,
        height,
        framing: Framing::Face,
        ..Default::default()
    };
    let offscreen =
        OffscreenRenderer::with_levels(ctx, default_head(), levels(), options, 1).unwrap();
    let region = (
        width / 2 - height / 6,
        height * 13 / 20,
        width / 2 + height / 6,
        height * 17 / 20,
    );
    (offscreen, region)
}

fn region_pixels(img: &image::RgbaImage, (x0, y0, x1, y1): Region) -> Vec<[u8; 4]> {
    img.enumerate_pixels()
        .filter(|(x, y, _)| (x0..x1).contains(x) && (y0..y1).contains(y))
        .map(|(_, _, p)| p.0)
        .collect()
}

/// Pixels of `region` that are visibly different.
fn difference(a: &image::RgbaImage, b: &image::RgbaImage, region: Region) -> usize {
    region_pixels(a, region)
        .iter()
        .zip(&region_pixels(b, region))
        .filter(|&(&p, &q)| visibly_different(p, q))
        .count()
}

/// Pixels of `region` that show teeth (light grey).
fn teeth(img: &image::RgbaImage, region: Region) -> usize {
    region_pixels(img, region)
        .iter()
        .filter(|p| p[0].min(p[1]).min(p[2]) > 150 && i32::from(p[0]) - i32::from(p[2]) < 40)
        .count()
}

/// At the level its size picks, a head tile shows the same face as the full mesh, in every
/// viseme: all but a few edge pixels equal, in the mouth nearly all, and the same teeth.
#[test]
fn a_tile_at_its_level_looks_like_the_full_mesh() {
    let Some(ctx) = gpu() else { return };
    for (width, height) in [(249, 192), (160, 120)] {
        let (mut offscreen, region) = tile(&ctx, width, height);
        let level = offscreen
            .head()
            .level_for(offscreen.camera.pixels_per_metre(height));
        assert!(level > 0, "{width}x{height}: level {level}");
        let whole = (0, 0, width, height);
        let mut worst = 0.0f64;
        for (v, name) in VISEME_NAMES.iter().enumerate() {
            let weights = VisemeWeights::one_hot(v);
            offscreen.set_level(0);
            let full = offscreen.render(&ctx, &weights).unwrap();
            offscreen.set_level(level);
            let coarse = offscreen.render(&ctx, &weights).unwrap();
            if let Some(dir) = std::env::var_os("LIPCALL_LOD_SHOTS") {
                let dir = std::path::Path::new(&dir);
                full.save(dir.join(format!("{width}_{name}_full.png")))
                    .unwrap();
                coarse
                    .save(dir.join(format!("{width}_{name}_lod{level}.png")))
                    .unwrap();
            }
            let diff = difference(&full, &coarse, whole);
            let share = diff as f64 / (width * height) as f64;
            worst = worst.max(share);
            let mouth_diff = difference(&full, &coarse, region);
            let mouth_area = (region.2 - region.0) * (region.3 - region.1);
            let (teeth_full, teeth_coarse) = (teeth(&full, region), teeth(&coarse, region));
            println!(
                "{width}x{height} level {level} {name}: {diff} pixels differ ({:.2} %), \
                 {mouth_diff} of the mouth's {mouth_area}; teeth {teeth_full} vs {teeth_coarse}",
                100.0 * share
            );
            assert!(share < 0.01, "{name}: {diff} pixels differ");
            assert!(
                mouth_diff * 50 <= mouth_area as usize,
                "{name}: {mouth_diff} of the mouth's {mouth_area} pixels differ"
            );
            assert!(
                teeth_full.abs_diff(teeth_coarse) <= 1 + teeth_full / 20,
                "{name}: teeth {teeth_full} vs {teeth_coarse} pixels"
            );
        }
        println!(
            "{width}x{height}: at most {:.2} % of the pixels differ",
            100.0 * worst
        );
    }
}

/// Lit per vertex, a small head looks as it does lit per pixel: its triangles are a few pixels
/// across. Compared at the level of detail each size draws, in every viseme, from the largest
/// head lit per vertex down to a 120-pixel tile.
#[test]
fn a_small_tile_lit_per_vertex_looks_lit_per_pixel() {
    let Some(ctx) = gpu() else { return };
    let head = default_head();
    let camera = Camera::framing(&head.face_frame(), Framing::Face);
    let probe =
        OffscreenRenderer::with_levels(&ctx, head, levels(), FrameOptions::default(), 1).unwrap();
    let lit_per_vertex =
        |height| probe.head().shading_for(camera.pixels_per_metre(height)) == Shading::PerVertex;
    assert!(!lit_per_vertex(2000), "a large head is lit per pixel");
    let largest = (120..2000).rev().find(|&h| lit_per_vertex(h)).unwrap();
    println!("lit per vertex up to {largest} pixels high");
    assert!(lit_per_vertex(279), "eight peers' tiles are lit per vertex");
    for (width, height) in [
        (largest * 4 / 3, largest),
        (256, 279),
        (249, 192),
        (160, 120),
    ] {
        let (mut offscreen, region) = tile(&ctx, width, height);
        let ppm = offscreen.camera.pixels_per_metre(height);
        offscreen.set_level(offscreen.head().level_for(ppm));
        println!("{width}x{height}: {:?}", offscreen.head().shading_for(ppm));
        let mouth_area = ((region.2 - region.0) * (region.3 - region.1)) as usize;
        for (v, name) in VISEME_NAMES.iter().enumerate() {
            let weights = VisemeWeights::one_hot(v);
            offscreen.set_shading(&ctx.device, Shading::PerPixel);
            let pixel = offscreen.render(&ctx, &weights).unwrap();
            offscreen.set_shading(&ctx.device, Shading::PerVertex);
            let vertex = offscreen.render(&ctx, &weights).unwrap();
            if let Some(dir) = std::env::var_os("LIPCALL_LOD_SHOTS") {
                let dir = std::path::Path::new(&dir);
                pixel
                    .save(dir.join(format!("{width}_{name}_pixel.png")))
                    .unwrap();
                vertex
                    .save(dir.join(format!("{width}_{name}_vertex.png")))
                    .unwrap();
            }
            let diff = difference(&pixel, &vertex, (0, 0, width, height));
            let mouth_diff = difference(&pixel, &vertex, region);
            let (teeth_pixel, teeth_vertex) = (teeth(&pixel, region), teeth(&vertex, region));
            println!(
                "{width}x{height} {name}: {diff} pixels differ ({:.2} %), {mouth_diff} of the \
                 mouth's {mouth_area}; teeth {teeth_pixel} vs {teeth_vertex}",
                100.0 * diff as f64 / (width * height) as f64
            );
            assert!(
                diff * 200 < (width * height) as usize,
                "{name}: {diff} pixels differ"
            );
            assert!(
                mouth_diff * 100 <= mouth_area,
                "{name}: {mouth_diff} of the mouth's {mouth_area} pixels differ"
            );
            assert!(
                teeth_pixel.abs_diff(teeth_vertex) <= 2 + teeth_pixel / 20,
                "{name}: teeth {teeth_pixel} vs {teeth_vertex} pixels"
            );
        }
    }
}
