//! Work the renderer leaves out because it would not show: triangles that cannot face a frontal
//! camera (`render::facing`), and frames whose face moved by less than a quarter of a pixel
//! (`GpuHead::looks_the_same`, which the app's tiles ask before drawing). GPU tests run on
//! whatever adapter wgpu finds (lavapipe on CI); when there is none they fail under CI and skip,
//! saying why, elsewhere.

mod common;

use common::gpu;

use lipcall::render::lod::DetailLevels;
use lipcall::render::offscreen::{FrameOptions, OffscreenRenderer};
use lipcall::render::{Camera, Framing};
use lipcall::vocab::pose::HEAD_MAX_RAD;
use lipcall::vocab::{FacePose, VISEME_NAMES, Viseme, VisemeWeights};

/// Pixels that differ by more than 24 levels in some channel.
fn differing(a: &image::RgbaImage, b: &image::RgbaImage) -> usize {
    a.pixels()
        .zip(b.pixels())
        .filter(|(p, q)| common::visibly_different(p.0, q.0))
        .count()
}

fn blend(pairs: &[(Viseme, f32)]) -> VisemeWeights {
    let mut w = VisemeWeights([0.0; 15]);
    for &(v, x) in pairs {
        w.0[v as usize] = x;
    }
    w
}

/// Leaving out the triangles a frontal camera cannot see changes no pixel, in every viseme,
/// blends of them, and the head turned, nodded and tilted to the living face's bounds with the
/// eyes shut or glancing; and it leaves out a good part of the head.
#[test]
fn the_frontal_triangles_draw_the_same_picture() {
    let Some(ctx) = gpu() else { return };
    let model = lipcall::render::default_head().expect("bundled head");
    let levels = DetailLevels::build(&model);
    let [pitch, yaw, roll] = HEAD_MAX_RAD;
    let poses = [
        FacePose::REST,
        FacePose {
            pitch,
            yaw,
            roll,
            ..FacePose::REST
        },
        FacePose {
            pitch: -pitch,
            yaw: -yaw,
            roll: -roll,
            ..FacePose::REST
        },
        FacePose {
            pitch: -pitch,
            yaw,
            blink: 1.0,
            ..FacePose::REST
        },
        FacePose {
            pitch,
            roll: -roll,
            gaze: glam::Vec2::new(0.3, -0.18),
            ..FacePose::REST
        },
    ];
    let mut weights: Vec<VisemeWeights> = (0..VISEME_NAMES.len())
        .map(VisemeWeights::one_hot)
        .collect();
    weights.push(blend(&[(Viseme::Aa, 0.5), (Viseme::U, 0.5)]));
    weights.push(blend(&[(Viseme::I, 0.6), (Viseme::FF, 0.4)]));
    for (framing, width, height) in [(Framing::Face, 256, 279), (Framing::Mouth, 320, 240)] {
        let options = FrameOptions {
            width,
            height,
            framing,
            ..Default::default()
        };
        let mut offscreen =
            OffscreenRenderer::with_levels(&ctx, &model, &levels, options, 1).unwrap();
        for level in [
            0,
            offscreen
                .head()
                .level_for(offscreen.camera.pixels_per_metre(height)),
        ] {
            offscreen.set_level(level);
            let mut worst = 0;
            for pose in &poses {
                for w in &weights {
                    offscreen.set_leave_out_unseen(false);
                    let all = offscreen.render_posed(&ctx, w, pose).unwrap();
                    let every = offscreen.triangles_drawn();
                    offscreen.set_leave_out_unseen(true);
                    let frontal = offscreen.render_posed(&ctx, w, pose).unwrap();
                    let drawn = offscreen.triangles_drawn();
                    assert!(
                        drawn * 10 <= every * 8,
                        "{framing:?} level {level}: {drawn} of {every} triangles drawn"
                    );
                    worst = worst.max(differing(&all, &frontal));
                }
            }
            println!("{framing:?} {width}x{height} level {level}: at most {worst} pixels differ");
            // The same triangles that face the camera, in another order: at most a pixel where
            // two surfaces meet at equal depth.
            assert!(
                worst <= 2,
                "{framing:?} level {level}: {worst} pixels differ"
            );
        }
    }
}

/// A camera other than the frontal framings, or a head turned beyond the living face's bounds,
/// gets every triangle.
#[test]
fn other_views_draw_every_triangle() {
    let Some(ctx) = gpu() else { return };
    let model = lipcall::render::default_head().expect("bundled head");
    let options = FrameOptions {
        width: 160,
        height: 120,
        ..Default::default()
    };
    let mut offscreen = OffscreenRenderer::new(&ctx, &model, options).unwrap();
    let every = model
        .primitives
        .iter()
        .map(|p| p.indices.len() / 3)
        .sum::<usize>();
    let w = VisemeWeights::one_hot(Viseme::Aa as usize);
    offscreen.render(&ctx, &w).unwrap();
    assert!(offscreen.triangles_drawn() < every);
    let beyond = FacePose {
        yaw: 2.0 * HEAD_MAX_RAD[1],
        ..FacePose::REST
    };
    offscreen.render_posed(&ctx, &w, &beyond).unwrap();
    assert_eq!(offscreen.triangles_drawn(), every);
    offscreen.camera = Camera::framing_yaw(offscreen.head().face_frame(), Framing::Face, 0.6);
    offscreen.render(&ctx, &w).unwrap();
    assert_eq!(offscreen.triangles_drawn(), every);
}

/// A face that moved by less than a quarter of a pixel looks the same: drawn again, only a few
/// edge pixels change (which side of a pixel's centre an edge falls). The app's tiles show the
/// last picture then.
#[test]
fn a_face_that_moved_less_than_a_quarter_pixel_looks_the_same() {
    let Some(ctx) = gpu() else { return };
    let model = lipcall::render::default_head().expect("bundled head");
    let (width, height) = (256, 279);
    let options = FrameOptions {
        width,
        height,
        ..Default::default()
    };
    let mut offscreen = OffscreenRenderer::new(&ctx, &model, options).unwrap();
    let ppm = offscreen.camera.pixels_per_metre(height);
    let a = blend(&[(Viseme::Aa, 0.4), (Viseme::Sil, 0.6)]);
    let pose = FacePose {
        yaw: 0.01,
        pitch: -0.02,
        ..FacePose::REST
    };
    // The largest step of the mouth and of the head that still looks the same.
    let head = offscreen.head().clone();
    let largest = |make: &dyn Fn(f32) -> (VisemeWeights, FacePose)| {
        let mut x = 0.0f32;
        while x < 1.0 {
            let (w, p) = make(x + 1e-4);
            if !head.looks_the_same((&a, &pose), (&w, &p), ppm) {
                break;
            }
            x += 1e-4;
        }
        x
    };
    let mouth = |x: f32| {
        (
            blend(&[(Viseme::Aa, 0.4 + x), (Viseme::Sil, 0.6 - x)]),
            pose,
        )
    };
    let turn = |x: f32| {
        (
            a,
            FacePose {
                yaw: pose.yaw + x,
                ..pose
            },
        )
    };
    let (dm, dt) = (largest(&mouth), largest(&turn));
    assert!(dm > 0.0 && dt > 0.0, "steps {dm} {dt}");
    let before = offscreen.render_posed(&ctx, &a, &pose).unwrap();
    for (name, (w, p)) in [("mouth", mouth(dm)), ("head", turn(dt))] {
        let after = offscreen.render_posed(&ctx, &w, &p).unwrap();
        let diff = differing(&before, &after);
        println!(
            "{name}: a step of {:.4} changes {diff} pixels",
            if name == "mouth" { dm } else { dt }
        );
        assert!(
            diff * 1000 <= (width * height) as usize,
            "{name}: {diff} pixels differ"
        );
    }
    // Four times the step is drawn.
    let (w, p) = mouth(4.0 * dm);
    assert!(!head.looks_the_same((&a, &pose), (&w, &p), ppm));
}
