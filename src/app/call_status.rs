//! What the call bar shows of the call: its state, who can hear it, the codec sent, the last
//! error. Written by the engine's worker and the transports' follow-ups, read by the UI.

use std::net::SocketAddr;

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
