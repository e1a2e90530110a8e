//! Golden features for one fixed file: tests/data/golden-q8.spx, the first two seconds of
//! assets/speech/demo.wav encoded by speexenc 1.2.1 at quality 8. The LSPs were checked
//! bit-exact against libspeex's own decoder state (tests/walker.rs does that on every frame).

use lipcall::codec::speex::stream;

const GOLDEN: [(usize, u8, [f32; 10], f32); 4] = [
    (
        20,
        5,
        [
            0.289062, 0.406251, 0.652345, 0.767581, 0.962894, 1.769528, 1.903318, 2.073241,
            2.574214, 2.706052,
        ],
        -19.78,
    ),
    (
        40,
        5,
        [
            0.257812, 0.337893, 0.423833, 1.052734, 1.490232, 1.653318, 1.996091, 2.098631,
            2.604488, 2.736325,
        ],
        -18.02,
    ),
    (
        60,
        5,
        [
            0.242188, 0.341799, 0.439457, 1.060546, 1.476559, 1.653318, 1.996091, 2.098631,
            2.604488, 2.736325,
        ],
        -15.13,
    ),
    (
        80,
        5,
        [
            0.400389, 0.505860, 0.681641, 0.804690, 0.917973, 1.740231, 2.028317, 2.202146,
            2.484371, 2.654295,
        ],
        -15.47,
    ),
];

#[test]
fn golden_file_gives_golden_features() {
    let bytes = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/golden-q8.spx"
    ))
    .unwrap();
    let decoded = stream::decode(&bytes, false).unwrap();
    // speexdec's end-trimming arithmetic keeps 40 samples past the input here; so do we.
    assert_eq!(decoded.pcm.len(), 16_040);
    assert_eq!(decoded.features.len(), 101);
    for (row, mode, lsp, energy) in GOLDEN {
        let f = &decoded.features[row];
        assert_eq!(f.mode, Some(mode), "row {row}");
        for (got, want) in f.lsp.iter().zip(lsp) {
            assert!((got - want).abs() < 1e-6, "row {row}: {:?}", f.lsp);
        }
        assert!(
            (f.energy_db - energy).abs() < 0.01,
            "row {row}: {} dB",
            f.energy_db
        );
    }
}

#[test]
fn round_trip_rows_line_up_with_the_input() {
    // A 1 kHz burst from 0.5 s to 1.0 s: the loud rows must be exactly rows 25..50.
    let pcm: Vec<i16> = (0..16_000)
        .map(|i| {
            let on = (4000..8000).contains(&i);
            if on {
                (8000.0 * (i as f32 * std::f32::consts::FRAC_PI_4).sin()) as i16
            } else {
                0
            }
        })
        .collect();
    let decoded =
        stream::round_trip(&pcm, lipcall::codec::speex::codec::EncoderConfig::default()).unwrap();
    let loud: Vec<usize> = decoded
        .features
        .iter()
        .enumerate()
        .filter(|(_, f)| f.energy_db > -30.0)
        .map(|(n, _)| n)
        .collect();
    assert_eq!(loud.first(), Some(&25), "{loud:?}");
    assert!(matches!(loud.last(), Some(&49) | Some(&50)), "{loud:?}");
}
