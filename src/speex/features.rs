//! Per-frame inputs of the lip-sync network: the decoder's 10 LSPs and the frame energy.

use super::LSP_COUNT;

/// What the receiver knows about one 20 ms frame once it has decoded it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameFeatures {
    /// Narrowband mode of the frame (0..=8), or `None` for a concealed (lost) frame.
    pub mode: Option<u8>,
    /// Quantised LSPs in radians, strictly increasing in (0, pi).
    pub lsp: [f32; LSP_COUNT],
    /// Energy of the decoded samples these LSPs shaped, in dB relative to full scale.
    pub energy_db: f32,
}
