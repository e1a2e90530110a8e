//! An independent LPC analysis for checking LSPs and NLSFs read from a bitstream: a Hamming
//! window, autocorrelation with a 40 Hz lag window and a noise floor, Levinson-Durbin and a
//! fine grid search for the roots, all in f64 and of any order.

use std::f64::consts::PI;

/// Windowed autocorrelation of `x` at lags 0..=order, with a 40 Hz Gaussian lag window and a
/// white-noise floor, as speech coders condition it.
pub fn autocorrelation(x: &[f64], order: usize, rate: f64) -> Vec<f64> {
    let n = x.len();
    let windowed: Vec<f64> = x
        .iter()
        .enumerate()
        .map(|(i, &v)| v * (0.54 - 0.46 * (2.0 * PI * i as f64 / (n - 1) as f64).cos()))
        .collect();
    (0..=order)
        .map(|lag| {
            let lag_window = (-0.5 * (2.0 * PI * 40.0 * lag as f64 / rate).powi(2)).exp();
            let r: f64 = (lag..n).map(|i| windowed[i] * windowed[i - lag]).sum();
            r * lag_window * if lag == 0 { 1.0001 } else { 1.0 }
        })
        .collect()
}

/// Levinson-Durbin: predictor a[0..=order] with a[0] = 1 and A(z) = sum a_k z^-k.
pub fn levinson(r: &[f64]) -> Vec<f64> {
    let order = r.len() - 1;
    let mut a = vec![0.0; order + 1];
    a[0] = 1.0;
    let mut error = r[0];
    for i in 1..=order {
        let acc: f64 = (1..i).map(|j| a[j] * r[i - j]).sum::<f64>() + r[i];
        let k = -acc / error;
        let previous = a.clone();
        for j in 1..i {
            a[j] = previous[j] + k * previous[i - j];
        }
        a[i] = k;
        error *= 1.0 - k * k;
    }
    a
}

/// Roots of P(z) = A(z) + z^-(p+1) A(1/z) and Q(z) = A(z) - z^-(p+1) A(1/z) on the unit
/// circle, strictly inside (0, pi), sorted.
pub fn lsp_from_lpc(a: &[f64]) -> Vec<f64> {
    let order = a.len() - 1;
    let coefficient = |k: usize| if k <= order { a[k] } else { 0.0 };
    let p: Vec<f64> = (0..=order + 1)
        .map(|k| coefficient(k) + coefficient(order + 1 - k))
        .collect();
    let q: Vec<f64> = (0..=order + 1)
        .map(|k| coefficient(k) - coefficient(order + 1 - k))
        .collect();
    // e^{j (p+1)/2 w} P(e^{jw}) is real and e^{j (p+1)/2 w} Q(e^{jw}) imaginary: sums of
    // cos and sin of (half - k) w, the angles stepped by rotation.
    let half = (order + 1) as f64 / 2.0;
    let rotated_sum = |coefficients: &[f64], w: f64, imaginary: bool| -> f64 {
        let (step_sin, step_cos) = w.sin_cos();
        let (mut sin, mut cos) = (half * w).sin_cos();
        let mut sum = 0.0;
        for &c in coefficients {
            sum += c * if imaginary { sin } else { cos };
            (sin, cos) = (
                sin * step_cos - cos * step_sin,
                cos * step_cos + sin * step_sin,
            );
        }
        sum
    };
    let p_real = |w: f64| rotated_sum(&p, w, false);
    let q_imag = |w: f64| rotated_sum(&q, w, true);
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

/// The LSPs (radians) of an LPC analysis of `len` samples from `start`.
pub fn estimate(pcm: &[i16], start: i64, len: usize, order: usize, rate: f64) -> Option<Vec<f64>> {
    let s = usize::try_from(start).ok()?;
    let x: Vec<f64> = pcm.get(s..s + len)?.iter().map(|&v| f64::from(v)).collect();
    let roots = lsp_from_lpc(&levinson(&autocorrelation(&x, order, rate)));
    (roots.len() == order).then_some(roots)
}
