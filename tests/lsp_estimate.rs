//! The walker's LSPs against an independent estimate: an LPC analysis of the decoded audio
//! (windowed autocorrelation, Levinson-Durbin, LSP root search), on voiced frames.

mod common;

use common::*;
use lipcall::codec::speex::codec::EncoderConfig;
use lipcall::codec::speex::stream;

const ORDER: usize = 10;

fn mean_abs_diff(a: &[f64], b: &[f32; ORDER]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(&x, &y)| (x - f64::from(y)).abs())
        .sum::<f64>()
        / ORDER as f64
}

#[test]
fn walker_lsps_agree_with_an_lpc_analysis_of_the_decoded_audio() {
    let dir = tempfile::tempdir().unwrap();
    let inputs = [
        timit_8k(dir.path(), "dr3-falk0", "sa2"),
        timit_8k(dir.path(), "dr4-maeb0", "sx180"),
        demo_8k(dir.path()),
    ];
    let mut per_offset = [0.0f64; 3];
    // Control: the same estimate against a frame half a second away must agree far worse.
    let mut unrelated = 0.0f64;
    let mut counted = 0usize;
    let mut all = Vec::new();
    for input in &inputs {
        let pcm = lipcall::audio::wav::read_narrowband(input).unwrap();
        let spx = stream::encode(
            &pcm,
            EncoderConfig {
                quality: 8,
                ..Default::default()
            },
        )
        .unwrap();
        let decoded = stream::decode(&spx, false).unwrap();
        let frames = &decoded.features;
        for n in 1..frames.len().saturating_sub(1) {
            // Voiced, steady frames: loud, and a spectrum that changes little around them.
            if frames[n].energy_db < -35.0 || frames[n].mode.is_none() {
                continue;
            }
            let drift = mean_abs_diff(&frames[n - 1].lsp.map(f64::from), &frames[n + 1].lsp);
            if drift > 0.05 {
                continue;
            }
            // A 240-sample window centred on the row's 160 samples.
            let Some(lpc) = lpc::estimate(&decoded.pcm, n as i64 * 160 - 40, 240, ORDER, 8000.0)
            else {
                continue;
            };
            for (slot, k) in [n - 1, n, n + 1].into_iter().enumerate() {
                per_offset[slot] += mean_abs_diff(&lpc, &frames[k].lsp);
            }
            unrelated += mean_abs_diff(&lpc, &frames[(n + 25) % frames.len()].lsp);
            all.push(mean_abs_diff(&lpc, &frames[n].lsp));
            counted += 1;
        }
    }
    assert!(counted > 100, "only {counted} voiced steady frames");
    let mean = per_offset.map(|s| s / counted as f64);
    let unrelated = unrelated / counted as f64;
    all.sort_by(f64::total_cmp);
    let median = all[all.len() / 2];
    println!(
        "{counted} frames: mean |LPC - walker| per LSP: previous row {:.4}, same row {:.4}, next row {:.4} rad; median same row {median:.4}; unrelated frame {unrelated:.4}",
        mean[0], mean[1], mean[2]
    );
    // Tolerance: the 30-bit quantiser alone errs by about 0.02 rad; the decoded signal adds
    // pitch harmonics and excitation noise that pull LPC peaks, and our window is not the
    // encoder's. 0.08 rad is 100 Hz at 8 kHz, a fifth of the typical spacing of two LSPs.
    assert!(
        mean[1] <= mean[0] && mean[1] <= mean[2],
        "the same row fits best"
    );
    assert!(
        unrelated > 2.0 * mean[1],
        "control: unrelated {unrelated:.4} rad"
    );
    assert!(
        mean[1] < 0.08,
        "same-row mean difference {:.4} rad",
        mean[1]
    );
    assert!(median < 0.06, "median {median:.4} rad");
}
