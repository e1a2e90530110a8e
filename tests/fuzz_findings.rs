//! What the fuzz targets in tools/fuzz found (docs/fuzzing.md), each kept as the smallest input
//! that shows it: the parser now gives a clear error (or a sound result) where it panicked,
//! hung or returned something its callers could not use.

mod common;

use lipcall::audio::wav;
use lipcall::lipsync::decompose::decompose_track;
use lipcall::lipsync::markers::MarkerTrack;
use lipcall::render::gltf_load::load_head_from_slice;
use lipcall::vocab::VisemeSet;
use lipcall::vocab::ordered_lsp;

/// A one-triangle glTF head with a `viseme_aa` target moving each vertex by `delta` in y.
fn head_with_target(positions: [[f32; 3]; 3], delta: f32) -> Vec<u8> {
    let mut data = Vec::new();
    for p in positions {
        data.extend(p.iter().flat_map(|c| c.to_le_bytes()));
    }
    for _ in 0..3 {
        data.extend([0.0, delta, 0.0f32].iter().flat_map(|c| c.to_le_bytes()));
    }
    let accessor = |view: usize, bounds: &str| {
        format!(r#"{{"bufferView":{view},"componentType":5126,"count":3,"type":"VEC3"{bounds}}}"#)
    };
    let (mut min, mut max) = ([f32::MAX; 3], [f32::MIN; 3]);
    for p in positions {
        for k in 0..3 {
            min[k] = min[k].min(p[k]);
            max[k] = max[k].max(p[k]);
        }
    }
    let bounds = format!(r#","min":{min:?},"max":{max:?}"#);
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
"meshes":[{{"extras":{{"targetNames":["viseme_aa"]}},
  "primitives":[{{"attributes":{{"POSITION":0}},"targets":[{{"POSITION":1}}]}}]}}],
"accessors":[{},{}],
"bufferViews":[{{"buffer":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":36}}],
"buffers":[{{"byteLength":72,"uri":"data:application/octet-stream;base64,{}"}}]}}"#,
        accessor(0, &bounds),
        accessor(1, ""),
        common::base64(&data)
    )
    .into_bytes()
}

const TRIANGLE: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]];

/// gltf target: a head whose morph target moves vertices by a finite 1e36 loaded, and framing
/// it summed the motion into an infinite mouth position (a camera of NaNs).
#[test]
fn a_head_with_absurd_coordinates_is_refused() {
    let head = load_head_from_slice(&head_with_target(TRIANGLE, 0.02)).unwrap();
    let frame = head.face_frame();
    assert!(frame.mouth.is_finite() && frame.head_max.is_finite());

    let e = load_head_from_slice(&head_with_target(TRIANGLE, 1e36)).unwrap_err();
    assert!(e.to_string().contains("morph target"), "{e}");
    let far = TRIANGLE.map(|[x, y, z]| [x + 3e37, y, z]);
    let e = load_head_from_slice(&head_with_target(far, 0.02)).unwrap_err();
    assert!(e.to_string().contains("POSITION"), "{e}");
}

/// gltf target: a GLB header whose length is under its own 12 bytes made the gltf crate
/// subtract with overflow (a panic in debug builds, which tests and `cargo run` are).
#[test]
fn a_glb_shorter_than_its_header_is_refused() {
    for length in [0u32, 11] {
        let mut glb = b"glTF".to_vec();
        glb.extend(2u32.to_le_bytes());
        glb.extend(length.to_le_bytes());
        glb.extend(b"\x02\0\0\0JSON{}\0\0");
        let e = load_head_from_slice(&glb).unwrap_err();
        assert!(e.to_string().contains("less than the header"), "{e}");
    }
}

/// gltf target: a primitive whose POSITION names an accessor that does not exist panicked
/// (index out of bounds) inside the gltf crate's own validation, in release builds too.
#[test]
fn a_position_naming_a_missing_accessor_is_refused() {
    let good = String::from_utf8(head_with_target(TRIANGLE, 0.02)).unwrap();
    let bad = good.replace(
        r#""attributes":{"POSITION":0}"#,
        r#""attributes":{"POSITION":7}"#,
    );
    assert_ne!(good, bad);
    let e = load_head_from_slice(bad.as_bytes()).unwrap_err();
    assert!(e.to_string().contains("POSITION names accessor 7"), "{e}");
}

/// gltf target: a morph target lipcall does not use, whose accessor is not VEC3, tripped the gltf
/// crate's assertion on element size (debug builds): its reader opened every target's accessors,
/// unchecked. Unused targets are now never read; the head loads.
#[test]
fn an_unused_morph_target_of_another_type_is_not_read() {
    let good = String::from_utf8(head_with_target(TRIANGLE, 0.02)).unwrap();
    let odd = good
        .replace(r#"["viseme_aa"]"#, r#"["viseme_aa","notAShape"]"#)
        .replace(
            r#""targets":[{"POSITION":1}]"#,
            r#""targets":[{"POSITION":1},{"POSITION":2}]"#,
        )
        .replace(
            "],\n\"bufferViews\"",
            r#",{"bufferView":1,"componentType":5126,"count":3,"type":"VEC2"}],"bufferViews""#,
        );
    assert_eq!(odd.matches("VEC2").count(), 1, "{odd}");
    let head = load_head_from_slice(odd.as_bytes()).unwrap();
    assert_eq!(head.primitives.len(), 1);
}

/// markers target: two finite coordinates 6e38 apart made an infinite point once the origin
/// marker was subtracted, which the decomposition then fitted.
#[test]
fn a_marker_too_far_from_the_origin_is_refused() {
    let track = "frame,nose_x,nose_y,lip_x,lip_y\n1,-3e38,0,3e38,0\n2,0,0,1,1\n";
    let absolute = MarkerTrack::parse(track, None).unwrap();
    assert!(absolute.points.frames().flatten().all(|v| v.is_finite()));
    let e = MarkerTrack::parse(track, Some("nose")).unwrap_err();
    assert_eq!(
        e.to_string(),
        "line 2: marker lip is too far from the origin marker"
    );
}

/// markers target (by its "weights convex" property): a frame fitted from the previous frame's
/// weights, whose f32 sum misses 1 by rounding, came out NaN for every viseme. The start's
/// deficit left the weight of the shape it sat on just under 1, with a curvature of rounding
/// noise, and a step of noise over noise zeroed every weight: `decompose --weights` wrote NaN
/// rows and an Eq. 1 error of NaN.
#[test]
fn a_frame_fitted_from_rounded_weights_stays_convex() {
    let track = "frame,nose_x,nose_y,lip_x,lip_y,chin_x,chin_y\n\
        11,100,50,101,0,101,140\n12,10,50,100,85,100,130\n11,100,56,100,85,100,130\n\
        0,15,0,100,80,100,-120\n12,0,05,010100,80,100,120\n10,100,50,10,0,101,10\n\
        11,1,0,101,90,0,1\n12,0,05,010,85,0,1\n";
    let track = MarkerTrack::parse(track, None).unwrap();
    let shapes = track
        .key_frame_shapes("viseme,frame\nPP,11\naa,12\n")
        .unwrap();
    let set = VisemeSet::new(shapes.visemes()).unwrap();
    let weights =
        decompose_track(&track.points, &shapes, &set, &track.points.point_sigmas()).unwrap();
    assert_eq!(weights.len(), 8);
    for row in &weights {
        let sum: f32 = row.iter().sum();
        assert!(
            row.iter().all(|w| w.is_finite() && *w >= 0.0) && (sum - 1.0).abs() < 1e-3,
            "{weights:?}"
        );
    }
    // The frame that broke lies nearer the open key frame's lips than the closed one's.
    assert!(weights[3][1] > 0.9, "{weights:?}");
}

/// silk_walker target: a SILK frame whose wideband NLSFs map to two or more narrowband LSPs
/// near pi made `ordered_lsp` panic (`clamp` with its lower bound rounded a hair above its
/// upper one), in the receiver, for any peer's packet.
#[test]
fn lsps_at_the_top_of_the_band_are_spaced_not_a_panic() {
    let pi = std::f32::consts::PI;
    for top in [pi - 0.01, pi, 3.2, 100.0, f32::INFINITY] {
        let mut lsp = [top; 10];
        lsp[0] = 0.3;
        let ordered = ordered_lsp(lsp);
        assert!(ordered.windows(2).all(|w| w[0] < w[1]), "{ordered:?}");
        assert!(ordered[0] > 0.0 && ordered[9] < pi, "{ordered:?}");
    }
}

fn float_wav(dir: &std::path::Path, samples: &[f32]) -> std::path::PathBuf {
    let path = dir.join("float.wav");
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: 22_050,
        bits_per_sample: 32,
        sample_format: hound::SampleFormat::Float,
    };
    let mut writer = hound::WavWriter::create(&path, spec).unwrap();
    for &s in samples {
        writer.write_sample(s).unwrap();
    }
    writer.finalize().unwrap();
    path
}

/// wav target: float samples that are not numbers, or finite ones near f32's limit, overflowed
/// the resampler's FFT into NaN and rubato panicked (`encode`, `animate`, training).
#[test]
fn float_wavs_out_of_range_are_clipped_and_nan_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let loud: Vec<f32> = (0..4000)
        .map(|i| if (i / 100) % 2 == 0 { 3e38 } else { -6e37 })
        .collect();
    let pcm = wav::read_narrowband(&float_wav(dir.path(), &loud)).unwrap();
    assert!(pcm.len() > 1000);
    assert!(
        pcm.iter().any(|&s| s.unsigned_abs() > 30_000),
        "clipped to full scale"
    );

    let mut broken = vec![0.25f32; 4000];
    broken[1234] = f32::NAN;
    let e = wav::read_narrowband(&float_wav(dir.path(), &broken)).unwrap_err();
    assert!(e.to_string().contains("sample 1234 is not a number"), "{e}");
}
