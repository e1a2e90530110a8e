//! What a session is configured with and what it reports: shared by its sans-I/O core and the
//! handle that drives it.

use std::net::SocketAddr;
use std::time::Duration;

use crate::codec::any::{Codec, PayloadMap};
use crate::net::control::Refusal;
use crate::net::jitter::JitterConfig;
use crate::net::session::latch::Latch;
use crate::net::srtp::{DEFAULT_CLOCK_TOLERANCE, MasterKey};

#[derive(Debug, Clone)]
pub struct SessionConfig {
    pub bind: SocketAddr,
    /// Where media and reports go: peers of a mesh, or the relay.
    pub destinations: Vec<SocketAddr>,
    /// A relay room to join (the relay is `destinations[0]`).
    pub room: Option<String>,
    /// SRTP master key; `None` sends plain RTP.
    pub key: Option<MasterKey>,
    /// The key the peer's SRTP is made with where it is not `key` (SDES: each side sends
    /// under a key of its own); `None`: `key` both ways.
    pub peer_key: Option<MasterKey>,
    /// Where peers may send from, and whether they may move.
    pub latch: Latch,
    /// How far a new SRTP stream's sender clock may be from ours (per-session keys: a stream
    /// stamped further off is a replay of an earlier call, or a clock that is wrong).
    pub clock_tolerance: Duration,
    /// Display name sent as SDES NAME.
    pub name: Option<String>,
    pub jitter: JitterConfig,
    pub max_peers: usize,
    /// Peers silent for this long are forgotten.
    pub peer_timeout: Duration,
    /// Mean interval between RTCP reports (randomised by +-50 %).
    pub rtcp_interval: Duration,
    pub keepalive_interval: Duration,
    pub send_rtcp: bool,
    /// Perceptual enhancer in the decoders.
    pub enhancer: bool,
    /// Fixed SSRC (for interop set-ups that need it in advance); random when `None`.
    pub ssrc: Option<u32>,
    /// The codec this session sends.
    pub codec: Codec,
    /// A listening session whose callers wait for the user's answer: the reports to a caller
    /// not answered say it rings ([`crate::net::rtcp::RINGING_NOTE`]), and one hung up on
    /// before its answer hears it was declined.
    pub rings_for_callers: bool,
    /// Which codec each payload type carries, received and sent.
    pub payloads: PayloadMap,
    /// A call whose media a description negotiated (SIP): one remote stream, the agreed
    /// payload types only, hold and a keepalive ([`NegotiatedCall`]).
    pub call: Option<NegotiatedCall>,
}

/// What a negotiated two-party call (SIP's SDP) adds to a session's rules. The session keeps
/// one remote stream: a second SSRC replaces it only after the current one has been silent
/// for [`super::STREAM_HANDOVER`], so a stray or echoed stream never cuts into the call.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NegotiatedCall {
    /// The audio payload types the description agreed; media of any other is counted
    /// (`unknown_payload`) and dropped.
    pub audio_types: Vec<u8>,
    /// The RFC 4733 events' payload type, if agreed: received ones are counted, and
    /// [`super::SessionCore::queue_digits`] sends DTMF.
    pub events: Option<u8>,
    /// The peer receives nothing (it holds the call, or is send-only): nothing is sent,
    /// the stream's clock moves on.
    pub held: bool,
    /// A call that sent nothing for this long sends an empty datagram, so that a NAT on the
    /// way keeps the media's mapping (RFC 6263); `None`: never.
    pub keepalive: Option<Duration>,
}

impl SessionConfig {
    pub fn new(bind: SocketAddr) -> Self {
        Self {
            bind,
            destinations: Vec::new(),
            room: None,
            key: None,
            peer_key: None,
            latch: Latch::Rebinding,
            clock_tolerance: Duration::from_secs(u64::from(DEFAULT_CLOCK_TOLERANCE)),
            name: None,
            jitter: JitterConfig::default(),
            max_peers: 32,
            peer_timeout: Duration::from_secs(30),
            rtcp_interval: Duration::from_secs(5),
            keepalive_interval: Duration::from_secs(5),
            send_rtcp: true,
            enhancer: true,
            ssrc: None,
            codec: Codec::Speex,
            payloads: PayloadMap::default(),
            call: None,
            rings_for_callers: false,
        }
    }
}

/// Datagram counters of a session.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SessionStats {
    pub datagrams: u64,
    pub bytes: u64,
    pub rtp: u64,
    pub rtcp: u64,
    pub control: u64,
    /// Unparseable RTP/RTCP/control datagrams, and oversized ones (cut short by the socket,
    /// dropped unparsed).
    pub malformed: u64,
    /// Datagrams of no known kind.
    pub unknown: u64,
    /// RTP packets of a payload type no codec is mapped to (dropped, never decoded).
    pub unknown_payload: u64,
    /// SRTP/SRTCP packets that failed authentication.
    pub auth_failed: u64,
    pub replayed: u64,
    /// SRTP streams new to us stamped further from our clock than `clock_tolerance`: a replay
    /// of an earlier call, or a sender whose clock is off.
    pub stale: u64,
    /// Packets from new SSRCs beyond `max_peers`.
    pub too_many_peers: u64,
    /// Unconfirmed or idle peers removed to make room for a new one.
    pub evicted: u64,
    /// RTP or RTCP about a known peer from an address other than its own (ignored).
    pub foreign: u64,
    /// Peers that moved to a new address (their stream continued from it).
    pub moved: u64,
    /// Datagrams from callers the user hung up on, kept out.
    pub blocked: u64,
    /// Our own packets coming back (a relay or multicast echo).
    pub own: u64,
    /// Reports naming our stream: someone hears us, even a pure receiver that never sends.
    pub reports_about_us: u64,
    /// Those of them from where we call, whose sender said it rings for us (not answered yet).
    pub ringing_reports: u64,
    /// Goodbyes from where we call that said our call was declined.
    pub declined: u64,
    /// RTCP not believed: the part of `foreign` that is reports (a fixed call's only).
    pub foreign_rtcp: u64,
    /// The part of `auth_failed` that is SRTCP (baresip sends its first report and its BYE
    /// in the clear even under SRTP).
    pub rtcp_auth_failed: u64,
    /// A negotiated call's packets of a second stream while its current one still sends.
    pub other_stream: u64,
    /// RFC 4733 event packets received (a negotiated call's).
    pub events_in: u64,
    pub sent_events: u64,
    /// Empty datagrams sent to keep a NAT's mapping open ([`NegotiatedCall::keepalive`]).
    pub keepalives: u64,
    pub sent_rtp: u64,
    pub sent_rtcp: u64,
    pub send_errors: u64,
    /// The relay confirmed our place in the room.
    pub relay_joined: bool,
    /// Why the relay last turned our join down (cleared when it confirms one).
    pub relay_refusal: Option<Refusal>,
    /// Cookies the relay sent us to confirm our address with.
    pub relay_challenges: u64,
    /// The relay speaks another protocol version (an outdated lipcall on one side).
    pub relay_outdated: bool,
}
