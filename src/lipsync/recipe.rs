//! The recipe of the shipped default network (`assets/models/default.lipmodel`), and the
//! defaults of `lipcall train`. docs/model.md logs how each value was chosen on the validation
//! speakers.

/// Viseme set of the default network (`--visemes`).
pub const VISEMES: &str = "PP,FF,aa,I,U";
pub const HIDDEN: usize = 8;
pub const CONTEXT: usize = 2;
pub const LOOKAHEAD: usize = 1;
pub const SPEAKER_NORM_FRAMES: u32 = 150;
pub const ENERGY_CONTEXT: usize = 6;
pub const PEAK_DECAY_DB: f32 = 0.15;
pub const CLOSURE_WEIGHT: f32 = 8.0;
pub const LABIODENTAL_WEIGHT: f32 = 6.0;
pub const SEGMENT_CLOSURE_WEIGHT: f32 = 0.0;
pub const WARP: f32 = 0.0;
pub const WEIGHT_DECAY: f32 = 0.0;
pub const OPENNESS_WEIGHT: f32 = 20.0;
pub const WIDTH_WEIGHT: f32 = 20.0;
pub const ROUNDING_WEIGHT: f32 = 20.0;
/// Codec versions of each training utterance.
pub const CODEC_VERSIONS: usize = 6;
/// Loss weight of AN4's force-aligned frames (TIMIT's hand-labelled ones weigh 1).
pub const AN4_WEIGHT: f32 = 0.1;
pub const AN4_CODEC_VERSIONS: usize = 1;
pub const SEED: u64 = 0x5EED_CAFE;
/// Measured lips (`train --grid`): loss weight of a video frame, s1 clips and codec versions
/// used, the weight of the squared aperture and width errors, and how much earlier than its
/// audio frame the lips are taken (none: s1's lip opening trails his sound's energy by about
/// 11 ms; see docs/model.md).
pub const LIP_WEIGHT: f32 = 1.0;
pub const LIP_CLIPS: usize = 300;
pub const LIP_VERSIONS: usize = 2;
pub const LIP_CUE_WEIGHT: f32 = 20.0;
pub const LIP_SHIFT_MS: u32 = 0;
