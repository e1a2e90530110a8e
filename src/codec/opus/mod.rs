//! Opus through libopus: decoding, encoding and Ogg Opus files (RFC 7845).

pub mod codec;
pub mod features;
pub mod fec;
mod nlsf_map;
pub mod ogg_file;
pub mod stream;

pub use crate::vocab::{FRAME_SIZE, SAMPLE_RATE};
