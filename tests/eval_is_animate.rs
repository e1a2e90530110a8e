//! `evaluate` scores exactly the weights `animate` writes: both run a stream through the one
//! per-peer pipeline, so a score describes what the app shows.

use std::path::PathBuf;

use lipcall::commands::animate::{AnimateArgs, receiver_features, weight_track};
use lipcall::lipsync::ModelAnimator;
use lipcall::lipsync::mouth::VisemeShapes;
use lipcall::train::corpus::{PhoneSegment, PreparedUtterance, targets_from_phones};
use lipcall::train::eval::{NETWORK_ROW, evaluate_prepared, predict, score};

fn demo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/speech/demo.wav")
}

/// Phones alternating over the whole stream (16 kHz samples), so the scores are not trivial.
fn utterance(features: Vec<lipcall::vocab::FrameFeatures>) -> PreparedUtterance {
    let samples = features.len() as u64 * 320 + 160;
    let phones: Vec<PhoneSegment> = (0..samples / 3200)
        .map(|i| PhoneSegment {
            start: i * 3200,
            end: if (i + 1) * 3200 + 3200 > samples {
                samples
            } else {
                (i + 1) * 3200
            },
            phone: ["aa", "m", "iy", "f", "uw", "h#"][i as usize % 6].into(),
        })
        .collect();
    let targets = targets_from_phones(&phones, 16_000, samples as u32).unwrap();
    assert_eq!(targets.len(), features.len());
    PreparedUtterance {
        speaker: "demo".into(),
        id: "demo".into(),
        features,
        targets,
        weight: 1.0,
    }
}

#[test]
fn evaluate_scores_the_weights_animate_writes() {
    let args = AnimateArgs {
        input: demo(),
        weights: None,
        frames: None,
        head: None,
        fps: 50,
        mouth_close_up: false,
        visemes: None,
        model: None,
        articulation: None,
        baseline_jaw: false,
        closure_bias: 0.0,
        life: false,
        seed: 0,
        drive: Default::default(),
    };
    let animated = weight_track(&args).unwrap();
    let (_, _, features) = receiver_features(&args.input).unwrap();
    let model = lipcall::lipsync::default_model();
    let utterances = [utterance(features)];

    let predicted = predict(&mut ModelAnimator::new(&model), &utterances);
    assert_eq!(predicted, vec![animated.rows.concat()]);

    let shapes = VisemeShapes::point_model();
    let report = evaluate_prepared(&model, &utterances, &["demo".into()], &shapes).unwrap();
    let from_animate = score(
        &animated.visemes,
        &shapes,
        &utterances,
        &[animated.rows.concat()],
    )
    .unwrap();
    assert_eq!(report.scores(NETWORK_ROW), Some(&from_animate));
}
