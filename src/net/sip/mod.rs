//! Phone calls over SIP (RFC 3261): a user agent on the ezk stack ([`agent`]) that registers
//! ([`register`]), SDP offer and answer ([`sdp`]), and the call's RTP: a session configured
//! for what SDP negotiated ([`media`]).

pub mod address;
pub mod agent;
pub mod backend;
pub mod dial;
pub mod error;
pub mod guard;
pub mod media;
pub mod ptime;
pub mod quiet;
pub mod register;
pub mod sdp;
pub mod transport;
