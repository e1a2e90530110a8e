//! NLSF reconstruction from the two-stage VQ indices (RFC 6716 4.2.7.5.2-4.2.7.5.4), in the
//! decoder's fixed-point arithmetic so that the result is the decoder's own vector.

use super::tables::{
    NLSF_NB_MB_MIN_SPACING_Q15, NLSF_NB_MB_PREDICTION_Q8, NLSF_NB_MB_RESIDUAL_ICDF,
    NLSF_NB_MB_SELECT, NLSF_NB_MB_STAGE1_ICDF, NLSF_NB_MB_STAGE1_Q8, NLSF_NB_MB_WEIGHTS_Q9,
    NLSF_WB_MIN_SPACING_Q15, NLSF_WB_PREDICTION_Q8, NLSF_WB_RESIDUAL_ICDF, NLSF_WB_SELECT,
    NLSF_WB_STAGE1_ICDF, NLSF_WB_STAGE1_Q8, NLSF_WB_WEIGHTS_Q9, unpack_predictions,
    unpack_residual_rows,
};

/// Highest LPC order (WB).
pub const MAX_ORDER: usize = 16;
/// Largest magnitude of a stage-2 residual index before the extension (4.2.7.5.2).
pub(super) const RESIDUAL_MAX: i32 = 4;
/// Largest magnitude of a stage-2 residual index with the extension.
const EXTENDED_RESIDUAL_MAX: i32 = 10;
/// Residual indices -10..=10.
const RESIDUAL_LEVELS: usize = 2 * EXTENDED_RESIDUAL_MAX as usize + 1;
/// The stabiliser's gentle passes before its fallback (4.2.7.5.4).
const STABILIZE_PASSES: usize = 20;
/// Residual reconstruction pulls non-zero levels towards zero by 0.1 (Q10).
const LEVEL_ADJUST_Q10: i32 = 102;
/// Stage-1 vectors per codebook.
const VECTORS: usize = 32;

/// The two NLSF codebooks: NB/MB (order 10) and WB (order 16).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Codebook {
    NarrowMedium,
    Wide,
}

impl Codebook {
    pub fn order(self) -> usize {
        match self {
            Codebook::NarrowMedium => NB_MB.order(),
            Codebook::Wide => WB.order(),
        }
    }

    #[cfg(test)]
    fn stage1_q8(self, vector: usize) -> Option<&'static [u8]> {
        match self {
            Codebook::NarrowMedium => NB_MB.stage1_q8.get(vector).map(|v| &v[..]),
            Codebook::Wide => WB.stage1_q8.get(vector).map(|v| &v[..]),
        }
    }

    #[cfg(test)]
    fn min_spacing_q15(self) -> &'static [i16] {
        match self {
            Codebook::NarrowMedium => NB_MB.min_spacing_q15,
            Codebook::Wide => WB.min_spacing_q15,
        }
    }
}

/// One codebook's tables, with the 4-bit fields of its selection table unpacked per
/// coefficient (4.2.7.5.2-3) so that the per-frame work only indexes.
pub(super) struct CodebookTables<const ORDER: usize> {
    stage1_icdf: &'static [[u8; VECTORS]; 2],
    stage1_q8: &'static [[u8; ORDER]; VECTORS],
    weights_q9: &'static [[i16; ORDER]; VECTORS],
    /// Per vector and coefficient: which of `residual_icdf` codes its residual.
    residual_rows: [[u8; ORDER]; VECTORS],
    /// Per vector and coefficient: the backward prediction weight (Q8) from the coefficient
    /// above; 0 for the last.
    predictions_q8: [[u8; ORDER]; VECTORS],
    residual_icdf: &'static [[u8; 9]; 8],
    /// Per residual index -10..=10 (from 0), the dequantised residual, Q10 (4.2.7.5.3).
    residuals_q10: [i32; RESIDUAL_LEVELS],
    /// `ORDER + 1` spacings: below each coefficient, and above the last (4.2.7.5.4).
    min_spacing_q15: &'static [i16],
}

pub(super) static NB_MB: CodebookTables<10> = CodebookTables {
    stage1_icdf: &NLSF_NB_MB_STAGE1_ICDF,
    stage1_q8: &NLSF_NB_MB_STAGE1_Q8,
    weights_q9: &NLSF_NB_MB_WEIGHTS_Q9,
    residual_rows: unpack_residual_rows(&NLSF_NB_MB_SELECT),
    predictions_q8: unpack_predictions(&NLSF_NB_MB_SELECT, &NLSF_NB_MB_PREDICTION_Q8),
    residual_icdf: &NLSF_NB_MB_RESIDUAL_ICDF,
    // 0.18 in Q16, rounded
    residuals_q10: dequantised_residuals(11796),
    min_spacing_q15: &NLSF_NB_MB_MIN_SPACING_Q15,
};

pub(super) static WB: CodebookTables<16> = CodebookTables {
    stage1_icdf: &NLSF_WB_STAGE1_ICDF,
    stage1_q8: &NLSF_WB_STAGE1_Q8,
    weights_q9: &NLSF_WB_WEIGHTS_Q9,
    residual_rows: unpack_residual_rows(&NLSF_WB_SELECT),
    predictions_q8: unpack_predictions(&NLSF_WB_SELECT, &NLSF_WB_PREDICTION_Q8),
    residual_icdf: &NLSF_WB_RESIDUAL_ICDF,
    // 0.15 in Q16, rounded
    residuals_q10: dequantised_residuals(9830),
    min_spacing_q15: &NLSF_WB_MIN_SPACING_Q15,
};

/// The residual indices -10..=10 dequantised (Q10) with the codebook's step (Q16): pulled
/// towards zero by 0.1, then scaled.
const fn dequantised_residuals(step_q16: i32) -> [i32; RESIDUAL_LEVELS] {
    let mut residuals = [0; RESIDUAL_LEVELS];
    let mut index = -EXTENDED_RESIDUAL_MAX;
    while index <= EXTENDED_RESIDUAL_MAX {
        let level = (index << 10) - index.signum() * LEVEL_ADJUST_Q10;
        // |level| <= 10 * 1024, so the product fits 32 bits.
        residuals[(index + EXTENDED_RESIDUAL_MAX) as usize] = (level * step_q16) >> 16;
        index += 1;
    }
    residuals
}

impl<const ORDER: usize> CodebookTables<ORDER> {
    pub(super) const fn order(&self) -> usize {
        ORDER
    }

    /// The stage-1 index's distribution for inactive and unvoiced frames, or voiced ones.
    #[inline(always)]
    pub(super) fn stage1_icdf(&self, voiced: bool) -> &'static [u8; VECTORS] {
        let icdf: &'static [[u8; VECTORS]; 2] = self.stage1_icdf;
        &icdf[usize::from(voiced)]
    }

    /// The distribution of coefficient `k`'s residual in stage-1 vector `vector` (0..32).
    pub(super) fn residual_icdf(&self, vector: usize, k: usize) -> &'static [u8; 9] {
        let row = self.residual_rows[vector % VECTORS][k % ORDER];
        let icdf: &'static [[u8; 9]; 8] = self.residual_icdf;
        &icdf[usize::from(row & 7)]
    }

    /// The stabilised NLSFs (Q15) of stage-1 vector `vector` (0..32) and stage-2 residual
    /// indices in -10..=10, as the decoder computes them (4.2.7.5.3-4).
    pub(super) fn reconstruct(&self, vector: usize, residuals: &[i8; ORDER]) -> [i16; ORDER] {
        let vector = vector % VECTORS;
        let base = &self.stage1_q8[vector];
        let weights = &self.weights_q9[vector];
        let predictions = &self.predictions_q8[vector];
        let mut nlsf = [0i16; ORDER];
        // Stage 2: residuals in Q10, predicted backwards from the coefficient above, then
        // weighted onto the stage-1 vector.
        let mut above = 0i32;
        for k in (0..ORDER).rev() {
            let predicted = (above * i32::from(predictions[k])) >> 8;
            let index = (i32::from(residuals[k]) + EXTENDED_RESIDUAL_MAX)
                .clamp(0, 2 * EXTENDED_RESIDUAL_MAX) as usize;
            above = predicted + self.residuals_q10[index];
            let weighted = (above << 14) / i32::from(weights[k]).max(1);
            nlsf[k] = (weighted + (i32::from(base[k]) << 7)).clamp(0, 32767) as i16;
        }
        if !self.spaced(&nlsf) {
            stabilize(&mut nlsf, self.min_spacing_q15);
        }
        nlsf
    }

    /// Whether the vector already keeps the minimum spacings, which leaves [`stabilize`]
    /// nothing to do.
    fn spaced(&self, nlsf: &[i16; ORDER]) -> bool {
        let spacing = |k: usize| self.min_spacing_q15.get(k).map_or(0, |&s| i32::from(s));
        let mut ok = i32::from(nlsf[0]) >= spacing(0);
        for k in 1..ORDER {
            ok &= i32::from(nlsf[k]) - i32::from(nlsf[k - 1]) >= spacing(k);
        }
        ok & (32768 - i32::from(nlsf[ORDER - 1]) >= spacing(ORDER))
    }
}

/// Why indices do not form an NLSF vector (only possible for indices not read from a packet).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum NlsfIndexError {
    #[error("stage-1 index {0} is not in 0..32")]
    Stage1(usize),
    #[error("{given} residuals given for an order-{order} codebook")]
    ResidualCount { given: usize, order: usize },
    #[error("stage-2 residual {0} is not in -10..=10")]
    Residual(i8),
}

/// Reconstructs and stabilises the NLSF vector (Q15) of stage-1 index `stage1` and the
/// stage-2 residual indices `residuals` (one per coefficient, in -10..=10). The first
/// `codebook.order()` entries of the result are meaningful, the rest are 0.
pub fn reconstruct(
    codebook: Codebook,
    stage1: usize,
    residuals: &[i8],
) -> Result<[i16; MAX_ORDER], NlsfIndexError> {
    let order = codebook.order();
    if residuals.len() != order {
        return Err(NlsfIndexError::ResidualCount {
            given: residuals.len(),
            order,
        });
    }
    if let Some(&bad) = residuals
        .iter()
        .find(|&&r| !(-EXTENDED_RESIDUAL_MAX..=EXTENDED_RESIDUAL_MAX).contains(&i32::from(r)))
    {
        return Err(NlsfIndexError::Residual(bad));
    }
    if stage1 >= VECTORS {
        return Err(NlsfIndexError::Stage1(stage1));
    }
    let mut padded = [0i8; MAX_ORDER];
    padded[..order].copy_from_slice(residuals);
    Ok(reconstruct_padded(codebook, stage1, &padded))
}

/// [`reconstruct`] of indices known to be valid, as the walker reads them: the first
/// `codebook.order()` residuals are used.
pub(super) fn reconstruct_padded(
    codebook: Codebook,
    stage1: usize,
    residuals: &[i8; MAX_ORDER],
) -> [i16; MAX_ORDER] {
    fn widen<const ORDER: usize>(nlsf: [i16; ORDER]) -> [i16; MAX_ORDER] {
        let mut out = [0i16; MAX_ORDER];
        out[..ORDER].copy_from_slice(&nlsf);
        out
    }
    match codebook {
        Codebook::NarrowMedium => widen(NB_MB.reconstruct(stage1, first(residuals))),
        Codebook::Wide => widen(WB.reconstruct(stage1, first(residuals))),
    }
}

/// The first `N` entries of a `MAX_ORDER` array.
pub(super) fn first<const N: usize, T>(values: &[T; MAX_ORDER]) -> &[T; N] {
    const { assert!(N <= MAX_ORDER) };
    values.first_chunk().expect("orders are at most MAX_ORDER")
}

/// Enforces the minimum spacings (RFC 6716 4.2.7.5.4): `min_spacing[k]` below coefficient k
/// (from 0 for k = 0) and `min_spacing[order]` above the last one (to 1.0 in Q15).
/// `nlsf.len() + 1` spacings are needed; with fewer the vector is left as it is.
pub(super) fn stabilize(nlsf: &mut [i16], min_spacing: &[i16]) {
    let order = nlsf.len();
    if order == 0 || min_spacing.len() < order + 1 {
        return;
    }
    let spacing = |k: usize| i32::from(min_spacing[k]);
    for _ in 0..STABILIZE_PASSES {
        // The tightest gap (most negative slack); ties go to the lowest index.
        let mut worst_slack = i32::from(nlsf[0]) - spacing(0);
        let mut worst = 0;
        for k in 1..order {
            let slack = i32::from(nlsf[k]) - (i32::from(nlsf[k - 1]) + spacing(k));
            if slack < worst_slack {
                worst_slack = slack;
                worst = k;
            }
        }
        let top_slack = 32768 - (i32::from(nlsf[order - 1]) + spacing(order));
        if top_slack < worst_slack {
            worst_slack = top_slack;
            worst = order;
        }
        if worst_slack >= 0 {
            return;
        }
        if worst == 0 {
            nlsf[0] = min_spacing[0];
        } else if worst == order {
            nlsf[order - 1] = (32768 - spacing(order)) as i16;
        } else {
            // Push the pair apart around its centre, the centre kept where the other
            // spacings leave room for it.
            let half = spacing(worst) >> 1;
            let lowest_centre = (0..worst).map(spacing).sum::<i32>() + half;
            let highest_centre = 32768 - (worst + 1..=order).map(spacing).sum::<i32>() - half;
            let sum = i32::from(nlsf[worst - 1]) + i32::from(nlsf[worst]);
            let centre = ((sum >> 1) + (sum & 1))
                .max(lowest_centre)
                .min(highest_centre);
            nlsf[worst - 1] = (centre - half) as i16;
            nlsf[worst] = (centre - half + spacing(worst)) as i16;
        }
    }
    // Fallback: sort, then sweep up and down enforcing the spacings.
    nlsf.sort_unstable();
    nlsf[0] = nlsf[0].max(min_spacing[0]);
    for k in 1..order {
        nlsf[k] = nlsf[k].max(nlsf[k - 1].saturating_add(min_spacing[k]));
    }
    nlsf[order - 1] = nlsf[order - 1].min((32768 - spacing(order)) as i16);
    for k in (0..order - 1).rev() {
        let below_next = i32::from(nlsf[k + 1]) - spacing(k + 1);
        nlsf[k] = i32::from(nlsf[k]).min(below_next) as i16;
    }
}

/// The first half-frame's NLSFs: `previous` moved towards `current` by `factor_q2` / 4
/// (RFC 6716 4.2.7.5.5).
pub(super) fn interpolate(previous: &[i16], current: &[i16], factor_q2: u8) -> [i16; MAX_ORDER] {
    let mut out = [0i16; MAX_ORDER];
    for ((o, &p), &c) in out.iter_mut().zip(previous).zip(current) {
        let step = (i32::from(factor_q2) * (i32::from(c) - i32::from(p))) >> 2;
        *o = (i32::from(p) + step) as i16;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spacing_ok(nlsf: &[i16], min: &[i16]) -> bool {
        let order = nlsf.len();
        nlsf[0] >= min[0]
            && (1..order).all(|k| i32::from(nlsf[k]) - i32::from(nlsf[k - 1]) >= i32::from(min[k]))
            && 32768 - i32::from(nlsf[order - 1]) >= i32::from(min[order])
    }

    #[test]
    fn zero_residuals_give_the_stage1_vector() {
        for codebook in [Codebook::NarrowMedium, Codebook::Wide] {
            let order = codebook.order();
            for vector in 0..32 {
                let nlsf = reconstruct(codebook, vector, &vec![0; order]).unwrap();
                let base = codebook.stage1_q8(vector).unwrap();
                for k in 0..order {
                    // Stabilisation may move a coefficient a little; nothing else does.
                    assert!(
                        (i32::from(nlsf[k]) - (i32::from(base[k]) << 7)).abs() <= 300,
                        "{codebook:?} {vector} {k}"
                    );
                }
                assert!(nlsf[order..].iter().all(|&v| v == 0));
            }
        }
    }

    #[test]
    fn residuals_move_coefficients_by_the_weighted_step() {
        // A lone +1 on the last coefficient (no prediction from above): (1024 - 102) * step
        // in Q10, divided by the Q9 weight and scaled to Q15.
        let codebook = Codebook::NarrowMedium;
        let mut residuals = [0i8; 10];
        residuals[9] = 1;
        let nlsf = reconstruct(codebook, 0, &residuals).unwrap();
        let base = reconstruct(codebook, 0, &[0; 10]).unwrap();
        let level_q10 = ((1024 - 102) * 11796) >> 16;
        let weight = i32::from(NLSF_NB_MB_WEIGHTS_Q9[0][9]);
        assert_eq!(
            i32::from(nlsf[9]) - i32::from(base[9]),
            (level_q10 << 14) / weight
        );
    }

    #[test]
    fn extreme_residuals_are_stabilised() {
        for codebook in [Codebook::NarrowMedium, Codebook::Wide] {
            let order = codebook.order();
            for pattern in [[10i8, -10], [-10, 10], [10, 10], [-10, -10]] {
                let residuals: Vec<i8> = (0..order).map(|k| pattern[k % 2]).collect();
                for vector in [0, 17, 31] {
                    let nlsf = reconstruct(codebook, vector, &residuals).unwrap();
                    assert!(
                        spacing_ok(&nlsf[..order], codebook.min_spacing_q15()),
                        "{codebook:?} {vector} {pattern:?}: {nlsf:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn stabilize_separates_a_collapsed_vector() {
        let min = NLSF_NB_MB_MIN_SPACING_Q15;
        let mut nlsf = [16000i16; 10];
        stabilize(&mut nlsf, &min);
        assert!(spacing_ok(&nlsf, &min), "{nlsf:?}");
        let mut nlsf = [32767i16, 0, 32767, 0, 5, 5, 5, 5, 32000, 1];
        stabilize(&mut nlsf, &min);
        assert!(spacing_ok(&nlsf, &min), "{nlsf:?}");
        // Too few spacings: left alone rather than indexing past them.
        let mut short = [3i16, 2, 1];
        stabilize(&mut short, &min[..2]);
        assert_eq!(short, [3, 2, 1]);
    }

    #[test]
    fn bad_indices_are_errors() {
        assert_eq!(
            reconstruct(Codebook::Wide, 32, &[0; 16]),
            Err(NlsfIndexError::Stage1(32))
        );
        assert_eq!(
            reconstruct(Codebook::Wide, 0, &[0; 10]),
            Err(NlsfIndexError::ResidualCount {
                given: 10,
                order: 16
            })
        );
        assert_eq!(
            reconstruct(Codebook::NarrowMedium, 0, &[11; 10]),
            Err(NlsfIndexError::Residual(11))
        );
    }

    #[test]
    fn interpolation_moves_by_quarters() {
        let previous = [1000i16, 2000];
        let current = [2000i16, 1000];
        assert_eq!(interpolate(&previous, &current, 0)[..2], [1000, 2000]);
        assert_eq!(interpolate(&previous, &current, 1)[..2], [1250, 1750]);
        assert_eq!(interpolate(&previous, &current, 3)[..2], [1750, 1250]);
        assert_eq!(interpolate(&previous, &current, 4)[..2], [2000, 1000]);
    }
}
