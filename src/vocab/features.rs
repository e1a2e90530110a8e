//! One 20 ms frame as every layer sees it: the rates and sizes, and the feature row the codecs
//! hand the lip-sync network (10 LSPs in radians and the frame energy), with the promises it
//! keeps (`0 < lsp1 < ... < lsp10 < pi`).

/// Samples per 20 ms frame at the 8 kHz rate the features and the network work at.
pub const FRAME_SIZE: usize = 160;
/// The feature rate (and the narrowband codecs' rate).
pub const SAMPLE_RATE: u32 = 8000;
/// Line spectral pairs per feature row (the narrowband LPC order).
pub const LSP_COUNT: usize = 10;

/// Where a feature row's LSPs come from. The network is trained on all three, but each leans
/// its own way on the closed shape, so a model may carry a closure snap per family.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum FeatureFamily {
    /// Speex's LSPs, read from its bitstream.
    #[default]
    Bitstream,
    /// Opus SILK NLSFs, read from its bitstream and mapped onto narrowband LSPs.
    Nlsf,
    /// An LPC analysis of the decoded audio (G.711, G.722, CELT-only Opus, concealment).
    Analysis,
}

/// What the receiver knows about one 20 ms frame once it has decoded it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameFeatures {
    /// What the codec says of the frame: Speex's narrowband mode (0..=8), Opus's TOC
    /// configuration (0..=31), G.711's payload type (0 or 8); `None` for a concealed frame.
    pub mode: Option<u8>,
    /// Quantised LSPs in radians, strictly increasing in (0, pi).
    pub lsp: [f32; LSP_COUNT],
    /// Energy of the decoded samples of the row, in dB relative to a full-scale square wave.
    pub energy_db: f32,
    /// Where `lsp` comes from.
    pub family: FeatureFamily,
}

/// The energy floor: digital silence reads as this, not as minus infinity.
pub const SILENCE_DB: f32 = -100.0;

impl FrameFeatures {
    /// What a silent stream looks like before its first frame (and where a frame is missing):
    /// evenly spread LSPs, no energy.
    pub fn silent() -> Self {
        Self {
            mode: None,
            lsp: flat_lsp(),
            energy_db: SILENCE_DB,
            family: FeatureFamily::Bitstream,
        }
    }
}

/// LSPs of a flat spectrum, what the features hold before the first speech frame.
pub fn flat_lsp() -> [f32; LSP_COUNT] {
    std::array::from_fn(|i| std::f32::consts::PI * (i + 1) as f32 / (LSP_COUNT + 1) as f32)
}

/// Smallest gap kept between neighbouring LSPs and from 0 and pi.
pub const LSP_MARGIN: f32 = 0.002;

/// The decoder stores LSPs exactly as dequantised, and a few quantiser codes give overlapping
/// or non-positive values (the decoder only spaces the interpolated copies it filters with).
/// Features promise `0 < lsp1 < ... < lsp10 < pi`, so sort and space them here.
pub fn ordered_lsp(lsp: [f32; LSP_COUNT]) -> [f32; LSP_COUNT] {
    if already_ordered(&lsp) {
        lsp
    } else {
        sorted_and_spaced(lsp)
    }
}

/// Whether [`sorted_and_spaced`] would return `lsp` unchanged: increasing, each at least
/// [`LSP_MARGIN`] above the one below (and 0) and below its ceiling, in the same f32
/// arithmetic. Most frames' LSPs are, and this check costs a fraction of the sort.
fn already_ordered(lsp: &[f32; LSP_COUNT]) -> bool {
    let mut floor = LSP_MARGIN;
    let mut ordered = true;
    for (i, &l) in lsp.iter().enumerate() {
        ordered &= l >= floor && l <= lsp_ceiling(i);
        floor = l + LSP_MARGIN;
    }
    ordered
}

fn sorted_and_spaced(mut lsp: [f32; LSP_COUNT]) -> [f32; LSP_COUNT] {
    lsp.sort_by(f32::total_cmp);
    let mut floor = LSP_MARGIN;
    for (i, l) in lsp.iter_mut().enumerate() {
        let ceiling = lsp_ceiling(i);
        // Not `clamp`: after a value held at its ceiling, `floor` (that ceiling plus the margin)
        // can round a hair above this ceiling, and `clamp` panics on that.
        *l = l.max(floor).min(ceiling);
        floor = *l + LSP_MARGIN;
    }
    lsp
}

/// The highest LSP `i` may take: room for a margin above each LSP after it, and below pi.
fn lsp_ceiling(i: usize) -> f32 {
    (std::f32::consts::PI - LSP_MARGIN) - LSP_MARGIN * (LSP_COUNT - 1 - i) as f32
}

/// Mean-square energy of 16-bit samples in dB re full scale, floored at [`SILENCE_DB`].
pub fn energy_db(samples: &[i16]) -> f32 {
    if samples.is_empty() {
        return SILENCE_DB;
    }
    // Exact in integers (and so the same sum in any order, which lets it vectorise).
    let sum: i64 = samples
        .iter()
        .map(|&s| i64::from(i32::from(s) * i32::from(s)))
        .sum();
    let mean = sum as f64 / samples.len() as f64 / (32768.0 * 32768.0);
    if mean <= 0.0 {
        return SILENCE_DB;
    }
    ((10.0 * mean.log10()) as f32).max(SILENCE_DB)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_silent_row_is_flat_and_at_the_floor() {
        let silent = FrameFeatures::silent();
        assert_eq!(silent.lsp, flat_lsp());
        assert_eq!(silent.energy_db, SILENCE_DB);
        assert_eq!(silent.mode, None);
    }

    #[test]
    fn energy_of_full_scale_square_is_zero_db() {
        assert!((energy_db(&[32767, -32768, 32767, -32768]) - 0.0).abs() < 0.01);
        assert_eq!(energy_db(&[0; 160]), SILENCE_DB);
        let half: Vec<i16> = vec![16384; 160];
        assert!((energy_db(&half) + 6.02).abs() < 0.01);
    }

    #[test]
    fn overlapping_and_negative_lsps_are_ordered_and_spaced() {
        let raw = [-0.061, 0.3, 0.29, 0.29, 1.0, 1.5, 2.0, 2.5, 3.0, 3.2];
        let l = ordered_lsp(raw);
        assert!(l[0] >= LSP_MARGIN);
        assert!(l[9] <= std::f32::consts::PI - LSP_MARGIN);
        assert!(l.windows(2).all(|w| w[1] - w[0] >= LSP_MARGIN * 0.999));
        let fine = flat_lsp();
        assert_eq!(ordered_lsp(fine), fine);
    }

    #[test]
    fn lsps_already_ordered_are_those_sorting_and_spacing_keeps() {
        let mut state = 0x9E37_79B9u32;
        let mut next = || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) as f32 / (1u32 << 24) as f32
        };
        let (mut kept, mut total) = (0, 0);
        for round in 0..20_000 {
            // Sorted random angles, some crowded (gaps near the margin) or out of range.
            let spread = [3.2f32, 0.05, 0.02][round % 3];
            let mut lsp: [f32; LSP_COUNT] = std::array::from_fn(|_| next() * spread);
            if round % 2 == 0 {
                lsp.sort_by(f32::total_cmp);
                let offset = next() * (3.2 - spread);
                lsp.iter_mut().for_each(|l| *l += offset);
            }
            total += 1;
            if already_ordered(&lsp) {
                kept += 1;
                assert_eq!(sorted_and_spaced(lsp), lsp, "{lsp:?}");
            } else {
                assert_ne!(sorted_and_spaced(lsp), lsp, "{lsp:?}");
            }
            assert_eq!(ordered_lsp(lsp), sorted_and_spaced(lsp), "{lsp:?}");
        }
        assert!(kept > total / 10 && kept < total, "{kept} of {total}");
    }

    #[test]
    fn flat_lsp_is_increasing_inside_zero_pi() {
        let l = flat_lsp();
        assert!(l[0] > 0.0 && l[9] < std::f32::consts::PI);
        assert!(l.windows(2).all(|w| w[0] < w[1]));
    }
}
