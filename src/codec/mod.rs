//! The codec layer: each codec decodes its payloads into 8 kHz frames and hands over the
//! features the lip-sync network eats (LSPs + energy), read from the bitstream where the codec
//! carries them and from an LPC analysis of the decoded audio where it does not.

pub mod any;
pub mod decoder;
pub mod g711;
pub mod g722;
pub mod lpc;
pub mod ogg;
pub mod opus;
pub mod silk;
pub mod speex;

/// Samples per 20 ms frame at the 8 kHz rate the features and the network work at.
pub const FRAME_SIZE: usize = 160;
/// The feature and playback rate.
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
