//! What can go wrong in a SIP call, as the user is told it.

use std::net::SocketAddr;

use super::sdp::SdpError;

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SipError {
    #[error("cannot use {addr} for SIP: {why}")]
    Bind { addr: SocketAddr, why: String },
    #[error("cannot reach {host}: {why}")]
    Unresolved { host: String, why: String },
    #[error("bad SIP address {0:?} (expected sip:USER@HOST[:PORT])")]
    BadUri(String),
    #[error("the registrar {0} did not answer within {1} s")]
    RegistrarSilent(String, u64),
    #[error("the registrar {0} refused our credentials: wrong user name or password")]
    BadCredentials(String),
    #[error(
        "the registrar {registrar} answered 423 Interval Too Brief again after we asked for \
         its Min-Expires ({min_expires} s): giving up"
    )]
    IntervalLoop { registrar: String, min_expires: u32 },
    #[error(
        "the registrar {registrar} demands registrations of at least {min_expires} s (423 \
         Min-Expires); lipcall takes at most {max} s"
    )]
    IntervalTooLong {
        registrar: String,
        min_expires: u32,
        max: u32,
    },
    #[error(
        "{asker} asked for our password in realm {realm:?} ({code}), which is not our account's \
         registrar or realm: refused, no digest sent"
    )]
    ForeignChallenge {
        asker: String,
        code: u16,
        realm: String,
    },
    #[error("the registrar {registrar} refused the registration: {code} {reason}")]
    RegisterRefused {
        registrar: String,
        code: u16,
        reason: String,
    },
    #[error("{target} refused the call: {code} {reason}")]
    CallRefused {
        target: String,
        code: u16,
        reason: String,
    },
    #[error("{0} did not answer (no response to the INVITE)")]
    NoAnswer(String),
    #[error("the call needs credentials that {0} did not accept (give --account and --password)")]
    CallAuth(String),
    #[error("the caller hung up before the call was answered")]
    CallerCancelled,
    #[error("the SIP exchange failed: {0}")]
    Protocol(String),
    #[error(transparent)]
    Sdp(#[from] SdpError),
    #[error("{0}")]
    Tls(String),
    #[error("cannot connect over {server}: {why}")]
    TlsRefused { server: String, why: String },
    #[error("the caller offered plain RTP and --srtp=required demands SRTP: refused with 488")]
    PlainOffer,
    #[error("cannot start the SIP thread: {0}")]
    Thread(String),
}
