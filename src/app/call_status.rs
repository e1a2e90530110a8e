//! What the call bar shows of the call: its state, who can hear it, the codec sent, the last
//! error, and its phase ([`CallPhase`]). Written by the engine's worker and the transports' follow-ups, read by the UI.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use crate::codec::any::Codec;

/// Who can hear the call besides its members.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Encryption {
    /// Plain RTP: anyone on the path.
    #[default]
    None,
    /// lipcall's SRTP with the room passphrase: only those who know it (a relay cannot).
    EndToEnd,
    /// Encrypted to a server that decrypts and can hear it: WebRTC's DTLS-SRTP through Janus,
    /// TLS and OCB2-AES128 through a Mumble server.
    HopByHop,
}

/// The call as the UI shows it.
#[derive(Debug, Clone, Default)]
pub struct CallStatus {
    /// Where the call stands (idle, calling, ringing, in a call, failed, ended).
    pub phase: CallPhase,
    /// Human-readable state ("idle, listening on ..", "in call with ..").
    pub state: String,
    pub in_call: bool,
    pub encryption: Encryption,
    /// The codec we send in the call.
    pub codec: Option<Codec>,
    pub local_addr: Option<SocketAddr>,
    pub error: Option<String>,
    /// RTP packets of payload types no codec is mapped to, dropped (from anyone).
    pub unknown_payload: u64,
}

/// How long a direct call waits to hear anyone before it has failed.
pub const DIRECT_ANSWER_WAIT: Duration = Duration::from_secs(15);
/// How long a direct call rings at the called app before nobody answered: half a minute, as
/// a softphone rings before it gives up (Linphone's default for an incoming call).
pub const RINGING_ANSWER_WAIT: Duration = Duration::from_secs(30);

/// Where the call stands, the one account the call bar and the `--status` file both read.
/// A message that belongs to a phase (a reason, who hung up) lives in it, so it goes with it.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub enum CallPhase {
    #[default]
    Idle,
    /// Placing a call to `to`; a direct call that hears nobody by `deadline` has failed
    /// (other links have their own timeouts, which end in [`CallPhase::Failed`]); `ringing`
    /// once the called app says it rings there.
    Calling {
        to: String,
        deadline: Option<Instant>,
        ringing: bool,
    },
    /// A caller waits for Answer or Decline: the phone's SIP call, or a direct caller of the
    /// listening session at `caller` (heard, not yet sent our microphone).
    Ringing {
        from: String,
        caller: Option<SocketAddr>,
    },
    InCall {
        with: String,
        since: Instant,
    },
    /// The last call failed, and why (shown in red until the next call).
    Failed {
        reason: String,
    },
    /// The last call ended: who hung up, or how it ended.
    Ended {
        by: String,
    },
    /// A direct caller rang and stopped before it was answered.
    Missed {
        from: String,
    },
}

impl CallPhase {
    /// The word the `--status` file carries: `idle|calling|ringing|in_call|failed` (a call
    /// that ended is idle again).
    pub fn word(&self) -> &'static str {
        match self {
            Self::Idle | Self::Ended { .. } | Self::Missed { .. } => "idle",
            Self::Calling { .. } => "calling",
            Self::Ringing { .. } => "ringing",
            Self::InCall { .. } => "in_call",
            Self::Failed { .. } => "failed",
        }
    }

    /// What the call bar says of it, `now` for a call's length.
    pub fn describe(&self, now: Instant) -> String {
        match self {
            Self::Idle => "not in a call".into(),
            Self::Calling {
                to, ringing: true, ..
            } => format!("ringing {to}…"),
            Self::Calling { to, .. } => format!("calling {to}…"),
            Self::Ringing { from, .. } => format!("{from} is calling you"),
            Self::InCall { with, since } => {
                let secs = now.saturating_duration_since(*since).as_secs();
                format!("in a call with {with} ({}:{:02})", secs / 60, secs % 60)
            }
            Self::Failed { reason } => format!("call failed: {reason}"),
            Self::Ended { by } => format!("call ended: {by}"),
            Self::Missed { from } => format!("missed call from {from}"),
        }
    }

    /// Whether a call is being placed or held (ringing, idle, failed and ended are not).
    pub fn is_active(&self) -> bool {
        matches!(self, Self::Calling { .. } | Self::InCall { .. })
    }
}
