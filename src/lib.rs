//! lipcall: voice chat with lip-synced heads driven by the Speex decoder's own LSPs.

pub mod app;
pub mod audio;
pub mod commands;
pub mod lipsync;
pub mod net;
pub mod render;
pub mod speex;
pub mod train;
