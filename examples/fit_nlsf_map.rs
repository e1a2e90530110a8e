//! Fits the affine maps from mediumband (order 10 at 12 kHz) and wideband (order 16 at 16 kHz)
//! SILK NLSFs onto the network's 10 narrowband LSPs, by least squares against the spectral refit
//! (`codec::opus::features::refitted_lsp`), on speech of the training speakers only: TIMIT dr1-dr3
//! and the AN4 training set. dr4 (validation) reports the error; dr5-dr6 (test) are never read.
//!
//!     cargo run --release --example fit_nlsf_map > src/codec/opus/nlsf_map.rs
//!
//! The receiver then maps a frame's NLSFs with 10 x (order + 1) multiply-adds instead of the
//! refit's spectrum, Levinson-Durbin and root search (see the codec bench).

use std::path::{Path, PathBuf};

use lipcall::audio::wav;
use lipcall::codec::opus;
use lipcall::codec::opus::features::refitted_lsp;
use lipcall::codec::silk::{Frame, SilkWalker};

const CORPUS: &str = "../shared/data";
/// Every how many AN4 training files one is taken (the maps have at most 170 coefficients).
const AN4_STRIDE: usize = 4;
const RIDGE: f64 = 1e-6;

/// Normal equations of one least-squares fit with `n` inputs (+1 for the bias) and 10 outputs.
struct Normal {
    n: usize,
    xtx: Vec<f64>,
    xty: Vec<f64>,
    rows: usize,
}

impl Normal {
    fn new(n: usize) -> Self {
        Self {
            n,
            xtx: vec![0.0; (n + 1) * (n + 1)],
            xty: vec![0.0; (n + 1) * 10],
            rows: 0,
        }
    }

    fn add(&mut self, x: &[f64], y: &[f32; 10]) {
        let m = self.n + 1;
        let xi = |i: usize| if i < self.n { x[i] } else { 1.0 };
        for i in 0..m {
            for j in 0..m {
                self.xtx[i * m + j] += xi(i) * xi(j);
            }
            for (k, &yk) in y.iter().enumerate() {
                self.xty[i * 10 + k] += xi(i) * f64::from(yk);
            }
        }
        self.rows += 1;
    }

    /// Solves (X'X + ridge I) W = X'Y by Gaussian elimination: W is (n + 1) x 10.
    fn solve(&self) -> Vec<[f64; 10]> {
        let m = self.n + 1;
        let mut a = self.xtx.clone();
        let mut b: Vec<[f64; 10]> = (0..m)
            .map(|i| std::array::from_fn(|k| self.xty[i * 10 + k]))
            .collect();
        let scale = (0..m).map(|i| a[i * m + i]).sum::<f64>() / m as f64;
        for i in 0..self.n {
            a[i * m + i] += RIDGE * scale;
        }
        for col in 0..m {
            let pivot = (col..m)
                .max_by(|&r, &s| a[r * m + col].abs().total_cmp(&a[s * m + col].abs()))
                .unwrap();
            for j in 0..m {
                a.swap(col * m + j, pivot * m + j);
            }
            b.swap(col, pivot);
            for row in 0..m {
                if row != col {
                    let f = a[row * m + col] / a[col * m + col];
                    for j in 0..m {
                        a[row * m + j] -= f * a[col * m + j];
                    }
                    let pivot_row = b[col];
                    for (t, p) in b[row].iter_mut().zip(pivot_row) {
                        *t -= f * p;
                    }
                }
            }
        }
        (0..m).map(|i| b[i].map(|v| v / a[i * m + i])).collect()
    }
}

fn apply(w: &[[f64; 10]], x: &[f64]) -> [f64; 10] {
    let n = x.len();
    std::array::from_fn(|k| w[n][k] + (0..n).map(|i| w[i][k] * x[i]).sum::<f64>())
}

/// (input rate, bitrate) settings each file is encoded at: wideband and mediumband SILK.
const SETTINGS: [(u32, u32); 6] = [
    (16_000, 12_000),
    (16_000, 16_000),
    (16_000, 24_000),
    (16_000, 32_000),
    (12_000, 12_000),
    (12_000, 20_000),
];

/// (internal rate, inputs, refit target) of every SILK frame of `path` through the settings.
fn frames_of(path: &Path, out: &mut Vec<(u32, Vec<f64>, [f32; 10])>) {
    let Ok(audio) = wav::read_mono(path) else {
        return;
    };
    for (rate, bitrate) in SETTINGS {
        let Ok(resampled) = wav::resample(&audio, rate) else {
            continue;
        };
        let pcm = wav::to_i16(&resampled);
        let config = opus::codec::EncoderConfig {
            bitrate,
            input_rate: rate,
            ..Default::default()
        };
        let Ok(bytes) = opus::stream::encode(&pcm, config) else {
            continue;
        };
        let Ok(file) = opus::ogg_file::read(&bytes) else {
            continue;
        };
        let mut walker = SilkWalker::new();
        for packet in file.pages.iter().flat_map(|p| &p.packets) {
            let Ok(frames) = walker.walk_packet(packet) else {
                continue;
            };
            for frame in frames {
                if let Frame::Silk(silk) = frame
                    && silk.internal_rate_hz != 8000
                    && let Some(target) = refitted_lsp(&silk.nlsf, silk.internal_rate_hz)
                {
                    let x = silk.nlsf.radians().map(f64::from).collect();
                    out.push((silk.internal_rate_hz, x, target));
                }
            }
        }
    }
}

fn wavs(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<PathBuf> = entries.flatten().map(|e| e.path()).collect();
    entries.sort();
    for path in entries {
        if path.is_dir() {
            wavs(&path, out);
        } else if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("wav"))
        {
            out.push(path);
        }
    }
}

fn main() {
    let timit = Path::new(CORPUS).join("timit-sample");
    let mut train = Vec::new();
    for speaker in [
        "dr1-fvmh0",
        "dr1-mcpm0",
        "dr2-faem0",
        "dr2-marc0",
        "dr3-falk0",
        "dr3-madc0",
    ] {
        wavs(&timit.join(speaker), &mut train);
    }
    let mut an4 = Vec::new();
    wavs(&Path::new(CORPUS).join("an4/wav/an4_clstk"), &mut an4);
    train.extend(an4.into_iter().step_by(AN4_STRIDE));
    let mut validation = Vec::new();
    for speaker in ["dr4-falr0", "dr4-maeb0"] {
        wavs(&timit.join(speaker), &mut validation);
    }
    eprintln!(
        "{} training files, {} validation files",
        train.len(),
        validation.len()
    );

    let mut rows = Vec::new();
    for (i, path) in train.iter().enumerate() {
        frames_of(path, &mut rows);
        if i % 50 == 0 {
            eprintln!("{i} files, {} frames", rows.len());
        }
    }
    let mut held = Vec::new();
    for path in &validation {
        frames_of(path, &mut held);
    }
    let mut maps = Vec::new();
    for (rate, order) in [(12_000u32, 10usize), (16_000, 16)] {
        let mut normal = Normal::new(order);
        for (_, x, y) in rows.iter().filter(|r| r.0 == rate) {
            normal.add(x, y);
        }
        let w = normal.solve();
        let error = |set: &[(u32, Vec<f64>, [f32; 10])]| {
            let (mut sum, mut count) = (0.0, 0usize);
            for (_, x, y) in set.iter().filter(|r| r.0 == rate) {
                let p = apply(&w, x);
                for (p, &y) in p.iter().zip(y) {
                    sum += (p - f64::from(y)).powi(2);
                    count += 1;
                }
            }
            (
                (sum / count.max(1) as f64).sqrt() * 4000.0 / std::f64::consts::PI,
                count / 10,
            )
        };
        let (train_hz, train_n) = error(&rows);
        let (held_hz, held_n) = error(&held);
        eprintln!(
            "{rate} Hz: rms error {train_hz:.1} Hz on {train_n} training frames, {held_hz:.1} Hz on {held_n} dr4 frames"
        );
        maps.push(FittedMap {
            rate,
            order,
            weights: w,
            frames: train_n,
            held_hz,
        });
    }
    print_table(&maps);
}

/// One fitted map: its rate and order, weights (inputs + bias) x 10, and its fit.
struct FittedMap {
    rate: u32,
    order: usize,
    weights: Vec<[f64; 10]>,
    frames: usize,
    held_hz: f64,
}

fn print_table(maps: &[FittedMap]) {
    println!(
        "//! Affine maps from mediumband and wideband SILK NLSFs (radians at the internal rate) onto\n\
         //! the network's 10 narrowband LSPs (radians at 8 kHz), fitted by least squares against the\n\
         //! spectral refit on training speakers only. Generated by\n\
         //! `cargo run --release --example fit_nlsf_map > src/codec/opus/nlsf_map.rs`; do not edit.\n"
    );
    for map in maps {
        let name = if map.rate == 12_000 {
            "MEDIUMBAND"
        } else {
            "WIDEBAND"
        };
        println!(
            "/// {} Hz, order {}: {} training frames; rms error on validation speakers {:.0} Hz.",
            map.rate, map.order, map.frames, map.held_hz
        );
        println!("/// Row k: the weights of LSP k on each NLSF, then its bias.");
        println!("pub const {name}: [[f32; {}]; 10] = [", map.order + 1);
        for k in 0..10 {
            // Six decimals are far below the map's error; written as the f32 they become.
            let row: Vec<String> = map
                .weights
                .iter()
                .map(|w| format!("{:?}", ((w[k] * 1e6).round() / 1e6) as f32))
                .collect();
            println!("    [{}],", row.join(", "));
        }
        println!("];");
        println!();
    }
}
