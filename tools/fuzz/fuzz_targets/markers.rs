//! Marker recordings as `decompose --markers M --key-frames K` reads them: the marker CSV (with
//! and without an origin marker), the key-frame CSV against it, and the decomposition of the
//! track onto the key frames' shapes. The input is the marker CSV, a NUL byte, the key-frame
//! CSV. No panic; every point of a track is a finite number; the weights are convex.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lipcall::lipsync::decompose::decompose_track;
use lipcall::lipsync::markers::MarkerTrack;
use lipcall::lipsync::visemes::VisemeSet;

fuzz_target!(|data: &[u8]| {
    let (track_bytes, keys_bytes) = match data.iter().position(|&b| b == 0) {
        Some(nul) => (&data[..nul], &data[nul + 1..]),
        None => (data, &[][..]),
    };
    let Ok(track_text) = std::str::from_utf8(track_bytes) else {
        return;
    };
    let Ok(track) = MarkerTrack::parse(track_text, None) else {
        return;
    };
    if let Some(origin) = track.marker_names.first()
        && let Ok(relative) = MarkerTrack::parse(track_text, Some(origin))
    {
        assert!(relative.points.frames().flatten().all(|v| v.is_finite()));
    }
    assert_eq!(track.frame_numbers.len(), track.points.len());
    assert!(track.points.frames().flatten().all(|v| v.is_finite()));
    let Ok(keys_text) = std::str::from_utf8(keys_bytes) else {
        return;
    };
    let Ok(shapes) = track.key_frame_shapes(keys_text) else {
        return;
    };
    let Ok(set) = VisemeSet::new(shapes.visemes()) else {
        return;
    };
    let sigmas = track.points.point_sigmas();
    let Ok(weights) = decompose_track(&track.points, &shapes, &set, &sigmas) else {
        return;
    };
    for row in &weights {
        let sum: f32 = row.iter().sum();
        assert!(
            row.iter().all(|w| w.is_finite() && *w >= 0.0) && (sum - 1.0).abs() < 1e-3,
            "weights not convex: {row:?}"
        );
    }
});
