//! Feature rows of Opus streams. SILK and hybrid frames carry the vocal-tract shape in their
//! bitstream as NLSFs (read by [`crate::codec::silk::SilkWalker`]); they become the network's
//! inputs, the 10 LSPs of a narrowband (8 kHz) predictor as Speex would code them.
//! CELT-only frames carry none: their rows come from an LPC analysis of the decoded audio.
//!
//! Narrowband SILK codes an order-10 predictor at 8 kHz: its NLSFs are the LSPs, taken as
//! they are. Mediumband (order 10 at 12 kHz) and wideband (order 16 at 16 kHz) frames describe a
//! wider band. [`refitted_lsp`] is the reference mapping: the predictor's power spectrum below
//! 4 kHz, read straight off the NLSFs, becomes an autocorrelation at 8 kHz, smoothed with the
//! Speex encoder's lag window and noise floor and refitted at order 10 with the analysis's
//! Levinson-Durbin and root search ([`crate::codec::lpc`]). The receiver uses affine maps fitted
//! to it on training speakers ([`super::nlsf_map`], `examples/fit_nlsf_map.rs`): 170
//! multiply-adds instead of a spectrum and a root search, so that the features cost a few
//! percent of decoding (`cargo bench --bench codec`).

use std::collections::VecDeque;
use std::f64::consts::PI;
use std::sync::LazyLock;

use super::stream::Decoded;
use crate::codec::lpc::{LpcAnalyser, levinson, lsp_from_lpc};
use crate::codec::silk::{Frame, Nlsf, SilkWalker};
use crate::vocab::{FRAME_SIZE, LSP_COUNT, SAMPLE_RATE};
use crate::vocab::{FrameFeatures, energy_db, ordered_lsp};

/// Points of the 0-4 kHz spectrum the refit reads: enough for the few formants below 4 kHz of an
/// order-16 envelope, few enough to stay a small part of decoding a frame.
const SPECTRUM_POINTS: usize = 64;
/// The Speex encoder's Gaussian lag window (96 Hz) and white-noise floor, as the analysis
/// applies them ([`crate::codec::lpc`]): SILK's envelope then has Speex's formant bandwidths.
const LAG_SIGMA: f64 = 2.0 * PI * 96.0 / 8000.0;
const NOISE_FLOOR: f64 = 1.0002;

/// SILK's internal rates.
const SILK_RATES: [u32; 3] = [8000, 12_000, 16_000];

/// The share of a rate's band below 4 kHz.
fn narrowband(rate: u32) -> f64 {
    f64::from(SAMPLE_RATE) / f64::from(rate.max(1))
}

/// cos(w) of the spectrum's points, at a rate whose band below 4 kHz is `band` of its own.
fn spectrum_points(band: f64) -> [f64; SPECTRUM_POINTS] {
    std::array::from_fn(|k| ((k as f64 + 0.5) * PI / SPECTRUM_POINTS as f64 * band).cos())
}

/// [`spectrum_points`] of each of [`SILK_RATES`].
static POINT_COS: LazyLock<[[f64; SPECTRUM_POINTS]; 3]> =
    LazyLock::new(|| SILK_RATES.map(|rate| spectrum_points(narrowband(rate))));

/// cos(lag * w) at the spectrum's points, for the autocorrelation.
static LAG_COS: LazyLock<[[f64; LSP_COUNT + 1]; SPECTRUM_POINTS]> = LazyLock::new(|| {
    std::array::from_fn(|k| {
        let w = (k as f64 + 0.5) * PI / SPECTRUM_POINTS as f64;
        std::array::from_fn(|lag| (lag as f64 * w).cos())
    })
});

/// The 10 narrowband LSPs (radians at 8 kHz) of a SILK frame's NLSFs at `internal_rate_hz`,
/// as the receiver computes them: narrowband NLSFs as they are, mediumband and wideband ones
/// through [`super::nlsf_map`]. `None` for an order that does not match the rate.
pub fn narrowband_lsp(nlsf: &Nlsf, internal_rate_hz: u32) -> Option<[f32; LSP_COUNT]> {
    let mut x = [0.0f32; crate::codec::silk::MAX_ORDER];
    for (x, radians) in x.iter_mut().zip(nlsf.radians()) {
        *x = radians;
    }
    let lsp = match (internal_rate_hz, nlsf.order()) {
        (8000, LSP_COUNT) => std::array::from_fn(|k| x[k]),
        (12_000, LSP_COUNT) => affine(&super::nlsf_map::MEDIUMBAND, &x),
        (16_000, 16) => affine(&super::nlsf_map::WIDEBAND, &x),
        _ => return None,
    };
    Some(ordered_lsp(lsp))
}

/// Row k of `map` holds LSP k's weights on the first N - 1 inputs and its bias.
fn affine<const N: usize>(map: &[[f32; N]; LSP_COUNT], x: &[f32]) -> [f32; LSP_COUNT] {
    std::array::from_fn(|k| {
        let row = &map[k];
        row[..N - 1]
            .iter()
            .zip(x)
            .fold(row[N - 1], |sum, (w, x)| sum + w * x)
    })
}

/// The reference mapping (see the module's documentation): the 10 narrowband LSPs of the part
/// of the NLSFs' spectrum below 4 kHz, refitted; `None` when the refit is ill-conditioned.
pub fn refitted_lsp(nlsf: &Nlsf, internal_rate_hz: u32) -> Option<[f32; LSP_COUNT]> {
    let mut angles = [0.0f64; crate::codec::silk::MAX_ORDER];
    for (angle, radians) in angles.iter_mut().zip(nlsf.radians()) {
        *angle = f64::from(radians);
    }
    let angles = &angles[..nlsf.order()];
    refit(angles, narrowband(internal_rate_hz))
}

/// The order-10 LSPs at 8 kHz of the predictor whose LSFs (radians at its own rate, increasing,
/// an even number of them) are `angles`, keeping the part of its spectrum below `band` times its
/// Nyquist frequency.
fn refit(angles: &[f64], band: f64) -> Option<[f32; LSP_COUNT]> {
    if angles.is_empty() || !angles.len().is_multiple_of(2) || !(band > 0.0 && band <= 1.0) {
        return None;
    }
    let cos_angles: [f64; crate::codec::silk::MAX_ORDER] =
        std::array::from_fn(|i| angles.get(i).map_or(0.0, |a| a.cos()));
    let cos_angles = &cos_angles[..angles.len()];
    let mut r = [0.0f64; LSP_COUNT + 1];
    let points = match SILK_RATES.iter().position(|&rate| band == narrowband(rate)) {
        Some(i) => POINT_COS[i],
        None => spectrum_points(band),
    };
    for (&x, lag_cos) in points.iter().zip(LAG_COS.iter()) {
        // |A|^2 up to a constant: cos^2(w/2) prod_odd (x - x_i)^2 + sin^2(w/2) prod_even (x - x_i)^2,
        // where the odd-numbered LSFs (1st, 3rd, ...) are the roots of the sum polynomial.
        let (mut sum, mut difference) = (1.0f64, 1.0f64);
        for pair in cos_angles.chunks_exact(2) {
            let (d_sum, d_difference) = (x - pair[0], x - pair[1]);
            sum *= d_sum * d_sum;
            difference *= d_difference * d_difference;
        }
        let inverse_power = 0.5 * (1.0 + x) * sum + 0.5 * (1.0 - x) * difference;
        if inverse_power.is_nan() || inverse_power <= 0.0 {
            return None;
        }
        let power = 1.0 / inverse_power;
        for (r, c) in r.iter_mut().zip(lag_cos) {
            *r += power * c;
        }
    }
    for (k, r) in r.iter_mut().enumerate() {
        let s = LAG_SIGMA * k as f64;
        *r *= (-0.5 * s * s).exp();
    }
    r[0] *= NOISE_FLOOR;
    let a = levinson(&r)?;
    let lsp = lsp_from_lpc(&a)?;
    let mut out = [0.0f32; LSP_COUNT];
    for (o, l) in out.iter_mut().zip(lsp) {
        *o = l as f32;
    }
    Some(ordered_lsp(out))
}

/// One walked SILK-layer frame's span of decoded samples at `rate`, with the LSPs it codes and
/// its bandwidth (`None`: a CELT-only or concealed frame codes none).
pub fn frame_span(frame: &Frame, rate: u32) -> (Option<([f32; LSP_COUNT], u8)>, usize) {
    let rate = rate as usize;
    match frame {
        Frame::Silk(silk) => (
            narrowband_lsp(&silk.nlsf, silk.internal_rate_hz).map(|l| (l, silk.bandwidth as u8)),
            silk.duration_ms as usize * rate / 1000,
        ),
        Frame::Celt { duration_48k, .. } | Frame::Concealed { duration_48k, .. } => {
            (None, *duration_48k as usize * rate / 48_000)
        }
    }
}

/// The coded spans of a stream, in order, and their assignment to 20 ms rows: a row takes what
/// the span covering most of its samples codes; of equals, the later: a row of two 10 ms SILK
/// frames takes the second's NLSFs, as a 20 ms frame's code its second half (its first is
/// interpolated from the frame before), which keeps 10 ms streams' weights nearer 20 ms ones'
/// (docs/audio.md). The receiver pushes
/// each payload's frames as it decodes them and takes a row per frame played
/// ([`crate::codec::decoder`]); [`stream_features`] does the same over a whole file. Adjacent
/// spans coding the same thing are one; at most `capacity` spans are kept (a full queue
/// lengthens its newest).
#[derive(Debug, Clone)]
pub struct CodedRuns<T> {
    runs: VecDeque<(Option<T>, usize)>,
    capacity: usize,
}

impl CodedRuns<([f32; LSP_COUNT], u8)> {
    /// A payload's walked frames, decoded to `samples` samples at `rate` (what its frames do
    /// not cover codes nothing).
    pub fn push_packet(&mut self, frames: &[Frame], samples: usize, rate: u32) {
        let mut left = samples;
        for frame in frames {
            let (coded, length) = frame_span(frame, rate);
            let length = length.min(left);
            self.push(coded, length);
            left -= length;
        }
        self.push(None, left);
    }
}

impl<T: Copy + PartialEq> CodedRuns<T> {
    pub fn with_capacity(capacity: usize) -> Self {
        Self {
            runs: VecDeque::with_capacity(capacity),
            capacity: capacity.max(1),
        }
    }

    /// The next `samples` samples code `coded` (`None`: nothing).
    pub fn push(&mut self, coded: Option<T>, samples: usize) {
        if samples == 0 {
            return;
        }
        let full = self.runs.len() >= self.capacity;
        match self.runs.back_mut() {
            Some(last) if full || last.0 == coded => last.1 += samples,
            _ => self.runs.push_back((coded, samples)),
        }
    }

    /// Keeps the first `len` samples.
    pub fn truncate(&mut self, len: usize) {
        let mut kept = 0;
        let mut runs = 0;
        for run in self.runs.iter_mut() {
            if kept >= len {
                break;
            }
            run.1 = run.1.min(len - kept);
            kept += run.1;
            runs += 1;
        }
        self.runs.truncate(runs);
    }

    /// Takes `samples` samples off the front: what the coded run that covers most of them codes.
    pub fn take(&mut self, mut samples: usize) -> Option<T> {
        let mut best: Option<(T, usize)> = None;
        while samples > 0 {
            let Some(front) = self.runs.front_mut() else {
                break;
            };
            let n = front.1.min(samples);
            if let Some(coded) = front.0
                && best.is_none_or(|(_, most)| n >= most)
            {
                best = Some((coded, n));
            }
            front.1 -= n;
            samples -= n;
            if front.1 == 0 {
                self.runs.pop_front();
            }
        }
        best.map(|(coded, _)| coded)
    }
}

/// The feature rows of a decoded Ogg Opus stream, one per 160 samples of `decoded.pcm` (8 kHz):
/// each row takes the LSPs of the SILK frame whose decoded samples overlap it most
/// ([`CodedRuns`], as the receiver assigns them), or an LPC analysis of its own audio where
/// that frame was CELT-only; the energy is the row's.
pub fn stream_features(decoded: &Decoded) -> Vec<FrameFeatures> {
    let rows = decoded.pcm.len() / FRAME_SIZE;
    let mut runs = CodedRuns::with_capacity(decoded.packets.len() * 3 + 2);
    let mut walker = SilkWalker::new();
    // Samples pushed, counted from the first of `decoded.pcm` (negative inside the pre-skip).
    let mut at = decoded.packets.first().map_or(0, |p| p.pcm_offset.min(0));
    let skipped = usize::try_from(-at).unwrap_or(0);
    for packet in &decoded.packets {
        if packet.pcm_offset > at {
            runs.push(None, (packet.pcm_offset - at) as usize);
            at = packet.pcm_offset;
        }
        let Ok(frames) = walker.walk_packet(&packet.data) else {
            walker.packet_lost();
            runs.push(None, packet.samples);
            at += packet.samples as i64;
            continue;
        };
        runs.push_packet(&frames, packet.samples, decoded.rate.max(1));
        at += packet.samples as i64;
    }
    runs.take(skipped);
    let mut analyser = LpcAnalyser::new();
    decoded
        .pcm
        .chunks_exact(FRAME_SIZE)
        .take(rows)
        .map(|samples| {
            let pcm: &[i16; FRAME_SIZE] = samples.try_into().expect("chunks of FRAME_SIZE");
            // Only rows without NLSFs are analysed, as the receiver does (codec::decoder).
            match runs.take(FRAME_SIZE) {
                Some((lsp, mode)) => FrameFeatures {
                    mode: Some(mode),
                    lsp,
                    energy_db: energy_db(pcm),
                    family: crate::vocab::FeatureFamily::Nlsf,
                },
                None => analyser.analyse(pcm).features(None),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::lpc::levinson as fit;

    /// An order-10 predictor with formants at 500, 1500 and 2500 Hz and its LSPs.
    fn formant_lsp() -> [f64; LSP_COUNT] {
        let mut r = [0.0f64; LSP_COUNT + 1];
        for (lag, r) in r.iter_mut().enumerate() {
            for (f, bw) in [(500.0, 80.0), (1500.0, 120.0), (2500.0, 200.0)] {
                let w = 2.0 * PI * f / 8000.0;
                let decay = (-PI * bw / 8000.0 * lag as f64).exp();
                *r += decay * (w * lag as f64).cos();
            }
        }
        r[0] *= 1.001;
        lsp_from_lpc(&fit(&r).unwrap()).unwrap()
    }

    #[test]
    fn the_refit_of_a_narrowband_envelope_gives_back_its_lsps() {
        // The lag window widens the formants, which moves each LSP pair apart a little.
        let lsp = formant_lsp();
        let refitted = refit(&lsp, 1.0).unwrap();
        for (a, b) in lsp.iter().zip(refitted) {
            assert!((a - f64::from(b)).abs() < 0.06, "{lsp:?} vs {refitted:?}");
        }
    }

    #[test]
    fn a_wideband_envelope_keeps_its_formants_below_4_khz() {
        // The same formants described at 16 kHz by an order-16 predictor: its spectrum below
        // 4 kHz, refitted at 8 kHz, puts LSP pairs around 500, 1500 and 2500 Hz again.
        let mut r = [0.0f64; 17];
        for (lag, r) in r.iter_mut().enumerate() {
            for (f, bw) in [
                (500.0, 80.0),
                (1500.0, 120.0),
                (2500.0, 200.0),
                (5000.0, 300.0),
            ] {
                let w = 2.0 * PI * f / 16000.0;
                let decay = (-PI * bw / 16000.0 * lag as f64).exp();
                *r += decay * (w * lag as f64).cos();
            }
        }
        r[0] *= 1.001;
        let angles = wideband_lsf(&r);
        let lsp = refit(&angles, 0.5).unwrap();
        for formant in [500.0, 1500.0, 2500.0] {
            let w = (2.0 * PI * formant / 8000.0) as f32;
            let nearest = lsp.iter().map(|l| (l - w).abs()).fold(f32::MAX, f32::min);
            assert!(nearest < 0.12, "no LSP near {formant} Hz: {lsp:?}");
        }
        assert!(lsp.windows(2).all(|p| p[0] < p[1]));
    }

    /// LSFs of an order-16 predictor (Levinson without bias, roots by a fine grid search).
    fn wideband_lsf(r: &[f64; 17]) -> Vec<f64> {
        let n = 16;
        let mut a = vec![0.0; n + 1];
        a[0] = 1.0;
        let mut error = r[0];
        for i in 1..=n {
            let acc: f64 = r[i] + (1..i).map(|j| a[j] * r[i - j]).sum::<f64>();
            let k = -acc / error;
            let previous = a.clone();
            for j in 1..i {
                a[j] = previous[j] + k * previous[i - j];
            }
            a[i] = k;
            error *= 1.0 - k * k;
        }
        // Sum and difference polynomials evaluated as real functions of w.
        let c = |k: usize| if k <= n { a[k] } else { 0.0 };
        let half = (n + 1) as f64 / 2.0;
        let p = |w: f64| -> f64 {
            (0..=n + 1)
                .map(|k| (c(k) + c(n + 1 - k)) * ((half - k as f64) * w).cos())
                .sum()
        };
        let q = |w: f64| -> f64 {
            (0..=n + 1)
                .map(|k| (c(k) - c(n + 1 - k)) * ((half - k as f64) * w).sin())
                .sum()
        };
        let steps = 20_000;
        let mut roots = Vec::new();
        for f in [&p as &dyn Fn(f64) -> f64, &q] {
            for s in 1..steps {
                let (w0, w1) = (
                    PI * (s - 1) as f64 / steps as f64,
                    PI * s as f64 / steps as f64,
                );
                if (f(w0) < 0.0) != (f(w1) < 0.0) && w0 > 0.0 {
                    roots.push(0.5 * (w0 + w1));
                }
            }
        }
        roots.sort_by(f64::total_cmp);
        assert_eq!(roots.len(), n, "{roots:?}");
        roots
    }

    /// The SILK frames of the demo speech through Opus at 16 kb/s from `rate`.
    fn demo_silk_frames(rate: u32) -> Vec<crate::codec::silk::SilkFrame> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/speech/demo.wav");
        let audio = crate::audio::wav::read_mono(&path).unwrap();
        let pcm = crate::audio::wav::to_i16(&crate::audio::wav::resample(&audio, rate).unwrap());
        let config = super::super::codec::EncoderConfig {
            input_rate: rate,
            ..Default::default()
        };
        let file = super::super::stream::encode(&pcm, config).unwrap();
        let file = super::super::ogg_file::read(&file).unwrap();
        let mut walker = SilkWalker::new();
        file.pages
            .iter()
            .flat_map(|p| &p.packets)
            .flat_map(|p| walker.walk_packet(p).unwrap())
            .filter_map(|f| f.silk().copied())
            .collect()
    }

    #[test]
    fn narrowband_nlsfs_are_the_lsps_and_wider_bands_land_near_the_refit() {
        let narrow = demo_silk_frames(8000);
        assert!(narrow.len() > 300);
        for frame in &narrow {
            assert_eq!(frame.internal_rate_hz, 8000);
            let lsp = narrowband_lsp(&frame.nlsf, 8000).unwrap();
            for (l, r) in lsp.iter().zip(frame.nlsf.radians()) {
                assert!((l - r).abs() < 0.02, "{lsp:?} vs {:?}", frame.nlsf);
            }
        }
        // The demo speech is no training speaker: the fitted map stays within about 100 Hz
        // (rms) of the refit it was fitted to, where a mean vector would be 300 Hz away.
        let wide = demo_silk_frames(16_000);
        let (mut squared, mut spread, mut count) = (0.0f64, 0.0f64, 0usize);
        let refits: Vec<[f32; LSP_COUNT]> = wide
            .iter()
            .filter_map(|f| refitted_lsp(&f.nlsf, f.internal_rate_hz))
            .collect();
        let mut mean = [0.0f64; LSP_COUNT];
        for refit in &refits {
            for (m, r) in mean.iter_mut().zip(refit) {
                *m += f64::from(*r) / refits.len() as f64;
            }
        }
        for frame in &wide {
            assert_eq!(frame.internal_rate_hz, 16_000);
            let (Some(mapped), Some(refit)) = (
                narrowband_lsp(&frame.nlsf, 16_000),
                refitted_lsp(&frame.nlsf, 16_000),
            ) else {
                continue;
            };
            assert!(mapped.windows(2).all(|p| p[0] < p[1]));
            for ((m, r), mean) in mapped.iter().zip(refit).zip(mean) {
                squared += f64::from(m - r).powi(2);
                spread += (f64::from(r) - mean).powi(2);
                count += 1;
            }
        }
        let hz = |sum: f64| (sum / count as f64).sqrt() * 4000.0 / PI;
        assert!(count > 3000);
        assert!(
            hz(squared) < 100.0,
            "map {:.0} Hz from the refit",
            hz(squared)
        );
        assert!(
            hz(spread) > 2.0 * hz(squared),
            "spread {:.0} Hz",
            hz(spread)
        );
        assert!(narrowband_lsp(&wide[0].nlsf, 8000).is_none());
    }

    #[test]
    fn narrowband_nlsfs_are_taken_as_the_lsps_they_are() {
        for frame in demo_silk_frames(8000) {
            let raw: [f32; LSP_COUNT] =
                std::array::from_fn(|k| frame.nlsf.radians().nth(k).unwrap());
            assert_eq!(narrowband_lsp(&frame.nlsf, 8000), Some(ordered_lsp(raw)));
        }
    }

    #[test]
    fn malformed_angle_sets_are_refused() {
        assert!(refit(&[], 0.5).is_none());
        assert!(refit(&[0.1, 0.2, 0.3], 0.5).is_none());
        assert!(refit(&[0.1, 0.2], 0.0).is_none());
        assert!(refit(&[0.1, 0.2], f64::NAN).is_none());
    }
}
