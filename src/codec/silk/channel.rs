//! One SILK channel: the decoder state that the bitstream's conditional coding and the NLSF
//! interpolation depend on, and the reading of one frame's indices (RFC 6716 4.2.7) and
//! excitation (4.2.7.8, read only to reach what follows it).

use super::nlsf::{self, Codebook, CodebookTables, MAX_ORDER, RESIDUAL_MAX};
use super::range::RangeDecoder;
use super::tables::{
    EXCITATION_LSB_ICDF, EXCITATION_SIGN_ICDF, FRAME_TYPE_ACTIVE_ICDF, FRAME_TYPE_INACTIVE_ICDF,
    GAIN_DELTA_ICDF, GAIN_MSB_ICDF, LTP_FILTER_0_ICDF, LTP_FILTER_1_ICDF, LTP_FILTER_2_ICDF,
    LTP_PERIODICITY_ICDF, LTP_SCALING_ICDF, NLSF_EXTENSION_ICDF, NLSF_INTERPOLATION_ICDF,
    PITCH_CONTOUR_10MS_ICDF, PITCH_CONTOUR_10MS_NB_ICDF, PITCH_CONTOUR_20MS_ICDF,
    PITCH_CONTOUR_20MS_NB_ICDF, PITCH_LAG_DELTA_ICDF, PITCH_LAG_HIGH_ICDF, PULSE_COUNT_ICDF,
    RATE_LEVEL_ICDF, SHELL_SPLIT_0_ICDF, SHELL_SPLIT_1_ICDF, SHELL_SPLIT_2_ICDF,
    SHELL_SPLIT_3_ICDF, SHELL_SPLIT_OFFSETS, UNIFORM4_ICDF, UNIFORM6_ICDF, UNIFORM8_ICDF,
};

/// Subframes of a 20 ms frame (a 10 ms frame has half as many).
pub const MAX_SUBFRAMES: usize = 4;
/// Samples per shell-coded excitation block.
const SHELL_BLOCK: usize = 16;
/// Blocks of the longest frame (20 ms at 16 kHz).
const MAX_SHELL_BLOCKS: usize = 20;
/// A pulse count symbol that announces one more LSB level instead of a count.
const PULSE_COUNT_ESCAPE: usize = 17;
/// After this many LSB levels the escape symbol is no longer possible.
const MAX_LSB_LEVELS: usize = 10;
/// Log-gain index range and the delta coding's limits (4.2.7.4).
const GAIN_LEVELS: i32 = 64;
const GAIN_DELTA_MIN: i32 = -4;
const GAIN_DELTA_MAX: i32 = 36;
/// The log-gain index a decoder starts from (and returns to after a loss or a rate change).
pub const GAIN_INDEX_AFTER_RESET: i32 = 10;

/// The frame type's signal class (RFC 6716 4.2.7.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SignalType {
    /// No voice activity.
    Inactive,
    Unvoiced,
    Voiced,
}

impl SignalType {
    fn index(self) -> usize {
        match self {
            SignalType::Inactive => 0,
            SignalType::Unvoiced => 1,
            SignalType::Voiced => 2,
        }
    }
}

/// How a frame's first gain (and LTP scaling) is coded, from its place in the packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Coding {
    Independent,
    /// Independent, but the LTP scaling is not coded (a side channel after mid-only frames).
    IndependentNoLtpScaling,
    /// Relative to the previous frame of the same packet.
    Conditional,
}

/// What one frame's side information holds, as far as the walker keeps it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Indices {
    pub signal_type: SignalType,
    pub high_quant_offset: bool,
    pub gains: [u8; MAX_SUBFRAMES],
    pub nlsf_stage1: u8,
    pub nlsf_residuals: [i8; MAX_ORDER],
    pub interpolation_q2: u8,
}

/// The NLSF state after a frame, as the decoder holds it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Parameters {
    pub nlsf_q15: [i16; MAX_ORDER],
    /// Interpolation weight in use (4: none), after the decoder's overrides.
    pub interpolation_q2: u8,
    pub first_half_q15: Option<[i16; MAX_ORDER]>,
    /// The log-gain index (0..64) of each subframe.
    pub gain_indices: [u8; MAX_SUBFRAMES],
}

/// One channel's decoder state, as far as the bitstream and the NLSFs depend on it.
#[derive(Debug, Clone)]
pub struct Channel {
    /// Internal rate in kHz (8, 12, 16), 0 before the first frame.
    rate_khz: u32,
    subframes: usize,
    codebook: Codebook,
    previous_nlsf: [i16; MAX_ORDER],
    first_frame_after_reset: bool,
    last_gain_index: i32,
    /// The previous frame's type, for the relative pitch-lag coding (regular or LBRR).
    previous_signal_type: SignalType,
    pub vad: [bool; 3],
    pub lbrr: [bool; 3],
}

impl Default for Channel {
    fn default() -> Self {
        Self::new()
    }
}

impl Channel {
    /// A freshly initialised channel decoder.
    pub const fn new() -> Self {
        Self {
            rate_khz: 0,
            subframes: MAX_SUBFRAMES,
            codebook: Codebook::NarrowMedium,
            previous_nlsf: [0; MAX_ORDER],
            first_frame_after_reset: true,
            last_gain_index: 0,
            previous_signal_type: SignalType::Inactive,
            vad: [false; 3],
            lbrr: [false; 3],
        }
    }

    pub fn codebook(&self) -> Codebook {
        self.codebook
    }

    /// Samples per frame at the internal rate.
    fn frame_length(&self) -> usize {
        self.subframes * 5 * self.rate_khz as usize
    }

    /// Sets the internal rate and frame size for the next frames; a new rate resets what
    /// depends on it, as the decoder does.
    pub fn configure(&mut self, rate_khz: u32, subframes: usize) {
        self.subframes = subframes;
        if rate_khz != self.rate_khz {
            self.rate_khz = rate_khz;
            self.codebook = if rate_khz == 16 {
                Codebook::Wide
            } else {
                Codebook::NarrowMedium
            };
            self.first_frame_after_reset = true;
            self.last_gain_index = GAIN_INDEX_AFTER_RESET;
        }
    }

    /// What a lost frame does to the state the walker tracks.
    pub fn conceal(&mut self) {
        self.last_gain_index = GAIN_INDEX_AFTER_RESET;
    }

    /// Marks the next frame as the first after a reset (no NLSF interpolation).
    pub fn restart(&mut self) {
        self.first_frame_after_reset = true;
        self.last_gain_index = GAIN_INDEX_AFTER_RESET;
    }

    /// Reads a frame's side information up to the NLSF interpolation weight (4.2.7.3-
    /// 4.2.7.5); LBRR frames count as `active`. [`Channel::skip_rest`] reads the rest.
    pub fn read_indices(
        &mut self,
        decoder: &mut RangeDecoder<'_>,
        active: bool,
        coding: Coding,
    ) -> Indices {
        // A copy that lives in registers: each symbol depends on the state the previous one
        // left, and a round trip through memory per symbol would lengthen that chain.
        let mut local = decoder.clone();
        let indices = self.read_indices_from(&mut local, active, coding);
        *decoder = local;
        indices
    }

    #[inline(always)]
    fn read_indices_from(
        &mut self,
        decoder: &mut RangeDecoder<'_>,
        active: bool,
        coding: Coding,
    ) -> Indices {
        let type_symbol = if active {
            decoder.decode_icdf_counted(&FRAME_TYPE_ACTIVE_ICDF) + 2
        } else {
            decoder.decode_icdf_counted(&FRAME_TYPE_INACTIVE_ICDF)
        };
        let signal_type = match type_symbol >> 1 {
            0 => SignalType::Inactive,
            1 => SignalType::Unvoiced,
            _ => SignalType::Voiced,
        };
        let high_quant_offset = type_symbol & 1 == 1;

        let mut gains = [0u8; MAX_SUBFRAMES];
        gains[0] = if coding == Coding::Conditional {
            decoder.decode_icdf(&GAIN_DELTA_ICDF) as u8
        } else {
            let msb = decoder.decode_icdf_counted(&GAIN_MSB_ICDF[signal_type.index()]);
            let lsb = decoder.decode_icdf_counted(&UNIFORM8_ICDF);
            (msb * 8 + lsb) as u8
        };
        for gain in gains.iter_mut().take(self.subframes).skip(1) {
            *gain = decoder.decode_icdf(&GAIN_DELTA_ICDF) as u8;
        }

        let voiced = signal_type == SignalType::Voiced;
        let (nlsf_stage1, nlsf_residuals) = match self.codebook {
            Codebook::NarrowMedium => read_nlsf_indices(decoder, &nlsf::NB_MB, voiced),
            Codebook::Wide => read_nlsf_indices(decoder, &nlsf::WB, voiced),
        };
        let interpolation_q2 = if self.subframes == MAX_SUBFRAMES {
            decoder.decode_icdf_counted(&NLSF_INTERPOLATION_ICDF) as u8
        } else {
            4
        };

        Indices {
            signal_type,
            high_quant_offset,
            gains,
            nlsf_stage1: nlsf_stage1 as u8,
            nlsf_residuals,
            interpolation_q2,
        }
    }

    /// Reads past the rest of the frame after [`Channel::read_indices`]: pitch and LTP
    /// parameters, seed and excitation (4.2.7.6-4.2.7.8).
    pub fn skip_rest(&mut self, decoder: &mut RangeDecoder<'_>, indices: &Indices, coding: Coding) {
        if indices.signal_type == SignalType::Voiced {
            self.skip_pitch_and_ltp(decoder, coding);
        }
        self.previous_signal_type = indices.signal_type;
        // The excitation's LCG seed.
        decoder.decode_icdf(&UNIFORM4_ICDF);
        self.skip_excitation(decoder, indices);
    }

    /// Leaves the frame after its indices: what follows is not read, but the frame's type
    /// still sets the context of the next frame's pitch coding.
    pub fn stop_after_indices(&mut self, indices: &Indices) {
        self.previous_signal_type = indices.signal_type;
    }

    /// Pitch lags, contour, LTP filters and scaling (4.2.7.6): read past.
    fn skip_pitch_and_ltp(&self, decoder: &mut RangeDecoder<'_>, coding: Coding) {
        let mut absolute_lag = true;
        if coding == Coding::Conditional && self.previous_signal_type == SignalType::Voiced {
            // Symbol 0 escapes to absolute coding; others are the lag change + 9.
            absolute_lag = decoder.decode_icdf(&PITCH_LAG_DELTA_ICDF) == 0;
        }
        if absolute_lag {
            decoder.decode_icdf(&PITCH_LAG_HIGH_ICDF);
            decoder.decode_icdf(match self.rate_khz {
                8 => &UNIFORM4_ICDF[..],
                12 => &UNIFORM6_ICDF[..],
                _ => &UNIFORM8_ICDF[..],
            });
        }
        let contour: &[u8] = match (self.rate_khz, self.subframes == MAX_SUBFRAMES) {
            (8, true) => &PITCH_CONTOUR_20MS_NB_ICDF,
            (8, false) => &PITCH_CONTOUR_10MS_NB_ICDF,
            (_, true) => &PITCH_CONTOUR_20MS_ICDF,
            (_, false) => &PITCH_CONTOUR_10MS_ICDF,
        };
        decoder.decode_icdf(contour);
        let filters: &[u8] = match decoder.decode_icdf(&LTP_PERIODICITY_ICDF) {
            0 => &LTP_FILTER_0_ICDF,
            1 => &LTP_FILTER_1_ICDF,
            _ => &LTP_FILTER_2_ICDF,
        };
        for _ in 0..self.subframes {
            decoder.decode_icdf(filters);
        }
        if coding == Coding::Independent {
            decoder.decode_icdf(&LTP_SCALING_ICDF);
        }
    }

    /// Reads past the frame's excitation (4.2.7.8): rate level, pulse counts, shell-coded
    /// pulse positions, LSBs and signs. Work is bounded by the frame length.
    fn skip_excitation(&self, decoder: &mut RangeDecoder<'_>, indices: &Indices) {
        let voiced = indices.signal_type == SignalType::Voiced;
        let rate_level = decoder.decode_icdf(row(&RATE_LEVEL_ICDF, usize::from(voiced)));
        let blocks = self
            .frame_length()
            .div_ceil(SHELL_BLOCK)
            .min(MAX_SHELL_BLOCKS);

        let mut counts = [0usize; MAX_SHELL_BLOCKS];
        let mut lsb_levels = [0usize; MAX_SHELL_BLOCKS];
        for (count, levels) in counts.iter_mut().zip(&mut lsb_levels).take(blocks) {
            *count = decoder.decode_icdf(row(&PULSE_COUNT_ICDF, rate_level));
            while *count == PULSE_COUNT_ESCAPE {
                *levels += 1;
                let escaped = row(&PULSE_COUNT_ICDF, PULSE_COUNT_ICDF.len() - 1);
                // With all LSB levels used up, the table starts one entry later, which
                // removes the escape symbol.
                let table = escaped.get(usize::from(*levels == MAX_LSB_LEVELS)..);
                *count = decoder.decode_icdf(table.unwrap_or_default());
            }
        }

        let mut magnitudes = [[0u32; SHELL_BLOCK]; MAX_SHELL_BLOCKS];
        for (block, &count) in magnitudes.iter_mut().zip(&counts).take(blocks) {
            if count > 0 {
                shell_split(decoder, count, 3, block);
            }
        }
        for (block, &levels) in magnitudes.iter_mut().zip(&lsb_levels).take(blocks) {
            if levels > 0 {
                for magnitude in block.iter_mut() {
                    for _ in 0..levels {
                        let bit = decoder.decode_icdf(&EXCITATION_LSB_ICDF) as u32;
                        *magnitude = (*magnitude << 1) | bit;
                    }
                }
            }
        }

        let sign_base =
            7 * (usize::from(indices.high_quant_offset) + 2 * indices.signal_type.index());
        for ((block, &count), &levels) in
            magnitudes.iter().zip(&counts).zip(&lsb_levels).take(blocks)
        {
            if count == 0 && levels == 0 {
                continue;
            }
            let first = EXCITATION_SIGN_ICDF
                .get(sign_base + count.min(6))
                .copied()
                .unwrap_or(128);
            let distribution = [first, 0];
            for _ in block.iter().filter(|&&m| m > 0) {
                decoder.decode_icdf(&distribution);
            }
        }
    }

    /// The decoder's parameter step for a regular frame (4.2.7.4-4.2.7.5.5): dequantised
    /// gain indices, the NLSFs, and the interpolation, updating the state.
    pub fn apply(&mut self, indices: &Indices, coding: Coding) -> Parameters {
        let mut gain_indices = [0u8; MAX_SUBFRAMES];
        for (k, (out, &index)) in gain_indices
            .iter_mut()
            .zip(&indices.gains)
            .take(self.subframes)
            .enumerate()
        {
            let index = i32::from(index);
            if k == 0 && coding != Coding::Conditional {
                // An absolute gain may drop at most 16 steps below the previous one.
                self.last_gain_index = index.max(self.last_gain_index - 16);
            } else {
                let delta = index + GAIN_DELTA_MIN;
                let double_step_above = 2 * GAIN_DELTA_MAX - GAIN_LEVELS + self.last_gain_index;
                if delta > double_step_above {
                    self.last_gain_index += 2 * delta - double_step_above;
                } else {
                    self.last_gain_index += delta;
                }
            }
            self.last_gain_index = self.last_gain_index.clamp(0, GAIN_LEVELS - 1);
            *out = self.last_gain_index as u8;
        }

        let order = self.codebook.order();
        let nlsf_q15 = nlsf::reconstruct_padded(
            self.codebook,
            usize::from(indices.nlsf_stage1),
            &indices.nlsf_residuals,
        );
        let interpolation_q2 = if self.first_frame_after_reset {
            4
        } else {
            indices.interpolation_q2
        };
        let first_half_q15 = (interpolation_q2 < 4).then(|| {
            nlsf::interpolate(
                &self.previous_nlsf[..order],
                &nlsf_q15[..order],
                interpolation_q2,
            )
        });
        self.previous_nlsf = nlsf_q15;
        self.first_frame_after_reset = false;
        Parameters {
            nlsf_q15,
            interpolation_q2,
            first_half_q15,
            gain_indices,
        }
    }
}

/// The stage-1 index and the stage-2 residual indices (-10..=10) of a frame's NLSFs
/// (4.2.7.5.1-2); the residuals past the codebook's order stay 0.
#[inline(always)]
fn read_nlsf_indices<const ORDER: usize>(
    decoder: &mut RangeDecoder<'_>,
    codebook: &CodebookTables<ORDER>,
    voiced: bool,
) -> (usize, [i8; MAX_ORDER]) {
    // Each table spelled out, so that its search is unrolled with the table's constants.
    let vector = if voiced {
        decoder.decode_icdf(codebook.stage1_icdf(true))
    } else {
        decoder.decode_icdf(codebook.stage1_icdf(false))
    };
    let mut residuals = [0i8; MAX_ORDER];
    for (k, residual) in residuals.iter_mut().enumerate().take(ORDER) {
        let mut level = decoder.decode_icdf_counted(codebook.residual_icdf(vector, k)) as i32;
        if level == 0 {
            level -= decoder.decode_icdf(&NLSF_EXTENSION_ICDF) as i32;
        } else if level == 2 * RESIDUAL_MAX {
            level += decoder.decode_icdf(&NLSF_EXTENSION_ICDF) as i32;
        }
        *residual = (level - RESIDUAL_MAX) as i8;
    }
    (vector, residuals)
}

/// Row `index` of a table of distributions, or its last row (never reached: every index
/// comes from a distribution with as many symbols as the table has rows).
fn row<const N: usize>(table: &[[u8; N]], index: usize) -> &[u8] {
    table
        .get(index)
        .or_else(|| table.last())
        .map_or(&[], |r| &r[..])
}

/// Splits `count` pulses between the halves of `out` (16, 8, 4, 2 samples at levels 3..0),
/// depth first as the bitstream orders them (4.2.7.8.3).
fn shell_split(decoder: &mut RangeDecoder<'_>, count: usize, level: usize, out: &mut [u32]) {
    let table: &[u8] = match level {
        3 => &SHELL_SPLIT_3_ICDF,
        2 => &SHELL_SPLIT_2_ICDF,
        1 => &SHELL_SPLIT_1_ICDF,
        _ => &SHELL_SPLIT_0_ICDF,
    };
    let (left, right) = if count > 0 {
        let start = SHELL_SPLIT_OFFSETS
            .get(count)
            .map_or(0, |&o| usize::from(o));
        let left = decoder.decode_icdf(table.get(start..).unwrap_or_default());
        (left, count.saturating_sub(left))
    } else {
        (0, 0)
    };
    let half = out.len() / 2;
    let (low, high) = out.split_at_mut(half);
    if level == 0 || half < 2 {
        if let (Some(l), Some(h)) = (low.first_mut(), high.first_mut()) {
            *l = left as u32;
            *h = right as u32;
        }
    } else {
        shell_split(decoder, left, level - 1, low);
        shell_split(decoder, right, level - 1, high);
    }
}
