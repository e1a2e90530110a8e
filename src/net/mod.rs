//! Real-time transport: RTP/RTCP (RFC 3550) carrying Speex (RFC 5574) over UDP, an adaptive
//! jitter buffer with loss concealment, SRTP (RFC 3711) keyed from a room passphrase, sessions
//! with several peers on one socket thread, and a relay that forwards rooms it cannot read.
//!
//! One UDP port carries everything, told apart by the first bytes of each datagram: RTP and
//! RTCP share it as in RFC 5761 (RTCP packet types 200..=204 sit where RTP's marker bit and
//! payload type are), and relay control datagrams start with a magic whose version bits are
//! not 2.

pub mod control;
pub mod jitter;
pub mod peer;
pub mod relay;
pub mod rtcp;
pub mod rtp;
pub mod session;
pub mod split;
pub mod srtp;

/// The dynamic payload type used for Speex, as GStreamer's rtpspeexpay does.
pub const PAYLOAD_TYPE: u8 = 110;
/// RTP clock rate of narrowband Speex.
pub const CLOCK_RATE: u32 = 8000;
/// RTP timestamp units per 20 ms frame.
pub const TIMESTAMP_STEP: u32 = 160;
/// Largest datagram we read or forward; Speex packets are far smaller.
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
    #[error(transparent)]
    Codec(#[from] crate::codec::speex::codec::CodecError),
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
