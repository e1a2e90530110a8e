//! The receive side of a call, shared by the app, the command line and evaluation: the link
//! every transport implements, the per-peer pipeline from decoded frames to tagged weights and
//! poses, the one opener of media files, and the CSV formats.

pub mod csv;
pub mod events;
pub mod janus;
pub mod link;
pub mod media;
pub mod mumble;
pub mod pipeline;
pub mod sip;
pub mod sip_sockets;
