//! Head renderer tests. GPU tests run on whatever adapter wgpu finds (the software lavapipe /
//! llvmpipe one on CI); when there is none they fail under CI and skip, saying why, elsewhere.

mod common;

use common::gpu;

use std::sync::OnceLock;

use common::glb_write::{glb_container, write_glb};
use glam::{Vec2, Vec3};
use lipcall::lipsync::mouth::Articulation;
use lipcall::render::gltf_load::load_head_from_slice;
use lipcall::render::head::{Expression, Material, MorphDelta, Primitive, TargetSource, Vertex};
use lipcall::render::offscreen::{FrameOptions, GpuContext, OffscreenRenderer, WeightTrack};
use lipcall::render::{Camera, Framing, HeadModel, RenderError};
use lipcall::vocab::Viseme;
use lipcall::vocab::{FacePose, VISEME_COUNT};
use lipcall::vocab::{VISEME_NAMES, VisemeWeights};
use serde_json::json;

fn default_head() -> &'static HeadModel {
    static HEAD: OnceLock<HeadModel> = OnceLock::new();
    HEAD.get_or_init(|| lipcall::render::default_head().expect("bundled head loads"))
}

fn mouth_renderer(ctx: &GpuContext, model: &HeadModel) -> OffscreenRenderer {
    let options = FrameOptions {
        width: 96,
        height: 96,
        framing: Framing::Mouth,
        ..Default::default()
    };
    OffscreenRenderer::new(ctx, model, options).expect("offscreen renderer")
}

/// Pixels of the central region darker than the lips and skin: the open mouth's interior.
fn dark_pixels(img: &image::RgbaImage) -> usize {
    let (w, h) = img.dimensions();
    img.enumerate_pixels()
        .filter(|(x, y, _)| *x > w / 5 && *x < 4 * w / 5 && *y > h / 5 && *y < 4 * h / 5)
        .filter(|(_, _, p)| (p[0] as u32 + p[1] as u32 + p[2] as u32) < 3 * 70)
        .count()
}

fn pixel_difference(a: &image::RgbaImage, b: &image::RgbaImage) -> usize {
    a.pixels()
        .zip(b.pixels())
        .filter(|(p, q)| (0..3).any(|k| (p[k] as i32 - q[k] as i32).abs() > 8))
        .count()
}

#[test]
fn default_head_has_all_fifteen_named_visemes() {
    let head = default_head();
    assert_eq!(head.source, TargetSource::Visemes);
    assert!(
        head.missing_visemes.is_empty(),
        "{:?}",
        head.missing_visemes
    );
    for (v, name) in VISEME_NAMES.iter().enumerate().skip(1) {
        assert!(
            head.primitives.iter().any(|p| !p.targets[v].is_empty()),
            "no shape for {name}"
        );
    }
    assert!(
        head.primitives.len() >= 5,
        "skin, mouth, teeth, tongue, eyes"
    );
    let frame = head.face_frame();
    assert!(
        frame.mouth_width > 0.02 && frame.mouth_width < 0.08,
        "{frame:?}"
    );
}

#[test]
fn gpu_blend_matches_cpu_reference() {
    let Some(ctx) = gpu() else { return };
    // The default head, and a head with every eye slot (all 20 slots then carry shapes).
    let living = living_test_head();
    for head in [default_head(), &living] {
        let mut offscreen = mouth_renderer(&ctx, head);
        // A convex mix touching several shapes, and single shapes; eyes at rest and posed (the
        // head rotation is the model matrix's, so it leaves the blend alone).
        let mix = VisemeWeights::from_named([("aa", 0.5), ("U", 0.3), ("PP", 0.2)]).unwrap();
        let posed = FacePose {
            blink: 0.6,
            gaze: Vec2::new(0.3, -0.2),
            pitch: 0.05,
            yaw: -0.04,
            roll: 0.03,
        };
        let glance = FacePose {
            blink: 1.0,
            gaze: Vec2::new(-0.5, 0.4),
            ..FacePose::REST
        };
        let cases = [
            (mix, FacePose::REST),
            (VisemeWeights::single("TH").unwrap(), FacePose::REST),
            (VisemeWeights::neutral(), FacePose::REST),
            (mix, posed),
            (VisemeWeights::neutral(), glance),
        ];
        for (weights, pose) in cases {
            offscreen.render_posed(&ctx, &weights, &pose).unwrap();
            let cpu = head.blend_cpu_posed(&weights, &pose);
            let gpu = offscreen.blend_on_gpu(&ctx).unwrap();
            assert_eq!(cpu.len(), gpu.len());
            let mut worst = 0.0f32;
            for (c, g) in cpu.iter().zip(&gpu) {
                for k in 0..3 {
                    worst = worst.max((c.position[k] - g.position[k]).abs());
                    worst = worst.max((c.normal[k] - g.normal[k]).abs());
                }
            }
            assert!(worst < 1e-5, "GPU blend differs from CPU by {worst}");
        }
        // The eye slots really move the living head's vertices.
        if head.has_expression(Expression::Blink) {
            let open = head.blend_cpu(&VisemeWeights::neutral());
            let shut = head.blend_cpu_posed(&VisemeWeights::neutral(), &glance);
            assert_ne!(open, shut);
        }
    }
}

/// Runs this file's `neutral_weights_give_the_base_head` with wgpu asked for a backend this build
/// lacks (DirectX 12), so that no adapter is found; `CI` set or not.
fn without_an_adapter(ci: bool) -> (bool, String) {
    let mut child = std::process::Command::new(std::env::current_exe().unwrap());
    child
        .args([
            "--exact",
            "neutral_weights_give_the_base_head",
            "--nocapture",
        ])
        .env("WGPU_BACKEND", "dx12");
    if ci {
        child.env("CI", "true");
    } else {
        child.env_remove("CI");
    }
    let out = child.output().unwrap();
    let said = String::from_utf8_lossy(&out.stdout) + String::from_utf8_lossy(&out.stderr);
    (out.status.success(), said.into_owned())
}

#[test]
fn a_missing_adapter_fails_under_ci_and_skips_elsewhere() {
    let (passed, said) = without_an_adapter(true);
    assert!(
        !passed && said.contains("the head renderer: no GPU adapter") && said.contains("CI must"),
        "under CI a render test without an adapter must fail, saying why:\n{said}"
    );
    let (passed, said) = without_an_adapter(false);
    assert!(
        passed && said.contains("skipped: the head renderer: no GPU adapter"),
        "outside CI a render test without an adapter skips, saying why:\n{said}"
    );
}

#[test]
fn neutral_weights_give_the_base_head() {
    let Some(ctx) = gpu() else { return };
    let head = default_head();
    let mut offscreen = mouth_renderer(&ctx, head);
    let neutral = offscreen.render(&ctx, &VisemeWeights::neutral()).unwrap();
    let zero = offscreen.render(&ctx, &VisemeWeights([0.0; 15])).unwrap();
    assert_eq!(pixel_difference(&neutral, &zero), 0);
    let blended = offscreen.blend_on_gpu(&ctx).unwrap();
    let base: Vec<_> = head.primitives.iter().flat_map(|p| &p.vertices).collect();
    for (b, g) in base.iter().zip(&blended) {
        assert_eq!(b.position, g.position);
    }
}

#[test]
fn aa_opens_the_mouth_and_pp_closes_it() {
    let Some(ctx) = gpu() else { return };
    let mut offscreen = mouth_renderer(&ctx, default_head());
    let render = |o: &mut OffscreenRenderer, name: &str| {
        o.render(&ctx, &VisemeWeights::single(name).unwrap())
            .unwrap()
    };
    let sil = render(&mut offscreen, "sil");
    let aa = render(&mut offscreen, "aa");
    let pp = render(&mut offscreen, "PP");
    let (d_sil, d_aa, d_pp) = (dark_pixels(&sil), dark_pixels(&aa), dark_pixels(&pp));
    let region = (96 * 3 / 5) * (96 * 3 / 5);
    assert!(
        pixel_difference(&sil, &aa) > region / 10,
        "aa barely changes the mouth"
    );
    assert!(
        d_aa > d_sil + 150,
        "aa should show the dark mouth interior ({d_aa} vs {d_sil})"
    );
    assert!(
        d_pp * 10 < d_aa,
        "PP should close the mouth ({d_pp} dark pixels vs {d_aa} for aa)"
    );
    // Half-way between aa and PP is less open than aa.
    let mix = offscreen
        .render(
            &ctx,
            &VisemeWeights::from_named([("aa", 0.5), ("PP", 0.5)]).unwrap(),
        )
        .unwrap();
    assert!(dark_pixels(&mix) < d_aa);
}

#[test]
fn all_visemes_look_different_from_the_front() {
    let Some(ctx) = gpu() else { return };
    let mut offscreen = mouth_renderer(&ctx, default_head());
    let images: Vec<_> = (0..15)
        .map(|v| offscreen.render(&ctx, &VisemeWeights::one_hot(v)).unwrap())
        .collect();
    for a in 0..15 {
        for b in a + 1..15 {
            let diff = pixel_difference(&images[a], &images[b]);
            assert!(
                diff > 40,
                "{} and {} look alike ({diff} pixels differ)",
                VISEME_NAMES[a],
                VISEME_NAMES[b]
            );
        }
    }
}

/// A flat "face" grid facing +Z with morph targets of the given names: each target moves the
/// lower half of the grid (the "jaw") down by a different amount, or does nothing for `None`.
fn grid_glb(targets: &[(&str, f32)], with_normals: bool) -> Vec<u8> {
    grid_glb_with(targets, with_normals, None)
}

/// A 9 x 9 vertex grid facing +z with morph targets; with `texture` (image bytes and the declared
/// MIME type, if any) it also has UVs covering the image, stored in the GLB's binary chunk as the
/// material's base colour texture.
fn grid_glb_with(
    targets: &[(&str, f32)],
    with_normals: bool,
    texture: Option<(&[u8], Option<&str>)>,
) -> Vec<u8> {
    let n = 9usize;
    let mut pos = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let x = -0.1 + 0.2 * i as f32 / (n - 1) as f32;
            let y = -0.1 + 0.2 * j as f32 / (n - 1) as f32;
            pos.push([x, y, 0.0f32]);
        }
    }
    let mut idx = Vec::new();
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let a = (j * n + i) as u32;
            idx.extend_from_slice(&[
                a,
                a + 1,
                a + n as u32 + 1,
                a,
                a + n as u32 + 1,
                a + n as u32,
            ]);
        }
    }
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut add = |bytes: Vec<u8>,
                   count: usize,
                   kind: &str,
                   ctype: u32,
                   bounds: Option<([f32; 3], [f32; 3])>| {
        let offset = bin.len();
        bin.extend_from_slice(&bytes);
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()}));
        let mut a = json!({"bufferView": views.len() - 1, "componentType": ctype, "count": count, "type": kind});
        if let Some((min, max)) = bounds {
            a["min"] = json!(min);
            a["max"] = json!(max);
        }
        accessors.push(a);
        accessors.len() - 1
    };
    let f32s = |v: &[[f32; 3]]| {
        v.iter()
            .flatten()
            .flat_map(|f| f.to_le_bytes())
            .collect::<Vec<u8>>()
    };
    let p = add(
        f32s(&pos),
        pos.len(),
        "VEC3",
        5126,
        Some(([-0.1, -0.1, 0.0], [0.1, 0.1, 0.0])),
    );
    let nrm = vec![[0.0, 0.0, 1.0f32]; pos.len()];
    let nacc = add(f32s(&nrm), pos.len(), "VEC3", 5126, None);
    let i = add(
        idx.iter().flat_map(|i| i.to_le_bytes()).collect(),
        idx.len(),
        "SCALAR",
        5125,
        None,
    );
    let mut target_json = Vec::new();
    for (k, (_, amount)) in targets.iter().enumerate() {
        let deltas: Vec<[f32; 3]> = pos
            .iter()
            .map(|p| {
                if p[1] < 0.0 {
                    [0.01 * k as f32, -amount, 0.0]
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        let d = add(
            f32s(&deltas),
            deltas.len(),
            "VEC3",
            5126,
            Some(([0.0, -amount, 0.0], [0.01 * k as f32, 0.0, 0.0])),
        );
        target_json.push(json!({"POSITION": d}));
    }
    let mut attributes = json!({"POSITION": p});
    if with_normals {
        attributes["NORMAL"] = json!(nacc);
    }
    let mut material = json!({"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.6, 0.5, 1.0]}});
    let mut images = Vec::new();
    if let Some((bytes, mime)) = texture {
        let uv: Vec<u8> = pos
            .iter()
            .flat_map(|p| [(p[0] + 0.1) / 0.2, (0.1 - p[1]) / 0.2])
            .flat_map(|f| f.to_le_bytes())
            .collect();
        attributes["TEXCOORD_0"] = json!(add(uv, pos.len(), "VEC2", 5126, None));
        let view = add(bytes.to_vec(), 1, "SCALAR", 5121, None);
        accessors.pop(); // only the buffer view is wanted
        let mut img = json!({"bufferView": view});
        if let Some(mime) = mime {
            img["mimeType"] = json!(mime);
        }
        images.push(img);
        material["pbrMetallicRoughness"]["baseColorTexture"] = json!({"index": 0});
    }
    let mut primitive = json!({"attributes": attributes, "indices": i, "material": 0});
    let mut mesh = json!({"name": "face"});
    if !targets.is_empty() {
        primitive["targets"] = json!(target_json);
        mesh["extras"] = json!({"targetNames": targets.iter().map(|t| t.0).collect::<Vec<_>>()});
    }
    mesh["primitives"] = json!([primitive]);
    let doc = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "root", "children": [1], "scale": [2.0, 2.0, 2.0]}, {"mesh": 0, "translation": [0.0, 0.0, 0.01]}],
        "meshes": [mesh],
        "materials": [material],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    let mut doc = doc;
    if !images.is_empty() {
        doc["images"] = json!(images);
        doc["textures"] = json!([{"source": 0}]);
    }
    glb_container(doc.to_string().as_bytes(), &bin)
}

#[test]
fn arkit_head_animates_through_the_recipe() {
    let glb = grid_glb(
        &[
            ("jawOpen", 0.05),
            ("mouthPucker", 0.01),
            ("eyeBlinkLeft", 0.02),
        ],
        true,
    );
    let head = load_head_from_slice(&glb).expect("ARKit grid loads");
    assert_eq!(head.source, TargetSource::Arkit);
    // jawOpen is in the recipe of aa; every viseme but sil has jawOpen or mouthPucker in its.
    let aa = lipcall::vocab::Viseme::from_name("aa").unwrap().index();
    assert!(!head.primitives[0].targets[aa].is_empty());
    assert!(
        head.missing_visemes.is_empty(),
        "{:?}",
        head.missing_visemes
    );
    // Node scale 2 applies to positions and deltas.
    let blended = head.blend_cpu(&VisemeWeights::single("aa").unwrap());
    let min_y = blended
        .iter()
        .map(|v| v.position[1])
        .fold(f32::INFINITY, f32::min);
    let jaw = lipcall::render::arkit::matrix()[aa][0];
    assert!((min_y - (-0.2 - 2.0 * 0.05 * jaw)).abs() < 1e-5, "{min_y}");

    let Some(ctx) = gpu() else { return };
    let options = FrameOptions {
        width: 64,
        height: 64,
        ..Default::default()
    };
    let mut offscreen = OffscreenRenderer::new(&ctx, &head, options).unwrap();
    let rest = offscreen.render(&ctx, &VisemeWeights::neutral()).unwrap();
    let open = offscreen
        .render(&ctx, &VisemeWeights::single("aa").unwrap())
        .unwrap();
    assert!(
        pixel_difference(&rest, &open) > 20,
        "ARKit jawOpen should move the grid"
    );
}

/// A small JPEG of one saturated blue, made with the `image` crate's encoder.
fn blue_jpeg() -> Vec<u8> {
    let img = image::RgbImage::from_pixel(16, 16, image::Rgb([20, 40, 230]));
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 90)
        .encode_image(&img)
        .expect("JPEG encodes");
    bytes
}

/// Mean colour of the pixels that are not the (black) background, and how many there are.
fn head_colour(img: &image::RgbaImage) -> ([f64; 3], usize) {
    let head: Vec<_> = img
        .pixels()
        .filter(|p| p[0].max(p[1]).max(p[2]) > 24)
        .collect();
    let mut sum = [0.0; 3];
    for p in &head {
        for k in 0..3 {
            sum[k] += p[k] as f64;
        }
    }
    let n = head.len().max(1) as f64;
    (sum.map(|s| s / n), head.len())
}

#[test]
fn jpeg_base_colour_textures_are_drawn_and_broken_ones_fall_back_to_the_factor() {
    let jpeg = blue_jpeg();
    assert_eq!(&jpeg[..3], &[0xFF, 0xD8, 0xFF]);
    let mut broken = jpeg.clone();
    for b in broken.iter_mut().skip(2) {
        *b = 0x5A;
    }
    let textured = [
        grid_glb_with(
            &[("viseme_aa", 0.05)],
            true,
            Some((&jpeg, Some("image/jpeg"))),
        ),
        // Without a MIME type the format comes from the bytes' signature.
        grid_glb_with(&[("viseme_aa", 0.05)], true, Some((&jpeg, None))),
    ];
    let broken = [
        grid_glb_with(
            &[("viseme_aa", 0.05)],
            true,
            Some((&broken, Some("image/jpeg"))),
        ),
        grid_glb_with(
            &[("viseme_aa", 0.05)],
            true,
            Some((&jpeg, Some("image/webp"))),
        ),
    ];
    let textured: Vec<HeadModel> = textured
        .iter()
        .map(|glb| load_head_from_slice(glb).expect("textured grid loads"))
        .collect();
    let broken: Vec<HeadModel> = broken
        .iter()
        .map(|glb| load_head_from_slice(glb).expect("a bad texture does not stop loading"))
        .collect();
    for head in &textured {
        let tex = head.materials[0].texture.as_ref().expect("JPEG decoded");
        assert_eq!((tex.width, tex.height), (16, 16));
        let [r, g, b, a] = tex.rgba[4 * (8 * 16 + 8)..][..4] else {
            unreachable!()
        };
        assert!(b > 200 && r < 60 && g < 80 && a == 255, "{r} {g} {b} {a}");
    }
    for head in &broken {
        assert!(head.materials[0].texture.is_none());
        assert_eq!(head.materials[0].base_color, [0.8, 0.6, 0.5, 1.0]);
    }

    let Some(ctx) = gpu() else { return };
    let options = FrameOptions {
        width: 64,
        height: 64,
        background: [0.0; 3],
        ..Default::default()
    };
    let render = |head: &HeadModel| {
        let mut offscreen = OffscreenRenderer::new(&ctx, head, options).unwrap();
        let img = offscreen.render(&ctx, &VisemeWeights::neutral()).unwrap();
        head_colour(&img)
    };
    for head in &textured {
        let ([r, g, b], n) = render(head);
        println!("textured head: {n} pixels, mean colour {r:.0} {g:.0} {b:.0}");
        assert!(n > 100, "the head covers too few pixels: {n}");
        assert!(b > 1.5 * r && b > 1.5 * g && b > 60.0, "{r} {g} {b}");
    }
    for head in &broken {
        let ([r, g, b], n) = render(head);
        println!("broken texture: {n} pixels, mean colour {r:.0} {g:.0} {b:.0}");
        assert!(n > 100, "the head covers too few pixels: {n}");
        assert!(
            r > b && g > b,
            "factor colour (0.8, 0.6, 0.5) expected: {r} {g} {b}"
        );
    }
}

#[test]
fn viseme_names_with_and_without_prefix_are_matched() {
    let glb = grid_glb(
        &[("viseme_aa", 0.05), ("PP", 0.0), ("Viseme_U", 0.02)],
        false,
    );
    let head = load_head_from_slice(&glb).unwrap();
    assert_eq!(head.source, TargetSource::Visemes);
    for name in ["aa", "U"] {
        let v = lipcall::vocab::Viseme::from_name(name).unwrap().index();
        assert!(!head.primitives[0].targets[v].is_empty(), "{name}");
    }
    assert!(head.missing_visemes.contains(&"E".to_owned()));
    // Normals were missing from the file and are computed.
    assert!(
        head.primitives[0]
            .vertices
            .iter()
            .all(|v| (v.normal[2] - 1.0).abs() < 1e-4)
    );
}

#[test]
fn heads_without_usable_targets_are_refused_with_what_is_missing() {
    let none = grid_glb(&[], true);
    let err = load_head_from_slice(&none).unwrap_err();
    assert!(matches!(err, RenderError::NoUsableTargets { .. }), "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains("viseme_aa") && msg.contains("jawOpen"),
        "{msg}"
    );

    let unrelated = grid_glb(&[("smile", 0.01), ("browUp", 0.01)], true);
    let msg = load_head_from_slice(&unrelated).unwrap_err().to_string();
    assert!(msg.contains("smile") && msg.contains("browUp"), "{msg}");
}

#[test]
fn malformed_glb_files_give_errors_not_panics() {
    assert!(load_head_from_slice(b"").is_err());
    assert!(load_head_from_slice(b"glTF").is_err());
    assert!(load_head_from_slice(b"not a gltf file at all").is_err());
    let good = grid_glb(&[("jawOpen", 0.05)], true);
    // Every truncation.
    for len in (0..good.len()).step_by(7) {
        assert!(
            load_head_from_slice(&good[..len]).is_err(),
            "truncated at {len}"
        );
    }
    // Deterministic byte corruption all over the file: any outcome but a panic.
    let mut state = 0x2545F4914F6CDD1Du64;
    for _ in 0..3000 {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        let mut bad = good.clone();
        let at = (state as usize) % bad.len();
        bad[at] = (state >> 32) as u8;
        let _ = load_head_from_slice(&bad);
    }
    // Accessors pointing outside their buffer.
    let json_len = u32::from_le_bytes([good[12], good[13], good[14], good[15]]) as usize;
    let text = String::from_utf8(good[20..20 + json_len].to_vec()).unwrap();
    let bin_start = 20 + json_len + 8;
    let mut doc: serde_json::Value = serde_json::from_str(text.trim_end()).unwrap();
    doc["accessors"][0]["count"] = json!(1_000_000);
    let out_of_range = glb_container(doc.to_string().as_bytes(), &good[bin_start..]);
    assert!(matches!(
        load_head_from_slice(&out_of_range),
        Err(RenderError::Gltf(_))
    ));
    let mut doc2: serde_json::Value = serde_json::from_str(text.trim_end()).unwrap();
    doc2["accessors"][0]["componentType"] = json!(5123);
    let wrong_type = glb_container(doc2.to_string().as_bytes(), &good[bin_start..]);
    assert!(load_head_from_slice(&wrong_type).is_err());
}

#[test]
fn missing_head_file_is_an_io_error() {
    let err = lipcall::render::gltf_load::load_head(std::path::Path::new("/nonexistent/head.glb"))
        .unwrap_err();
    assert!(matches!(
        err,
        RenderError::Input(lipcall::input::InputError::Io { .. })
    ));
}

#[test]
fn weight_track_samples_by_time() {
    let track = WeightTrack::from_columns(
        &["sil", "aa"],
        &[
            (0.0, vec![1.0, 0.0]),
            (0.02, vec![0.0, 1.0]),
            (0.04, vec![1.0, 0.0]),
        ],
    )
    .unwrap();
    let mid = track.sample(0.01);
    assert!((mid.0[0] - 0.5).abs() < 1e-6 && (mid.0[10] - 0.5).abs() < 1e-6);
    assert_eq!(track.sample(1.0), VisemeWeights::neutral());
    assert!((track.duration() - 0.06).abs() < 1e-9);
    assert!(WeightTrack::from_columns(&["zz"], &[]).is_err());
    assert!(WeightTrack::from_columns(&["aa"], &[(0.0, vec![1.0]), (0.0, vec![1.0])]).is_err());
}

#[test]
fn frames_are_written_at_25_and_50_fps() {
    let Some(ctx) = gpu() else { return };
    let mut track = WeightTrack::default();
    for k in 0..10 {
        let name = if k % 2 == 0 { "aa" } else { "PP" };
        track
            .push(k as f64 * 0.02, VisemeWeights::single(name).unwrap())
            .unwrap();
    }
    let dir = std::env::temp_dir().join(format!("lipcall-frames-{}", std::process::id()));
    for (fps, expected) in [(25, 5), (50, 10)] {
        let _ = std::fs::remove_dir_all(&dir);
        let options = FrameOptions {
            width: 48,
            height: 48,
            fps,
            ..Default::default()
        };
        let summary = lipcall::render::offscreen::render_frames_with(
            &ctx,
            default_head(),
            &track,
            &dir,
            &options,
        )
        .unwrap();
        assert_eq!(summary.frames, expected);
        for k in 0..expected {
            let path = dir.join(format!("frame_{k:06}.png"));
            let img = image::open(&path).unwrap();
            assert_eq!(img.width(), 48);
        }
        assert!(!dir.join(format!("frame_{expected:06}.png")).exists());
    }
    let _ = std::fs::remove_dir_all(&dir);
    let bad = FrameOptions {
        fps: 30,
        ..Default::default()
    };
    assert!(lipcall::render::render_frames(default_head(), &track, &dir, &bad).is_err());
}

/// An `n` x `n` grid over the rectangle at depth `z`, facing +Z.
fn grid(name: &str, material: usize, rect: [f32; 4], z: f32, n: usize) -> Primitive {
    let (vertices, indices) = common::mesh::grid(rect, z, n);
    Primitive::new(name, material, vertices, indices)
}

/// A disc of radius `r` around `centre`, facing +Z.
fn disc(name: &str, material: usize, centre: Vec3, r: f32) -> Primitive {
    let mut vertices = vec![Vertex {
        position: centre.into(),
        normal: [0.0, 0.0, 1.0],
        uv: [0.0; 2],
        color: [1.0; 4],
    }];
    let rim = 24;
    for k in 0..rim {
        let a = std::f32::consts::TAU * k as f32 / rim as f32;
        vertices.push(Vertex {
            position: (centre + Vec3::new(r * a.cos(), r * a.sin(), 0.0)).into(),
            ..vertices[0]
        });
    }
    let indices = (0..rim as u32)
        .flat_map(|k| [0, 1 + k, 1 + (k + 1) % rim as u32])
        .collect();
    Primitive::new(name, material, vertices, indices)
}

/// Every vertex of `p` moved by `f(position)`.
fn shape(p: &Primitive, f: impl Fn(Vec3) -> Vec3) -> Vec<MorphDelta> {
    common::mesh::deltas(&p.vertices, f)
}

/// A small synthetic face facing +Z, built in code and sent through `glb_write` and the loader
/// (its eye shapes under lipcall's slot names): a skin plane whose chin drops with the open
/// visemes, lips that open, spread and round with all 15, a dark mouth behind them, two dark
/// eyes that move with the four look shapes, and two lids, a shade darker than the skin, that
/// slide down over the eyes with the blink.
fn living_test_head() -> HeadModel {
    let mut skin = grid("skin", 0, [-0.1, 0.1, -0.12, 0.12], 0.0, 11);
    let mut upper = grid("upper lip", 1, [-0.03, 0.03, -0.045, -0.035], 0.002, 5);
    let mut lower = grid("lower lip", 1, [-0.03, 0.03, -0.06, -0.05], 0.002, 5);
    let mouth = grid("mouth", 2, [-0.03, 0.03, -0.06, -0.035], 0.001, 2);
    for v in 0..VISEME_COUNT {
        // Jaw opening and lip width per viseme: the design brief's table, as lip sync uses it.
        let a = Articulation::of(Viseme::ALL[v]);
        let (jaw, width) = (a.jaw, a.width);
        skin.targets[v] = shape(&skin, |p| {
            Vec3::new(0.0, if p.y < -0.09 { -0.01 * jaw } else { 0.0 }, 0.0)
        });
        upper.targets[v] = shape(&upper, |p| {
            Vec3::new(0.012 * width * p.x / 0.03, 0.003 * jaw, 0.0)
        });
        lower.targets[v] = shape(&lower, |p| {
            Vec3::new(0.012 * width * p.x / 0.03, -0.02 * jaw, 0.0)
        });
    }
    let mut primitives = vec![skin, upper, lower, mouth];
    for x in [-0.04f32, 0.04] {
        let mut eye = disc("eye", 2, Vec3::new(x, 0.04, 0.003), 0.014);
        for (e, d) in [
            (Expression::LookUp, Vec3::new(0.0, 0.006, 0.0)),
            (Expression::LookDown, Vec3::new(0.0, -0.006, 0.0)),
            (Expression::LookLeft, Vec3::new(0.01, 0.0, 0.0)),
            (Expression::LookRight, Vec3::new(-0.01, 0.0, 0.0)),
        ] {
            eye.targets[e.slot()] = shape(&eye, |_| d);
        }
        let mut lid = grid("lid", 3, [x - 0.02, x + 0.02, 0.056, 0.09], 0.005, 3);
        lid.targets[Expression::Blink.slot()] = shape(&lid, |_| Vec3::new(0.0, -0.034, 0.0));
        primitives.push(eye);
        primitives.push(lid);
    }
    let material = |name: &str, base_color: [f32; 4]| Material {
        name: name.into(),
        base_color,
        ..Material::default()
    };
    let model = HeadModel {
        primitives,
        materials: vec![
            material("skin", [0.8, 0.55, 0.45, 1.0]),
            material("lips", [0.6, 0.12, 0.12, 1.0]),
            material("dark", [0.01, 0.01, 0.015, 1.0]),
            material("lid", [0.5, 0.3, 0.25, 1.0]),
        ],
        source: TargetSource::Visemes,
        missing_visemes: Vec::new(),
    };
    model.validate().unwrap();
    load_head_from_slice(&write_glb(&model)).expect("the test head loads back")
}

#[test]
fn arkit_eye_targets_drive_the_eye_slots_of_any_head() {
    // An ARKit mouth with ARKit eyes; an unknown eye shape beside them is ignored.
    let amounts = [
        ("jawOpen", 0.05),
        ("eyeBlinkLeft", 0.01),
        ("eyeBlinkRight", 0.02),
        ("eyeLookOutLeft", 0.03),
        ("eyeLookInRight", 0.04),
        ("eyeSquintLeft", 0.05),
    ];
    let head = load_head_from_slice(&grid_glb(&amounts, true)).unwrap();
    assert_eq!(head.source, TargetSource::Arkit);
    let slot = |e: Expression| &head.primitives[0].targets[e.slot()];
    // grid_glb's target k moves the lower half by (0.01 k, -amount, 0), under a node scale of 2.
    let lower = head.primitives[0]
        .vertices
        .iter()
        .position(|v| v.position[1] < 0.0)
        .unwrap();
    let moved = |e: Expression| slot(e)[lower].position;
    let close = |a: [f32; 3], b: [f32; 3]| (0..3).all(|k| (a[k] - b[k]).abs() < 1e-6);
    // Both blinks add up in the one blink slot; out-left and in-right make "look left".
    assert!(
        close(moved(Expression::Blink), [2.0 * 0.03, -2.0 * 0.03, 0.0]),
        "{:?}",
        moved(Expression::Blink)
    );
    assert!(
        close(moved(Expression::LookLeft), [2.0 * 0.07, -2.0 * 0.07, 0.0]),
        "{:?}",
        moved(Expression::LookLeft)
    );
    for e in [
        Expression::LookUp,
        Expression::LookDown,
        Expression::LookRight,
    ] {
        assert!(slot(e).is_empty() && !head.has_expression(e));
    }
    assert!(head.has_expression(Expression::Blink));
    // A viseme head with the same eyes gets them too; a head without any does not blink.
    let visemes = load_head_from_slice(&grid_glb(
        &[("viseme_aa", 0.05), ("eyeBlinkLeft", 0.01)],
        true,
    ))
    .unwrap();
    assert_eq!(visemes.source, TargetSource::Visemes);
    assert!(visemes.has_expression(Expression::Blink));
    let plain = load_head_from_slice(&grid_glb(&[("viseme_aa", 0.05)], true)).unwrap();
    assert!(Expression::ALL.iter().all(|&e| !plain.has_expression(e)));
    // Eyes alone are no mouth.
    let eyes_only = grid_glb(&[("eyeBlinkLeft", 0.01), ("eyeBlinkRight", 0.01)], true);
    assert!(matches!(
        load_head_from_slice(&eyes_only),
        Err(RenderError::NoUsableTargets { .. })
    ));
    // The written test head keeps its eye shapes under lipcall's own names.
    let living = living_test_head();
    assert!(Expression::ALL.iter().all(|&e| living.has_expression(e)));
    assert!(living.missing_visemes.is_empty());
}

#[test]
fn head_motion_turns_the_rendered_head_and_the_rest_pose_changes_nothing() {
    let Some(ctx) = gpu() else { return };
    let head = living_test_head();
    let options = FrameOptions {
        width: 96,
        height: 96,
        ..Default::default()
    };
    let mut offscreen = OffscreenRenderer::new(&ctx, &head, options).unwrap();
    let plain = offscreen.render(&ctx, &VisemeWeights::neutral()).unwrap();
    let rest = offscreen
        .render_posed(&ctx, &VisemeWeights::neutral(), &FacePose::REST)
        .unwrap();
    assert_eq!(plain, rest);
    for pose in [
        FacePose {
            pitch: 0.05,
            ..FacePose::REST
        },
        FacePose {
            yaw: 0.05,
            ..FacePose::REST
        },
        FacePose {
            roll: 0.05,
            ..FacePose::REST
        },
    ] {
        let turned = offscreen
            .render_posed(&ctx, &VisemeWeights::neutral(), &pose)
            .unwrap();
        assert!(
            pixel_difference(&plain, &turned) > 20,
            "{pose:?} barely moves the head"
        );
        // The pivot is behind the face: a nod moves the mouth (the red lips) down.
        if pose.pitch > 0.0 {
            let centroid_y = |img: &image::RgbaImage| {
                let dark: Vec<u32> = img
                    .enumerate_pixels()
                    .filter(|(_, _, p)| p[0] as i32 > p[1] as i32 + 80)
                    .map(|(_, y, _)| y)
                    .collect();
                dark.iter().sum::<u32>() as f32 / dark.len().max(1) as f32
            };
            assert!(
                centroid_y(&turned) > centroid_y(&plain),
                "the lips should go down"
            );
        }
    }
}

/// Pixel rectangle (x0, y0, x1, y1), inclusive, covering where `moved` vertices of `head` can
/// be in 480 x 480 face frames: their rest positions and each of the given slots at full weight.
fn screen_region(head: &HeadModel, slots: std::ops::Range<usize>) -> (u32, u32, u32, u32) {
    let (w, h) = (480.0f32, 480.0f32);
    let camera = Camera::framing(&head.face_frame(), Framing::Face);
    let view_proj = camera.view_proj(w / h);
    let (mut x0, mut y0, mut x1, mut y1) = (f32::MAX, f32::MAX, f32::MIN, f32::MIN);
    for p in &head.primitives {
        for slot in slots.clone() {
            let Some(target) = p.targets.get(slot).filter(|t| !t.is_empty()) else {
                continue;
            };
            for (v, d) in p.vertices.iter().zip(target) {
                let delta = Vec3::from(d.position);
                if delta.length() < 1e-7 {
                    continue;
                }
                for pos in [Vec3::from(v.position), Vec3::from(v.position) + delta] {
                    let ndc = view_proj.project_point3(pos);
                    let (x, y) = ((ndc.x + 1.0) * 0.5 * w, (1.0 - ndc.y) * 0.5 * h);
                    (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
                }
            }
        }
    }
    assert!(x0 <= x1, "no moving vertices in slots {slots:?}");
    let clamp = |v: f32| v.clamp(0.0, w - 1.0) as u32;
    (
        clamp(x0 - 2.0),
        clamp(y0 - 2.0),
        clamp(x1 + 2.0),
        clamp(y1 + 2.0),
    )
}

fn region_pixels(img: &image::RgbaImage, (x0, y0, x1, y1): (u32, u32, u32, u32)) -> Vec<[u8; 4]> {
    (y0..=y1)
        .flat_map(|y| (x0..=x1).map(move |x| (x, y)))
        .map(|(x, y)| img.get_pixel(x, y).0)
        .collect()
}

fn changed(a: &[[u8; 4]], b: &[[u8; 4]]) -> usize {
    a.iter()
        .zip(b)
        .filter(|(p, q)| common::visibly_different(**p, **q))
        .count()
}

fn write_silence(path: &std::path::Path, seconds: u32) {
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: 8000,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut wav = hound::WavWriter::create(path, spec).unwrap();
    for _ in 0..8000 * seconds {
        wav.write_sample(0i16).unwrap();
    }
    wav.finalize().unwrap();
}

fn animate_frames(
    input: &std::path::Path,
    head: Option<&std::path::Path>,
    dir: &std::path::Path,
    life: bool,
) -> Vec<image::RgbaImage> {
    lipcall::commands::animate::animate(&lipcall::commands::animate::AnimateArgs {
        input: input.to_owned(),
        weights: None,
        frames: Some(dir.to_owned()),
        head: head.map(|h| h.to_owned()),
        fps: 25,
        mouth_close_up: false,
        visemes: None,
        model: None,
        articulation: None,
        baseline_jaw: false,
        closure_bias: 0.0,
        life,
        seed: lipcall::lipsync::life::DEFAULT_SEED,
        drive: Default::default(),
    })
    .expect("animate --frames");
    let mut frames = Vec::new();
    while let Ok(img) = image::open(dir.join(format!("frame_{:06}.png", frames.len()))) {
        frames.push(img.to_rgba8());
    }
    frames
}

/// Issue 11's done-when: 8 s of digital silence through `lipcall animate --frames` at 25 fps
/// shows at least one blink (the eyes change in a few frames and come back) and no mouth motion
/// (the mouth's pixels never change, so neither the lips nor the head moved). Run on the test
/// head with eye shapes and, once it has them, on the bundled default head.
#[test]
fn eight_seconds_of_digital_silence_blink_and_keep_the_mouth_still() {
    let Some(ctx) = gpu() else { return };
    let dir = tempfile::tempdir().unwrap();
    let wav = dir.path().join("silence.wav");
    write_silence(&wav, 8);
    let glb = dir.path().join("living.glb");
    let living = living_test_head();
    std::fs::write(&glb, write_glb(&living)).unwrap();
    let mut heads = vec![("test head", Some(glb.as_path()), living.clone())];
    if default_head().has_expression(Expression::Blink) {
        heads.push(("default head", None, default_head().clone()));
    } else {
        println!("the default head has no blink shape yet: only the test head is checked");
    }
    for (name, path, head) in heads {
        let frames = animate_frames(&wav, path, &dir.path().join(name), true);
        assert_eq!(frames.len(), 200, "{name}: 8 s at 25 fps");
        let mouth = screen_region(&head, 0..VISEME_COUNT);
        let eyes = screen_region(&head, VISEME_COUNT..lipcall::render::head::TARGET_COUNT);
        println!("{name}: mouth region {mouth:?}, eye region {eyes:?}");

        // The mouth region would show lips or head moving: check that it can, then that it
        // does not.
        let options = FrameOptions {
            width: 480,
            height: 480,
            ..Default::default()
        };
        let mut offscreen = OffscreenRenderer::new(&ctx, &head, options).unwrap();
        let rest = offscreen.render(&ctx, &VisemeWeights::neutral()).unwrap();
        let open = offscreen
            .render(&ctx, &VisemeWeights::single("aa").unwrap())
            .unwrap();
        let nod = offscreen
            .render_posed(
                &ctx,
                &VisemeWeights::neutral(),
                &FacePose {
                    pitch: 0.5f32.to_radians(),
                    ..FacePose::REST
                },
            )
            .unwrap();
        let still = region_pixels(&frames[0], mouth);
        assert!(changed(&region_pixels(&open, mouth), &region_pixels(&rest, mouth)) > 50);
        assert!(
            region_pixels(&nod, mouth) != region_pixels(&rest, mouth),
            "a half-degree nod would show"
        );
        for (k, frame) in frames.iter().enumerate() {
            assert!(
                region_pixels(frame, mouth) == still,
                "{name}: the mouth region moved in frame {k}"
            );
        }

        // The eyes: how much of their region differs from the first frame (open, ahead).
        let open_eyes = region_pixels(&frames[0], eyes);
        let area = open_eyes.len();
        let diff: Vec<usize> = frames
            .iter()
            .map(|f| changed(&region_pixels(f, eyes), &open_eyes))
            .collect();
        let (peak_at, &peak) = diff.iter().enumerate().max_by_key(|(_, d)| **d).unwrap();
        println!("{name}: eye region changes per frame {diff:?}");
        assert!(
            peak * 20 >= area,
            "{name}: no blink: at most {peak} of {area} eye pixels change"
        );
        // A blink is short: the big change lasts a few frames, and the eyes come back.
        let shut = |d: usize| 2 * d > peak;
        let start = (0..=peak_at)
            .rev()
            .take_while(|&k| shut(diff[k]))
            .last()
            .unwrap();
        let len = diff[start..].iter().take_while(|&&d| shut(d)).count();
        assert!(
            len <= 7,
            "{name}: the eyes stay changed for {len} frames from {start}"
        );
        assert!(
            diff[start + len..].iter().any(|&d| 4 * d <= peak),
            "{name}: the eyes do not reopen after the blink at frame {start}"
        );
    }

    // Without the living face the same silence is one still picture.
    let short = dir.path().join("short.wav");
    write_silence(&short, 2);
    let frames = animate_frames(&short, Some(&glb), &dir.path().join("still"), false);
    assert_eq!(frames.len(), 50);
    assert!(
        frames.iter().all(|f| *f == frames[0]),
        "--no-life: something moved"
    );
}

/// The default head with its parts painted in flat tag colours, to find them on screen: teeth
/// and gums blue, the tongue green (lighting keeps their hue).
fn tagged_default_head() -> HeadModel {
    let mut head = default_head().clone();
    for p in &mut head.primitives {
        let tag = match p.name.as_str() {
            "teethUpper" | "teethLower" => [0.0, 0.0, 1.0, 1.0],
            "tongue" => [0.0, 1.0, 0.0, 1.0],
            _ => continue,
        };
        for v in &mut p.vertices {
            v.color = tag;
        }
        head.materials[p.material].base_color = [1.0; 4];
        head.materials[p.material].texture = None;
    }
    head
}

/// The lipreading close-up at 128 x 128 px, one image per viseme in `VISEME_NAMES` order.
fn mouth_close_ups(ctx: &GpuContext, head: &HeadModel) -> Vec<image::RgbaImage> {
    let options = FrameOptions {
        width: 128,
        height: 128,
        framing: Framing::Mouth,
        ..Default::default()
    };
    let mut offscreen = OffscreenRenderer::new(ctx, head, options).unwrap();
    (0..VISEME_COUNT)
        .map(|v| offscreen.render(ctx, &VisemeWeights::one_hot(v)).unwrap())
        .collect()
}

/// Pixels of the mouth region (the middle three fifths of a close-up, both ways) that pass `f`.
fn mouth_region_count(img: &image::RgbaImage, f: impl Fn(&image::Rgba<u8>) -> bool) -> usize {
    let (w, h) = img.dimensions();
    img.enumerate_pixels()
        .filter(|(x, y, _)| *x > w / 5 && *x < 4 * w / 5 && *y > h / 5 && *y < 4 * h / 5)
        .filter(|(_, _, p)| f(p))
        .count()
}

/// Pixels of the mouth region that differ by more than 12 levels in some channel.
fn mouth_region_difference(a: &image::RgbaImage, b: &image::RgbaImage) -> usize {
    let (w, h) = a.dimensions();
    a.enumerate_pixels()
        .zip(b.pixels())
        .filter(|((x, y, _), _)| *x > w / 5 && *x < 4 * w / 5 && *y > h / 5 && *y < 4 * h / 5)
        .filter(|((_, _, p), q)| (0..3).any(|k| (p[k] as i32 - q[k] as i32).abs() > 12))
        .count()
}

fn mouth_region_area(img: &image::RgbaImage) -> usize {
    mouth_region_count(img, |_| true)
}

fn is_tag(p: &image::Rgba<u8>, channel: usize) -> bool {
    (0..3).all(|k| k == channel || p[channel] as i32 > p[k] as i32 + 60)
}

/// Lipreaders tell visemes apart by the mouth: in the close-up of the default head, each viseme
/// differs from the ones beside it in `VISEME_NAMES` order over a good part of the mouth region.
#[test]
fn default_head_visemes_differ_from_their_neighbours_in_the_mouth_close_up() {
    let Some(ctx) = gpu() else { return };
    let images = mouth_close_ups(&ctx, default_head());
    let area = mouth_region_area(&images[0]);
    for (a, b) in (0..VISEME_COUNT).zip(1..VISEME_COUNT) {
        let diff = mouth_region_difference(&images[a], &images[b]);
        println!(
            "{} -> {}: {diff} of {area} mouth pixels differ",
            VISEME_NAMES[a], VISEME_NAMES[b]
        );
        assert!(
            diff * 20 >= area,
            "{} and {} look alike in the mouth close-up: {diff} of {area} pixels differ",
            VISEME_NAMES[a],
            VISEME_NAMES[b]
        );
    }
}

/// What shows inside the mouth: no teeth or tongue with the lips shut (sil, PP), the upper teeth
/// over the lower lip in FF, the tongue tip between the teeth in TH, teeth in the open and
/// spread visemes.
#[test]
fn default_head_shows_teeth_and_tongue_where_lipreaders_look_for_them() {
    let Some(ctx) = gpu() else { return };
    let images = mouth_close_ups(&ctx, &tagged_default_head());
    let area = mouth_region_area(&images[0]);
    let teeth: Vec<usize> = images
        .iter()
        .map(|img| mouth_region_count(img, |p| is_tag(p, 2)))
        .collect();
    let tongue: Vec<usize> = images
        .iter()
        .map(|img| mouth_region_count(img, |p| is_tag(p, 1)))
        .collect();
    for v in 0..VISEME_COUNT {
        println!(
            "{}: teeth {} tongue {} of {area} pixels",
            VISEME_NAMES[v], teeth[v], tongue[v]
        );
    }
    let at = |name| lipcall::vocab::Viseme::from_name(name).unwrap().index();
    for shut in ["sil", "PP"] {
        assert!(
            teeth[at(shut)] * 400 < area && tongue[at(shut)] == 0,
            "{shut} should show neither teeth ({}) nor tongue ({})",
            teeth[at(shut)],
            tongue[at(shut)]
        );
    }
    assert!(
        teeth[at("FF")] * 40 >= area,
        "FF: upper teeth over the lower lip"
    );
    assert!(
        tongue[at("TH")] * 100 >= area,
        "TH: the tongue between the teeth ({} pixels)",
        tongue[at("TH")]
    );
    for open in ["aa", "E", "I", "SS", "O"] {
        assert!(teeth[at(open)] * 40 >= area, "{open}: teeth visible");
    }
}

/// How far the lips part at the middle of the mouth, in eye widths (the outer extent of the two
/// eyeballs, about the outer eye corners): real speakers reach 0.10 to 0.22.
#[test]
fn default_head_opens_its_lips_like_a_speaker() {
    let head = default_head();
    let skin = head
        .primitives
        .iter()
        .position(|p| p.name == "skin")
        .unwrap();
    let offset: usize = head.primitives[..skin]
        .iter()
        .map(|p| p.vertices.len())
        .sum();
    let eye_x = |name: &str| {
        let p = head.primitives.iter().find(|p| p.name == name).unwrap();
        let xs = p.vertices.iter().map(|v| v.position[0]);
        (
            xs.clone().fold(f32::INFINITY, f32::min),
            xs.fold(f32::NEG_INFINITY, f32::max),
        )
    };
    let eye_width = eye_x("eyeLeft").1 - eye_x("eyeRight").0;
    assert!((0.07..0.12).contains(&eye_width), "{eye_width}");
    // The lips' vertices at the middle of the mouth: lip-red, within 1.5 mm of x = 0.
    let lips: Vec<usize> = head.primitives[skin]
        .vertices
        .iter()
        .enumerate()
        .filter(|(_, v)| {
            let [r, g, _, _] = v.color;
            r > 0.2 && r > 3.0 * g && v.position[0].abs() < 0.0015
        })
        .map(|(i, _)| offset + i)
        .collect();
    assert!(lips.len() > 10, "{} lip vertices at the middle", lips.len());
    // The opening is the largest vertical gap between them.
    let gap = |name: &str| {
        let blended = head.blend_cpu(&VisemeWeights::single(name).unwrap());
        let mut ys: Vec<f32> = lips.iter().map(|&i| blended[i].position[1]).collect();
        ys.sort_by(f32::total_cmp);
        ys.windows(2).map(|w| w[1] - w[0]).fold(0.0, f32::max) / eye_width
    };
    let gaps: Vec<(&str, f32)> = VISEME_NAMES.iter().map(|&n| (n, gap(n))).collect();
    println!("lip gap in eye widths: {gaps:?}");
    let of = |name: &str| gaps.iter().find(|(n, _)| *n == name).unwrap().1;
    assert!(of("aa") >= 0.2, "aa opens {} eye widths", of("aa"));
    assert!(of("aa") <= 0.3, "aa opens {} eye widths", of("aa"));
    for (name, least) in [("O", 0.12), ("E", 0.09), ("U", 0.04), ("I", 0.03)] {
        assert!(of(name) >= least, "{name} opens {} eye widths", of(name));
    }
    // Shut lips leave no more than the spacing of the lips' vertex rows.
    for shut in ["sil", "PP"] {
        assert!(of(shut) < 0.03, "{shut} opens {} eye widths", of(shut));
    }
}
