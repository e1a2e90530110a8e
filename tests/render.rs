//! Head renderer tests. GPU tests run on whatever adapter wgpu finds (the software lavapipe /
//! llvmpipe one on CI) and are skipped, with a printed reason, only when there is none.

use std::sync::OnceLock;

use lipcall::render::glb_write::glb_container;
use lipcall::render::gltf_load::load_head_from_slice;
use lipcall::render::head::TargetSource;
use lipcall::render::offscreen::{FrameOptions, GpuContext, OffscreenRenderer, WeightTrack};
use lipcall::render::{Framing, HeadModel, RenderError, VISEME_NAMES, VisemeWeights};
use serde_json::json;

fn default_head() -> &'static HeadModel {
    static HEAD: OnceLock<HeadModel> = OnceLock::new();
    HEAD.get_or_init(|| lipcall::render::default_head().expect("bundled head loads"))
}

fn gpu() -> Option<GpuContext> {
    match GpuContext::new_headless() {
        Ok(ctx) => Some(ctx),
        Err(e) => {
            println!("SKIPPED: no GPU adapter for the head renderer: {e}");
            None
        }
    }
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
    let head = default_head();
    let mut offscreen = mouth_renderer(&ctx, head);
    // A convex mix touching several shapes, and single shapes.
    let mut mixes =
        vec![VisemeWeights::from_named([("aa", 0.5), ("U", 0.3), ("PP", 0.2)]).unwrap()];
    mixes.push(VisemeWeights::single("TH").unwrap());
    mixes.push(VisemeWeights::neutral());
    for weights in mixes {
        offscreen.render(&ctx, &weights).unwrap();
        let cpu = head.blend_cpu(&weights);
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
    // jawOpen is in the recipe of aa; PP (press/roll/close) has none of these shapes.
    let aa = lipcall::render::viseme_index("aa").unwrap();
    assert!(!head.primitives[0].targets[aa].is_empty());
    assert!(head.missing_visemes.contains(&"PP".to_owned()));
    // Node scale 2 applies to positions and deltas.
    let blended = head.blend_cpu(&VisemeWeights::single("aa").unwrap());
    let min_y = blended
        .iter()
        .map(|v| v.position[1])
        .fold(f32::INFINITY, f32::min);
    assert!((min_y - (-0.2 - 2.0 * 0.05 * 0.75)).abs() < 1e-5, "{min_y}");

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
        let v = lipcall::render::viseme_index(name).unwrap();
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
    assert!(matches!(err, RenderError::Io { .. }));
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
