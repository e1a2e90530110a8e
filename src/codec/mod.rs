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
