//! The command-line subcommands. Each takes its parsed arguments and returns an anyhow error
//! whose one-line rendering is what the user sees.

pub mod animate;
pub mod audio;
pub mod codec;
pub mod lipsync;
pub mod net;
