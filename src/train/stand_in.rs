//! TEST ONLY stand-in for the codec: LPC -> LSP and frame energy computed straight from the
//! audio, so the trainer can be exercised before the Speex feature extractor lands. The real
//! pipeline passes the decoder's own features through `corpus::FeatureFn`.

use std::f64::consts::PI;
use std::path::Path;

use crate::train::corpus::BoxError;
use crate::vocab::FrameFeatures;

const ORDER: usize = 10;
const FRAME: usize = 160;
const WINDOW: usize = 240;

fn read_mono_8k(path: &Path) -> Result<Vec<f64>, BoxError> {
    let mut reader = hound::WavReader::open(path)?;
    if reader.spec().sample_rate != 16000 || reader.spec().channels != 1 {
        return Err("stand-in features read 16 kHz mono only".into());
    }
    let samples: Vec<f64> = reader
        .samples::<i16>()
        .map(|s| s.map(|s| s as f64 / 32768.0))
        .collect::<Result<_, _>>()?;
    // Windowed-sinc low-pass at 3.6 kHz, then every other sample.
    let taps: Vec<f64> = (-15i32..=15)
        .map(|n| {
            let x = n as f64;
            let sinc = if n == 0 {
                0.45
            } else {
                (0.45 * PI * x).sin() / (PI * x)
            };
            sinc * (0.54 + 0.46 * (PI * x / 16.0).cos())
        })
        .collect();
    Ok((0..samples.len() / 2)
        .map(|i| {
            let centre = 2 * i as i64;
            taps.iter()
                .enumerate()
                .map(|(k, t)| {
                    let j = centre + k as i64 - 15;
                    if j < 0 || j as usize >= samples.len() {
                        0.0
                    } else {
                        t * samples[j as usize]
                    }
                })
                .sum()
        })
        .collect())
}

fn lpc(window: &[f64]) -> [f64; ORDER + 1] {
    let mut r = [0.0; ORDER + 1];
    for (lag, r) in r.iter_mut().enumerate() {
        *r = window.iter().zip(&window[lag..]).map(|(a, b)| a * b).sum();
    }
    r[0] = r[0] * 1.0001 + 1e-9;
    for (lag, r) in r.iter_mut().enumerate().skip(1) {
        *r *= (-0.5 * (2.0 * PI * 60.0 * lag as f64 / 8000.0).powi(2)).exp();
    }
    let mut a = [0.0; ORDER + 1];
    a[0] = 1.0;
    let mut error = r[0];
    for i in 1..=ORDER {
        let acc: f64 = (1..i).map(|j| a[j] * r[i - j]).sum::<f64>() + r[i];
        let k = -acc / error;
        let prev = a;
        for j in 1..i {
            a[j] = prev[j] + k * prev[i - j];
        }
        a[i] = k;
        error *= 1.0 - k * k;
    }
    for (i, c) in a.iter_mut().enumerate() {
        *c *= 0.994f64.powi(i as i32);
    }
    a
}

/// Roots of P and Q on the unit circle: sign changes of Re/Im of A(e^jw) e^(j 5.5 w).
fn lsp(a: &[f64; ORDER + 1]) -> Option<[f32; ORDER]> {
    let rotated = |w: f64| {
        let (mut re, mut im) = (0.0, 0.0);
        for (k, c) in a.iter().enumerate() {
            let phase = (5.5 - k as f64) * w;
            re += c * phase.cos();
            im += c * phase.sin();
        }
        (re, im)
    };
    let mut roots = Vec::with_capacity(ORDER);
    let grid = 512;
    for part in 0..2 {
        let f = |w: f64| {
            let (re, im) = rotated(w);
            if part == 0 { re } else { im }
        };
        let mut lo = 1e-4;
        let mut f_lo = f(lo);
        for g in 1..=grid {
            let hi = PI * g as f64 / grid as f64 - if g == grid { 1e-4 } else { 0.0 };
            let f_hi = f(hi);
            if f_lo * f_hi < 0.0 {
                let (mut a, mut b, mut fa) = (lo, hi, f_lo);
                for _ in 0..30 {
                    let m = 0.5 * (a + b);
                    let fm = f(m);
                    if fa * fm <= 0.0 {
                        b = m;
                    } else {
                        a = m;
                        fa = fm;
                    }
                }
                roots.push(0.5 * (a + b));
            }
            lo = hi;
            f_lo = f_hi;
        }
    }
    if roots.len() != ORDER {
        return None;
    }
    roots.sort_by(f64::total_cmp);
    let mut out = [0.0f32; ORDER];
    for (o, r) in out.iter_mut().zip(&roots) {
        *o = *r as f32;
    }
    Some(out)
}

/// Stand-in frame features of a 16 kHz mono WAV: frame n covers 8 kHz samples [160n, 160n+160).
pub fn features_for_utterance(path: &Path) -> Result<Vec<FrameFeatures>, BoxError> {
    let audio = read_mono_8k(path)?;
    let hamming: Vec<f64> = (0..WINDOW)
        .map(|i| 0.54 - 0.46 * (2.0 * PI * i as f64 / (WINDOW - 1) as f64).cos())
        .collect();
    let mut previous = crate::vocab::FrameFeatures::silent().lsp;
    let mut frames = Vec::with_capacity(audio.len() / FRAME);
    for n in 0..audio.len() / FRAME {
        let end = (n + 1) * FRAME;
        let window: Vec<f64> = (0..WINDOW)
            .map(|i| {
                let j = end as i64 - WINDOW as i64 + i as i64;
                if j < 0 {
                    0.0
                } else {
                    audio[j as usize] * hamming[i]
                }
            })
            .collect();
        if let Some(l) = lsp(&lpc(&window)) {
            previous = l;
        }
        let frame = &audio[n * FRAME..end];
        let power = frame.iter().map(|x| x * x).sum::<f64>() / FRAME as f64;
        frames.push(FrameFeatures {
            mode: Some(5),
            lsp: previous,
            energy_db: (10.0 * (power + 1e-10).log10()) as f32,
            family: crate::vocab::FeatureFamily::Analysis,
        });
    }
    Ok(frames)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::corpus::tests::timit_root;

    #[test]
    fn stand_in_features_look_like_lsps() {
        let path = timit_root().join("dr1-fvmh0/sa2.wav");
        let frames = features_for_utterance(&path).unwrap();
        assert!(frames.len() > 100);
        for f in &frames {
            assert!(f.lsp.windows(2).all(|w| w[0] < w[1]));
            assert!(f.lsp[0] > 0.0 && f.lsp[9] < std::f32::consts::PI);
        }
        let loudest = frames.iter().map(|f| f.energy_db).fold(f32::MIN, f32::max);
        let quietest = frames.iter().map(|f| f.energy_db).fold(f32::MAX, f32::min);
        assert!(
            loudest > -30.0 && quietest < loudest - 30.0,
            "{quietest}..{loudest}"
        );
    }
}
