//! Real-time transport: RTP/RTCP (RFC 3550) over UDP, an adaptive jitter buffer, SRTP
//! (RFC 3711) keyed from a room passphrase, sessions with several peers on one socket thread,
//! and a relay that forwards rooms it cannot read.
//!
//! The transport is codec-agnostic: it carries payloads and decides when each is played. Which
//! codec a payload type carries, how long a payload lasts and how it decodes are asked of the
//! codec layer ([`crate::codec::any`], [`crate::codec::decoder`]).
//!
//! One UDP port carries everything, told apart by the first bytes of each datagram: RTP and
//! RTCP share it as in RFC 5761 (RTCP packet types 200..=204 sit where RTP's marker bit and
//! payload type are), and relay control datagrams start with a magic whose version bits are
//! not 2.

pub mod addr;
pub mod backoff;
pub mod control;
pub mod host_port;
pub mod janus;
pub mod jitter;
pub mod join;
pub mod mumble;
pub mod peer;
pub mod relay;
pub mod rtcp;
pub mod rtp;
pub mod session;
pub mod sip;
pub mod srtp;
pub mod stun;
pub mod transport;
pub mod turn;

/// Largest datagram we read or forward.
pub const MAX_DATAGRAM: usize = 1500;

/// What a datagram on a lipcall port is, from its first two bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DatagramKind {
    Rtp,
    Rtcp,
    Control,
    Unknown,
}

pub fn classify(datagram: &[u8]) -> DatagramKind {
    if datagram.starts_with(&control::MAGIC) {
        return DatagramKind::Control;
    }
    match datagram {
        [first, second, ..] if first >> 6 == 2 => {
            if (200..=204).contains(second) {
                DatagramKind::Rtcp
            } else {
                DatagramKind::Rtp
            }
        }
        _ => DatagramKind::Unknown,
    }
}

/// Everything the transport can fail with.
#[derive(Debug, thiserror::Error)]
pub enum NetError {
    #[error("{context}: {source}")]
    Io {
        context: String,
        source: std::io::Error,
    },
    #[error("no RTP payload type is mapped to {0}")]
    NoPayloadType(crate::codec::any::Codec),
    #[error(transparent)]
    Rtp(#[from] rtp::RtpError),
    #[error(transparent)]
    Rtcp(#[from] rtcp::RtcpError),
    #[error(transparent)]
    Srtp(#[from] srtp::SrtpError),
    #[error("no system randomness: {0}")]
    Random(#[from] getrandom::Error),
}

impl NetError {
    pub(crate) fn io(context: impl Into<String>, source: std::io::Error) -> Self {
        NetError::Io {
            context: context.into(),
            source,
        }
    }
}
