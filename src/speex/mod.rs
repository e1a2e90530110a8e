//! Speex narrowband: the reference codec behind a safe wrapper, a pure-Rust bitstream walker,
//! Ogg Speex files and the per-frame features the lip-sync network eats.

pub mod bitstream;
pub mod features;
mod lsp_tables;

/// Samples per narrowband frame (20 ms at 8 kHz).
pub const FRAME_SIZE: usize = 160;
/// Narrowband sample rate.
pub const SAMPLE_RATE: u32 = 8000;
/// Number of line spectral pairs in a narrowband frame.
pub const LSP_COUNT: usize = 10;
