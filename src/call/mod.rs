//! The receive side of a call, shared by the app, the command line and evaluation: the
//! per-peer pipeline from decoded frames to tagged weights and poses.

pub mod pipeline;
