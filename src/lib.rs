//! lipcall: voice chat with lip-synced heads driven by the vocal-tract shape the codec already carries.

pub mod app;
pub mod audio;
pub mod call;
pub mod codec;
pub mod commands;
pub mod input;
pub mod lipsync;
pub mod net;
pub mod render;
pub mod secrets;
pub mod train;
pub mod vocab;
