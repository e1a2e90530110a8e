//! Helpers shared by the integration tests: running the reference tools and reading WAVs.
#![allow(dead_code)]

pub mod app;
pub mod glb_write;
pub mod janus;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn lipcall() -> Command {
    Command::new(env!("CARGO_BIN_EXE_lipcall"))
}

/// Runs a command that must exist and succeed (the reference tools are installed by .ci/run).
pub fn run(cmd: &mut Command) -> Output {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {:?}: {e} (install it: see README)", cmd));
    assert!(
        out.status.success(),
        "{:?} failed: {}",
        cmd,
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

pub fn read_wav_i16(path: &Path) -> (u32, Vec<i16>) {
    let mut r = hound::WavReader::open(path).unwrap();
    let rate = r.spec().sample_rate;
    (rate, r.samples::<i16>().map(Result::unwrap).collect())
}

pub fn repo_file(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// The TIMIT sample shipped beside the repository (never copied into it).
pub fn timit_dir() -> PathBuf {
    repo_file("../shared/data/timit-sample")
}

/// The project's demo speech, resampled by sox to 8 kHz mono 16-bit, in `dir`.
pub fn demo_8k(dir: &Path) -> PathBuf {
    let out = dir.join("demo8k.wav");
    run(Command::new("sox")
        .arg(repo_file("assets/speech/demo.wav"))
        .args(["-D", "-r", "8000", "-b", "16", "-c", "1"])
        .arg(&out));
    out
}

/// A TIMIT utterance resampled by sox to 8 kHz mono 16-bit, in `dir`.
pub fn timit_8k(dir: &Path, speaker: &str, utterance: &str) -> PathBuf {
    let out = dir.join(format!("{speaker}-{utterance}-8k.wav"));
    run(Command::new("sox")
        .arg(timit_dir().join(speaker).join(format!("{utterance}.wav")))
        .args(["-D", "-r", "8000", "-b", "16", "-c", "1"])
        .arg(&out));
    out
}

pub fn snr_db(reference: &[i16], test: &[i16]) -> f64 {
    let n = reference.len().min(test.len());
    let signal: f64 = reference[..n].iter().map(|&s| f64::from(s).powi(2)).sum();
    let noise: f64 = reference[..n]
        .iter()
        .zip(&test[..n])
        .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
        .sum();
    10.0 * (signal / noise.max(1e-9)).log10()
}
pub mod lpc;
pub mod mesh;
pub mod mumble;
pub mod nat;
pub mod net;
pub mod netns;
pub mod pulse;
pub mod sip;
pub mod talker;

/// A test's real peer or data is missing: under CI (`CI` set, as `.ci/run` runs) that fails the
/// test with the reason, since .ci/run installs everything; elsewhere the test says so and skips.
/// A memory field of a process's /proc/PID/status in MB (`VmRSS` now, `VmHWM` its peak);
/// `None` once it has gone.
pub fn memory_mb(pid: u32, field: &str) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let kb: f64 = status
        .lines()
        .find_map(|l| l.strip_prefix(field)?.strip_prefix(':'))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())?;
    Some(kb / 1024.0)
}

/// The resident memory of a process in MB (`None` once it has gone).
pub fn rss_mb(pid: u32) -> Option<f64> {
    memory_mb(pid, "VmRSS")
}

pub fn unavailable(reason: &str) {
    assert!(
        std::env::var_os("CI").is_none(),
        "{reason}: CI must provide it (.ci/run installs and starts every test peer)"
    );
    eprintln!("skipped: {reason}");
}

/// Two pixels a viewer tells apart: more than 24 levels apart in some colour channel.
pub fn visibly_different(p: [u8; 4], q: [u8; 4]) -> bool {
    (0..3).any(|k| p[k].abs_diff(q[k]) > 24)
}

/// The head renderer's GPU (the software adapter where there is no other). Without one the
/// test fails under CI, as for any missing peer, and elsewhere gets `None` after saying why it
/// skips.
pub fn gpu() -> Option<lipcall::render::GpuContext> {
    match lipcall::render::GpuContext::new_headless() {
        Ok(ctx) => Some(ctx),
        Err(e) => {
            unavailable(&format!("the head renderer: {e}"));
            None
        }
    }
}

/// Whether a PulseAudio server answers (the null sink of .ci/pulse-null-sink.sh).
pub fn pulse_running() -> bool {
    Command::new("pactl")
        .arg("info")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Standard base64 with padding (RFC 4648), for the data URIs of glTF test files.
pub fn base64(bytes: &[u8]) -> String {
    const ABC: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ABC[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// SNR of `test` against `reference`, each 100 ms segment of the reference aligned on its own
/// (within 4 frames of the best lag within `max` samples over 2-6 s), the energies summed over
/// all segments, and the steady-state lag. A playout may move in time where nothing is lost
/// (a late first packet, a frame shed in a pause): what is compared is the speech heard, not
/// its position.
pub fn segmental_snr(reference: &[i16], test: &[i16], max: usize) -> (f64, isize) {
    const SEGMENT: usize = 800;
    const FOLLOW: isize = 4 * 160;
    let energies_over = |at: usize, len: usize, lag: isize| -> Option<(f64, f64)> {
        let from = at as isize + lag;
        if from < 0 || from as usize + len > test.len() || at + len > reference.len() {
            return None;
        }
        let t = &test[from as usize..from as usize + len];
        let r = &reference[at..at + len];
        let signal: f64 = r.iter().map(|&x| f64::from(x).powi(2)).sum();
        let error: f64 = r
            .iter()
            .zip(t)
            .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
            .sum();
        Some((signal, error))
    };
    let best = |at: usize, len: usize, around: isize, reach: isize| {
        (around - reach..=around + reach)
            .filter_map(|lag| energies_over(at, len, lag).map(|(s, e)| (lag, s, e)))
            .min_by(|a, b| a.2.total_cmp(&b.2))
    };
    // The lag of the steady state (2-6 s in): the first second may hold the start-up's moves.
    let steady = (16_000.min(reference.len()), 32_000.min(reference.len() / 2));
    let first_lag = best(steady.0, steady.1, 0, max as isize).map_or(0, |(lag, ..)| lag);
    let (mut signal, mut error) = (0.0, 0.0);
    for at in (0..reference.len().saturating_sub(SEGMENT)).step_by(SEGMENT) {
        let Some((_, s, e)) = best(at, SEGMENT, first_lag, FOLLOW) else {
            continue;
        };
        signal += s;
        error += e;
    }
    (10.0 * (signal / error.max(1e-9)).log10(), first_lag)
}

/// Energy above `hz` (a 4th-order Butterworth high-pass: two biquads), in dB.
pub fn band_db(pcm: &[i16], rate: u32, hz: f64) -> f64 {
    let w = 2.0 * std::f64::consts::PI * hz / f64::from(rate);
    let mut x: Vec<f64> = pcm.iter().map(|&s| f64::from(s)).collect();
    for q in [0.541_196_1, 1.306_562_9] {
        let alpha = w.sin() / (2.0 * q);
        let a0 = 1.0 + alpha;
        let b0 = (1.0 + w.cos()) / 2.0 / a0;
        let b1 = -(1.0 + w.cos()) / a0;
        let (a1, a2) = (-2.0 * w.cos() / a0, (1.0 - alpha) / a0);
        let (mut x1, mut x2, mut y1, mut y2) = (0.0, 0.0, 0.0, 0.0);
        for v in x.iter_mut() {
            let y = b0 * *v + b1 * x1 + b0 * x2 - a1 * y1 - a2 * y2;
            (x2, x1, y2, y1) = (x1, *v, y1, y);
            *v = y;
        }
    }
    10.0 * x.iter().map(|v| v * v).sum::<f64>().max(1.0).log10()
}
