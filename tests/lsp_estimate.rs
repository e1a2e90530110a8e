//! The walker's LSPs against an independent estimate: an LPC analysis of the decoded audio
//! (windowed autocorrelation, Levinson-Durbin, LSP root search), on voiced frames.

mod common;

use std::f64::consts::PI;

use common::*;
use lipcall::codec::speex::codec::EncoderConfig;
use lipcall::codec::speex::stream;

const ORDER: usize = 10;

fn autocorrelation(x: &[f64]) -> [f64; ORDER + 1] {
    let n = x.len();
    let windowed: Vec<f64> = x
        .iter()
        .enumerate()
        .map(|(i, &v)| v * (0.54 - 0.46 * (2.0 * PI * i as f64 / (n - 1) as f64).cos()))
        .collect();
    std::array::from_fn(|lag| {
        // A 40 Hz Gaussian lag window and a white-noise floor, as speech coders use.
        let lag_window = (-0.5 * (2.0 * PI * 40.0 * lag as f64 / 8000.0).powi(2)).exp();
        let r: f64 = (lag..n).map(|i| windowed[i] * windowed[i - lag]).sum();
        r * lag_window * if lag == 0 { 1.0001 } else { 1.0 }
    })
}

/// Levinson-Durbin: predictor a[0..=ORDER] with a[0] = 1 and A(z) = sum a_k z^-k.
fn levinson(r: &[f64; ORDER + 1]) -> [f64; ORDER + 1] {
    let mut a = [0.0; ORDER + 1];
    a[0] = 1.0;
    let mut error = r[0];
    for i in 1..=ORDER {
        let acc: f64 = (1..i).map(|j| a[j] * r[i - j]).sum::<f64>() + r[i];
        let k = -acc / error;
        let previous = a;
        for j in 1..i {
            a[j] = previous[j] + k * previous[i - j];
        }
        a[i] = k;
        error *= 1.0 - k * k;
    }
    a
}

/// Roots of P(z) = A(z) + z^-11 A(1/z) and Q(z) = A(z) - z^-11 A(1/z) on the unit circle.
fn lsp_from_lpc(a: &[f64; ORDER + 1]) -> Vec<f64> {
    let coefficient = |k: usize| if k <= ORDER { a[k] } else { 0.0 };
    let p: Vec<f64> = (0..=ORDER + 1)
        .map(|k| coefficient(k) + coefficient(ORDER + 1 - k))
        .collect();
    let q: Vec<f64> = (0..=ORDER + 1)
        .map(|k| coefficient(k) - coefficient(ORDER + 1 - k))
        .collect();
    // e^{j 5.5 w} P(e^{jw}) is real and e^{j 5.5 w} Q(e^{jw}) imaginary: evaluate those.
    let half = (ORDER + 1) as f64 / 2.0;
    let p_real = |w: f64| -> f64 {
        (0..=ORDER + 1)
            .map(|k| p[k] * ((half - k as f64) * w).cos())
            .sum()
    };
    let q_imag = |w: f64| -> f64 {
        (0..=ORDER + 1)
            .map(|k| q[k] * ((half - k as f64) * w).sin())
            .sum()
    };
    let mut roots = Vec::new();
    for f in [&p_real as &dyn Fn(f64) -> f64, &q_imag] {
        let steps = 4000;
        let mut lo = 1e-6;
        let mut f_lo = f(lo);
        for s in 1..steps {
            let hi = PI * s as f64 / steps as f64;
            let f_hi = f(hi);
            if f_lo.signum() != f_hi.signum() {
                let (mut a0, mut b0) = (lo, hi);
                for _ in 0..50 {
                    let m = 0.5 * (a0 + b0);
                    if f(m).signum() == f(a0).signum() {
                        a0 = m;
                    } else {
                        b0 = m;
                    }
                }
                roots.push(0.5 * (a0 + b0));
            }
            lo = hi;
            f_lo = f_hi;
        }
    }
    roots.sort_by(f64::total_cmp);
    roots
}

fn estimate(pcm: &[i16], start: i64, len: usize) -> Option<Vec<f64>> {
    let s = usize::try_from(start).ok()?;
    let x: Vec<f64> = pcm.get(s..s + len)?.iter().map(|&v| f64::from(v)).collect();
    let roots = lsp_from_lpc(&levinson(&autocorrelation(&x)));
    (roots.len() == ORDER).then_some(roots)
}

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
            let Some(lpc) = estimate(&decoded.pcm, n as i64 * 160 - 40, 240) else {
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
