//! The words every layer shares: one 20 ms frame and its feature row, the visemes and their
//! weights, the face's pose. It sits at the bottom: every module may import it, and it imports
//! nothing of the crate.

pub mod audio;
pub mod features;
pub mod pose;
pub mod visemes;

pub use audio::{FrameAudio, MAX_AUDIO_RATE, MAX_FRAME_SAMPLES};
pub use features::{
    FRAME_SIZE, FeatureFamily, FrameFeatures, LSP_COUNT, LSP_MARGIN, SAMPLE_RATE, SILENCE_DB,
    energy_db, flat_lsp, ordered_lsp,
};
pub use pose::FacePose;
pub use visemes::{
    FullWeights, REDUCED_ORDER, VISEME_COUNT, VISEME_NAMES, Viseme, VisemeError, VisemeSet,
    VisemeWeights,
};
