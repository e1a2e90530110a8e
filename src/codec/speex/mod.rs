//! Speex narrowband: the reference codec behind a safe wrapper, a pure-Rust bitstream walker,
//! Ogg Speex files and the per-frame features the lip-sync network eats.

pub mod bitstream;
pub mod codec;
pub mod features;
mod lsp_tables;
pub mod ogg_file;
pub mod split;
pub mod stream;

pub use crate::vocab::{FRAME_SIZE, LSP_COUNT, SAMPLE_RATE};
