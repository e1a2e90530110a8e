//! SDP offer and answer for one audio stream (RFC 3264, RFC 8866): what lipcall offers (Opus,
//! PCMU, PCMA and RFC 4733 telephone-event), reading a peer's description (its media address,
//! formats and direction), and choosing the codec both sides speak. RTCP goes where RFC 3550
//! puts it, the RTP port + 1, unless `a=rtcp` (RFC 3605) names another port, or both sides say
//! `a=rtcp-mux` (RFC 5761: on the RTP port); we offer both, and take mux where it is offered.
//!
//! Descriptions are ezk's typed [`SessionDescription`], as the SIP stack hands and takes them:
//! ours are built as its structs, a peer's read from its fields, and a body that comes as text
//! (our own INVITE's answer, a re-INVITE) is parsed by ezk once, after a size cap. What ezk
//! leaves open (payload types over 127, host names, port 0, key lengths) is checked here.

use std::net::{IpAddr, SocketAddr};

use bytesstr::BytesStr;
use ezk_sdp_types::{
    Connection, Fmtp, MediaDescription, MediaType, Origin, Rtcp, RtpMap, SessionDescription,
    SrtpCrypto, SrtpKeyingMaterial, SrtpSuite, TaggedAddress, Time, TransportProtocol,
    UnknownAttribute,
};

use super::ptime::{ms_attribute, send_frame_ms};
use crate::codec::any::{Codec, PayloadMap};
use crate::net::addr::{OddAddress, media_target};

/// A description longer than this is refused unread.
pub const MAX_SDP_BYTES: usize = 16 * 1024;
/// Formats on one media line that we look at.
const MAX_FORMATS: usize = 64;

/// The one SRTP crypto suite lipcall keys by SDES (RFC 4568), as src/net/srtp.rs runs it.
pub const SRTP_SUITE: &str = "AES_CM_128_HMAC_SHA1_80";
/// An SDES inline key: 16 bytes of master key, 14 of salt.
pub const SDES_KEY_LEN: usize = 30;

/// An SRTP master key and salt given in SDP; never printed.
#[derive(Clone, PartialEq, Eq)]
pub struct SdesKey(pub [u8; SDES_KEY_LEN]);

impl std::fmt::Debug for SdesKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("SdesKey(..)")
    }
}

impl SdesKey {
    pub fn random() -> Result<Self, getrandom::Error> {
        let mut key = [0; SDES_KEY_LEN];
        getrandom::fill(&mut key)?;
        Ok(Self(key))
    }

    fn keying(&self) -> SrtpKeyingMaterial {
        use base64::Engine;
        SrtpKeyingMaterial {
            key_and_salt: base64::engine::general_purpose::STANDARD
                .encode(self.0)
                .into(),
            lifetime: None,
            mki: None,
        }
    }

    /// The key of `inline:KEY[|LIFETIME][|MKI:LEN]` (RFC 4568 9.1); `None` where it is no
    /// key of our suite's length.
    fn read(keying: &SrtpKeyingMaterial) -> Option<Self> {
        use base64::Engine;
        let bytes = base64::engine::general_purpose::STANDARD
            .decode(keying.key_and_salt.as_str())
            .ok()?;
        Some(Self(bytes.try_into().ok()?))
    }
}

/// The peer's SDES crypto attribute we took.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Sdes {
    pub tag: u32,
    pub key: SdesKey,
}

fn read_crypto(crypto: &SrtpCrypto) -> Option<Sdes> {
    if crypto.suite != SrtpSuite::AES_CM_128_HMAC_SHA1_80 {
        return None;
    }
    Some(Sdes {
        tag: crypto.tag,
        key: SdesKey::read(crypto.keys.first()?)?,
    })
}

/// Payload types lipcall offers for what has no static type.
pub const OPUS_PT: u8 = 111;
pub const EVENT_PT: u8 = 101;
pub const EVENT_WIDE_PT: u8 = 102;

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SdpError {
    #[error("the session description is {0} bytes (at most {MAX_SDP_BYTES})")]
    TooLong(usize),
    #[error("the session description has no audio stream")]
    NoAudio,
    #[error("the audio stream was refused (port 0)")]
    Refused,
    #[error("the session description has no connection address (c=)")]
    NoAddress,
    #[error("malformed SDP line {line:?}: {why}")]
    Malformed { line: String, why: &'static str },
    #[error("no codec in common (the peer offers {0}; lipcall speaks Opus, G.722, PCMU and PCMA)")]
    NoCommonCodec(String),
    #[error("the peer offers SRTP with no crypto suite lipcall speaks ({SRTP_SUITE} by SDES)")]
    Encrypted,
    #[error("we asked for SRTP and the peer answered without it")]
    Unencrypted,
    #[error("the peer's media address cannot be used: {0}")]
    OddAddress(#[from] OddAddress),
}

/// Which way media flows, as one side says it (RFC 3264 section 5.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    SendRecv,
    SendOnly,
    RecvOnly,
    Inactive,
}

impl Direction {
    fn of(sdp: ezk_sdp_types::Direction) -> Self {
        match sdp {
            ezk_sdp_types::Direction::SendRecv => Direction::SendRecv,
            ezk_sdp_types::Direction::SendOnly => Direction::SendOnly,
            ezk_sdp_types::Direction::RecvOnly => Direction::RecvOnly,
            ezk_sdp_types::Direction::Inactive => Direction::Inactive,
        }
    }

    fn attribute(self) -> ezk_sdp_types::Direction {
        match self {
            Direction::SendRecv => ezk_sdp_types::Direction::SendRecv,
            Direction::SendOnly => ezk_sdp_types::Direction::SendOnly,
            Direction::RecvOnly => ezk_sdp_types::Direction::RecvOnly,
            Direction::Inactive => ezk_sdp_types::Direction::Inactive,
        }
    }

    /// The direction an answer gives to an offer of `self`.
    pub fn reversed(self) -> Self {
        match self {
            Direction::SendOnly => Direction::RecvOnly,
            Direction::RecvOnly => Direction::SendOnly,
            other => other,
        }
    }

    /// Whether the side that said it sends.
    pub fn sends(self) -> bool {
        matches!(self, Direction::SendRecv | Direction::SendOnly)
    }

    /// The same side, receiving nothing.
    fn deaf(self) -> Self {
        match self {
            Direction::SendRecv | Direction::SendOnly => Direction::SendOnly,
            Direction::RecvOnly | Direction::Inactive => Direction::Inactive,
        }
    }
}
/// One payload format of a media line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Format {
    pub payload_type: u8,
    /// Upper case (`OPUS`, `PCMU`, `TELEPHONE-EVENT`); empty for a dynamic type with no rtpmap.
    pub encoding: String,
    pub clock_rate: u32,
}

/// A peer's audio stream as its description gives it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RemoteAudio {
    pub addr: SocketAddr,
    /// Where its RTCP goes: its `a=rtcp`, else the RTP port + 1.
    pub rtcp: SocketAddr,
    /// It said `a=rtcp-mux`: RTCP on the RTP port, where both sides say so.
    pub rtcp_mux: bool,
    pub formats: Vec<Format>,
    pub direction: Direction,
    /// RTP/SAVP: SRTP, keyed by the first crypto attribute of our suite (if any).
    pub secure: bool,
    pub crypto: Option<Sdes>,
    /// The packet length it asks to receive (`a=ptime`) and the longest it takes
    /// (`a=maxptime`), ms (RFC 4566 6).
    pub ptime: Option<u32>,
    pub maxptime: Option<u32>,
}

/// What we describe of our side.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LocalAudio {
    /// Where our RTP socket is reachable.
    pub addr: SocketAddr,
    /// Where our RTCP socket is reachable (`None`: none of its own, the RTP port + 1).
    pub rtcp: Option<SocketAddr>,
    /// The codecs we offer or accept, preferred first.
    pub codecs: Vec<Codec>,
    pub session_id: u64,
    /// Our SRTP key: offered with RTP/SAVP when `offer_srtp`, and given in an answer to an
    /// offer of SRTP.
    pub key: SdesKey,
    pub offer_srtp: bool,
    /// The Opus frame length we ask for and send where the peer takes it, ms (10 or 20).
    pub frame_ms: u8,
}

/// The outcome of an offer and its answer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Negotiated {
    /// Where our RTP goes (until symmetric RTP latches onto where the peer's comes from).
    pub remote: SocketAddr,
    /// Where our RTCP goes (until the peer's believed RTCP comes from elsewhere): the peer's
    /// RTCP address, or `remote` where RTCP is multiplexed.
    pub rtcp: SocketAddr,
    /// Both sides agreed `a=rtcp-mux`: RTCP shares the RTP socket.
    pub rtcp_mux: bool,
    pub codec: Codec,
    pub payload_type: u8,
    /// RFC 4733 events: payload type, with the codec's clock.
    pub events: Option<u8>,
    /// The peer's direction, as it said it.
    pub direction: Direction,
    /// Every payload type of the peer that carries a codec we decode.
    pub payloads: PayloadMap,
    pub audio_types: Vec<u8>,
    /// SRTP, with the peer's key (ours is in [`LocalAudio`]).
    pub srtp: Option<Sdes>,
    /// Where the call's SIP messages come from (the peer, or the proxy it is reached
    /// through): plain RTP from this IP may open the call's media ([`super::media`]).
    pub signalling_peer: Option<IpAddr>,
    /// The length of the frames we send, ms: 20, or 10 for Opus where we asked and the peer
    /// takes them ([`super::ptime::send_frame_ms`]).
    pub frame_ms: u8,
}

/// The payload types that carry SDP's static formats we know (RFC 3551).
fn static_format(pt: u8) -> Option<(&'static str, u32)> {
    match pt {
        0 => Some(("PCMU", 8000)),
        8 => Some(("PCMA", 8000)),
        9 => Some(("G722", 8000)),
        _ => None,
    }
}

fn codec_of(format: &Format) -> Option<Codec> {
    match (format.encoding.as_str(), format.clock_rate) {
        ("OPUS", 48000) => Some(Codec::Opus),
        ("PCMU", 8000) => Some(Codec::Pcmu),
        ("PCMA", 8000) => Some(Codec::Pcma),
        // RFC 3551 4.5.2: G.722's RTP clock is 8000 though it samples at 16 kHz.
        ("G722", 8000) => Some(Codec::G722),
        _ => None,
    }
}

fn malformed(line: &str, why: &'static str) -> SdpError {
    SdpError::Malformed {
        line: line.chars().take(80).collect(),
        why,
    }
}

/// An address of `c=`, `o=` or `a=rtcp`: an IP, never a host name (nothing we could send to).
fn ip_of(address: &TaggedAddress) -> Result<IpAddr, SdpError> {
    match address {
        TaggedAddress::IP4(ip) => Ok(IpAddr::V4(*ip)),
        TaggedAddress::IP6(ip) => Ok(IpAddr::V6(*ip)),
        TaggedAddress::IP4FQDN(host) | TaggedAddress::IP6FQDN(host) => {
            Err(malformed(host.as_str(), "the address is not an IP address"))
        }
    }
}

/// A key lifetime of `2^N` with N of 32 or more: ezk's parser computes it in a `u32`, which
/// overflows (a panic where overflow is checked).
fn overflowing_lifetime(text: &str) -> bool {
    text.match_indices("|2^").any(|(at, m)| {
        let digits: String = text[at + m.len()..]
            .chars()
            .take_while(char::is_ascii_digit)
            .collect();
        digits.len() > 2 || digits.parse::<u32>().is_ok_and(|n| n >= 32)
    })
}

/// Parses a description that came as text (a SIP body), capped at [`MAX_SDP_BYTES`].
pub fn parse(text: &str) -> Result<SessionDescription, SdpError> {
    if text.len() > MAX_SDP_BYTES {
        return Err(SdpError::TooLong(text.len()));
    }
    if overflowing_lifetime(text) {
        return Err(malformed(text, "an SRTP key lifetime over 2^31"));
    }
    SessionDescription::parse(&BytesStr::from(text))
        .map_err(|e| malformed(&e.to_string(), "not a session description ezk can read"))
}

/// A format of the audio line: static ones by RFC 3551, dynamic ones by their rtpmap.
fn format(pt: u8, audio: &MediaDescription) -> Result<Format, SdpError> {
    if pt >= 128 {
        return Err(malformed(&pt.to_string(), "bad payload type"));
    }
    if let Some(map) = audio.rtpmap.iter().find(|m| m.payload == pt) {
        let encoding = map.encoding.as_str().to_ascii_uppercase();
        if encoding.is_empty() || encoding.len() > 32 || map.clock_rate == 0 {
            return Err(malformed(&map.to_string(), "bad encoding or clock rate"));
        }
        return Ok(Format {
            payload_type: pt,
            encoding,
            clock_rate: map.clock_rate,
        });
    }
    let (encoding, clock_rate) = static_format(pt).unwrap_or(("", 0));
    Ok(Format {
        payload_type: pt,
        encoding: encoding.to_owned(),
        clock_rate,
    })
}

/// Reads the first audio stream of a description.
pub fn read(description: &SessionDescription) -> Result<RemoteAudio, SdpError> {
    let audio = description
        .media_descriptions
        .iter()
        .find(|m| m.media.media_type == MediaType::Audio)
        .ok_or(SdpError::NoAudio)?;
    let secure = match &audio.media.proto {
        TransportProtocol::RtpAvp | TransportProtocol::RtpAvpf => false,
        TransportProtocol::RtpSavp | TransportProtocol::RtpSavpf => true,
        other => return Err(malformed(&other.to_string(), "not RTP/AVP audio")),
    };
    if audio.media.port == 0 {
        return Err(SdpError::Refused);
    }
    let formats = audio
        .media
        .fmts
        .iter()
        .take(MAX_FORMATS)
        .map(|&pt| format(pt, audio))
        .collect::<Result<Vec<_>, _>>()?;
    let connection = audio
        .connection
        .as_ref()
        .or(description.connection.as_ref())
        .ok_or(SdpError::NoAddress)?;
    let ip = ip_of(&connection.address)?;
    let port = audio.media.port;
    let rtcp = match &audio.rtcp {
        Some(Rtcp { port: 0, .. }) => return Err(malformed("a=rtcp:0", "bad RTCP port")),
        Some(Rtcp { port, address }) => {
            let rtcp_ip = address.as_ref().map(ip_of).transpose()?;
            SocketAddr::new(rtcp_ip.unwrap_or(ip), *port)
        }
        // RTP ports are even: an odd last one has no port above it, and only mux can help.
        None => SocketAddr::new(ip, port.checked_add(1).unwrap_or(port)),
    };
    Ok(RemoteAudio {
        addr: SocketAddr::new(ip, port),
        rtcp,
        rtcp_mux: audio.rtcp_mux,
        formats,
        direction: Direction::of(audio.direction),
        secure,
        crypto: audio.crypto.iter().find_map(read_crypto),
        ptime: ms_attribute(description, audio, "ptime"),
        maxptime: ms_attribute(description, audio, "maxptime"),
    })
}
/// The telephone-event format of `remote` on `clock`, if it has one.
fn events_at(remote: &RemoteAudio, clock: u32) -> Option<u8> {
    remote
        .formats
        .iter()
        .find(|f| f.encoding == "TELEPHONE-EVENT" && f.clock_rate == clock)
        .map(|f| f.payload_type)
}

/// Chooses the codec: the first of the peer's formats (its preference) that we allow. `answer`
/// says the peer's description answers ours (its formats are then among ours).
pub fn negotiate(remote: &RemoteAudio, allowed: &[Codec]) -> Result<Negotiated, SdpError> {
    if remote.secure && remote.crypto.is_none() {
        return Err(SdpError::Encrypted);
    }
    let mut payloads = PayloadMap::default();
    let mut audio_types = Vec::new();
    let mut chosen = None;
    for format in &remote.formats {
        let Some(codec) = codec_of(format).filter(|c| allowed.contains(c)) else {
            continue;
        };
        if audio_types
            .iter()
            .any(|&pt| payloads.codec(pt) == Some(codec))
        {
            continue;
        }
        if payloads.set(codec, format.payload_type).is_err() {
            continue;
        }
        audio_types.push(format.payload_type);
        chosen.get_or_insert((codec, format.payload_type));
    }
    let Some((codec, payload_type)) = chosen else {
        let offered: Vec<String> = remote
            .formats
            .iter()
            .map(|f| match f.encoding.as_str() {
                "" => f.payload_type.to_string(),
                e => format!("{e}/{}", f.clock_rate),
            })
            .collect();
        return Err(SdpError::NoCommonCodec(offered.join(" ")));
    };
    Ok(Negotiated {
        remote: remote.addr,
        rtcp: if remote.rtcp_mux {
            remote.addr
        } else {
            remote.rtcp
        },
        rtcp_mux: remote.rtcp_mux,
        codec,
        payload_type,
        events: events_at(remote, codec.clock_rate()),
        direction: remote.direction,
        payloads,
        audio_types,
        srtp: remote.secure.then(|| remote.crypto.clone()).flatten(),
        signalling_peer: None,
        frame_ms: send_frame_ms(codec, remote.ptime, remote.maxptime, 20),
    })
}

/// The peer's description (an offer or an answer) read, its media address checked against our
/// socket's family (`local.addr`) and the codec chosen among `local.codecs`.
pub fn take_description(
    description: &SessionDescription,
    local: &LocalAudio,
) -> Result<Negotiated, SdpError> {
    let remote = read(description)?;
    media_target(remote.addr, local.addr)?;
    media_target(remote.rtcp, local.addr)?;
    agree(&remote, local)
}

/// [`negotiate`] with our codecs, then the packet length we send in the codec chosen: our own
/// where the peer's `ptime`/`maxptime` take it.
fn agree(remote: &RemoteAudio, local: &LocalAudio) -> Result<Negotiated, SdpError> {
    let mut negotiated = negotiate(remote, &local.codecs)?;
    negotiated.frame_ms = send_frame_ms(
        negotiated.codec,
        remote.ptime,
        remote.maxptime,
        local.frame_ms,
    );
    Ok(negotiated)
}

/// [`take_description`] of a description that came as text.
pub fn take(text: &str, local: &LocalAudio) -> Result<Negotiated, SdpError> {
    take_description(&parse(text)?, local)
}

/// As [`take_description`], for an offer within a call, where `c=0.0.0.0` is RFC 2543's hold, which RFC
/// 3264 (8.4) still asks us to take: the peer receives nothing, and our media keeps the
/// address it had (`remote` stays unspecified; [`super::media`] sends nothing there).
pub fn take_in_call(
    description: &SessionDescription,
    local: &LocalAudio,
) -> Result<Negotiated, SdpError> {
    let remote = read(description)?;
    let held = remote.addr.ip().is_unspecified() && remote.addr.is_ipv4() == local.addr.is_ipv4();
    if !held {
        media_target(remote.addr, local.addr)?;
        media_target(remote.rtcp, local.addr)?;
    }
    let mut negotiated = agree(&remote, local)?;
    if held {
        negotiated.direction = negotiated.direction.deaf();
    }
    Ok(negotiated)
}

/// Our description with its one audio stream `audio`.
fn ours(local: &LocalAudio, version: u64, audio: MediaDescription) -> SessionDescription {
    let ip = local.addr.ip();
    SessionDescription {
        origin: Origin {
            username: "lipcall".into(),
            session_id: local.session_id.to_string().into(),
            session_version: version.to_string().into(),
            address: ip.into(),
        },
        name: "lipcall".into(),
        connection: Some(Connection {
            address: ip.into(),
            ttl: None,
            num: None,
        }),
        bandwidth: Vec::new(),
        time: Time { start: 0, stop: 0 },
        direction: ezk_sdp_types::Direction::SendRecv,
        group: Vec::new(),
        extmap: Vec::new(),
        extmap_allow_mixed: false,
        ice_lite: false,
        ice_options: Default::default(),
        ice_ufrag: None,
        ice_pwd: None,
        setup: None,
        fingerprint: Vec::new(),
        attributes: Vec::new(),
        media_descriptions: vec![audio],
    }
}

/// Our audio line on `types`, SRTP (RTP/SAVP) where `secure`, packets of `ptime` ms,
/// `direction`.
fn audio_line(
    local: &LocalAudio,
    types: Vec<u8>,
    secure: bool,
    direction: Direction,
    ptime: u8,
) -> MediaDescription {
    let mut audio = MediaDescription::rejected(MediaType::Audio);
    audio.media.port = local.addr.port();
    audio.media.proto = if secure {
        TransportProtocol::RtpSavp
    } else {
        TransportProtocol::RtpAvp
    };
    audio.media.fmts = types;
    audio.direction = direction.attribute();
    audio.attributes.push(UnknownAttribute {
        name: "ptime".into(),
        value: Some(ptime.to_string().into()),
    });
    audio
}

/// The rtpmap (and Opus's fmtp) of `codec` on `pt`.
fn map_codec(audio: &mut MediaDescription, codec: Codec, pt: u8) {
    let (encoding, params) = match codec {
        Codec::Opus => ("opus", Some("2".into())),
        other => (other.encoding_name(), None),
    };
    audio.rtpmap.push(RtpMap {
        payload: pt,
        encoding: encoding.into(),
        clock_rate: codec.clock_rate(),
        params,
    });
    if codec == Codec::Opus {
        audio.fmtp.push(Fmtp {
            format: pt,
            params: "useinbandfec=1".into(),
        });
    }
}

/// telephone-event (RFC 4733) on `pt` at `clock`, keys 0-16.
fn map_events(audio: &mut MediaDescription, pt: u8, clock: u32) {
    audio.rtpmap.push(RtpMap {
        payload: pt,
        encoding: "telephone-event".into(),
        clock_rate: clock,
        params: None,
    });
    audio.fmtp.push(Fmtp {
        format: pt,
        params: "0-16".into(),
    });
}

/// Where our RTCP socket is, as `a=rtcp` says it (the address only where it is not the RTP's).
fn rtcp_attribute(local: &LocalAudio) -> Option<Rtcp> {
    let rtcp = local.rtcp?;
    Some(Rtcp {
        port: rtcp.port(),
        address: (rtcp.ip() != local.addr.ip()).then(|| rtcp.ip().into()),
    })
}

/// Our SDES key under `tag`.
fn crypto(local: &LocalAudio, tag: u32) -> SrtpCrypto {
    SrtpCrypto {
        tag,
        suite: SrtpSuite::AES_CM_128_HMAC_SHA1_80,
        keys: vec![local.key.keying()],
        params: Vec::new(),
    }
}

fn offered_type(codec: Codec) -> u8 {
    match codec {
        Codec::Opus => OPUS_PT,
        other => other.default_payload_type(),
    }
}

/// Our offer: every allowed codec SIP peers speak, then telephone-event at 8 kHz (and at
/// 48 kHz beside Opus).
pub fn offer(local: &LocalAudio, version: u64) -> SessionDescription {
    let codecs: Vec<Codec> = local
        .codecs
        .iter()
        .copied()
        .filter(|c| !matches!(c, Codec::Speex | Codec::SpeexWb))
        .collect();
    let mut types: Vec<u8> = codecs.iter().map(|&c| offered_type(c)).collect();
    types.push(EVENT_PT);
    let wide = codecs.contains(&Codec::Opus);
    if wide {
        types.push(EVENT_WIDE_PT);
    }
    // 10 ms asked for only where Opus is offered: the other codecs go in 20 ms frames.
    let ptime = if wide { local.frame_ms } else { 20 };
    let mut audio = audio_line(local, types, local.offer_srtp, Direction::SendRecv, ptime);
    if local.offer_srtp {
        audio.crypto.push(crypto(local, 1));
    }
    for &codec in &codecs {
        map_codec(&mut audio, codec, offered_type(codec));
    }
    map_events(&mut audio, EVENT_PT, 8000);
    if wide {
        map_events(&mut audio, EVENT_WIDE_PT, 48000);
    }
    audio.rtcp = rtcp_attribute(local);
    audio.rtcp_mux = true;
    ours(local, version, audio)
}

/// Our answer to an offer that negotiated as `chosen`: its codec and events on the peer's
/// payload types, the direction mirrored.
pub fn answer(local: &LocalAudio, chosen: &Negotiated, version: u64) -> SessionDescription {
    let mut types = vec![chosen.payload_type];
    types.extend(chosen.events);
    let mut audio = audio_line(
        local,
        types,
        chosen.srtp.is_some(),
        chosen.direction.reversed(),
        if chosen.codec == Codec::Opus {
            local.frame_ms
        } else {
            20
        },
    );
    if let Some(theirs) = &chosen.srtp {
        audio.crypto.push(crypto(local, theirs.tag));
    }
    map_codec(&mut audio, chosen.codec, chosen.payload_type);
    if let Some(pt) = chosen.events {
        map_events(&mut audio, pt, chosen.codec.clock_rate());
    }
    if chosen.rtcp_mux {
        audio.rtcp_mux = true;
    } else {
        audio.rtcp = rtcp_attribute(local);
    }
    ours(local, version, audio)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const BARESIP_OFFER: &str = "v=0\r\no=- 123 456 IN IP4 127.0.0.1\r\ns=-\r\nc=IN IP4 127.0.0.1\r\n\
        t=0 0\r\nm=audio 10000 RTP/AVP 96 0 8 101\r\na=rtpmap:96 opus/48000/2\r\n\
        a=fmtp:96 stereo=1\r\na=rtpmap:101 telephone-event/8000\r\na=sendrecv\r\n";

    /// A description of `lines` after the lines RFC 8866 requires.
    fn described(lines: &str) -> String {
        format!("v=0\r\no=- 1 1 IN IP4 192.0.2.1\r\ns=-\r\nt=0 0\r\n{lines}")
    }

    fn remote(text: &str) -> Result<RemoteAudio, SdpError> {
        read(&parse(text)?)
    }

    fn local() -> LocalAudio {
        LocalAudio {
            addr: "127.0.0.1:4000".parse().unwrap(),
            rtcp: Some("127.0.0.1:4001".parse().unwrap()),
            codecs: vec![Codec::Opus, Codec::Pcmu, Codec::Pcma],
            session_id: 7,
            key: SdesKey([7; SDES_KEY_LEN]),
            offer_srtp: false,
            frame_ms: 20,
        }
    }

    #[test]
    fn sdes_keys_go_both_ways_and_never_print() {
        let mut ours = local();
        ours.offer_srtp = true;
        let offer = offer(&ours, 1).to_string();
        assert!(offer.contains("m=audio 4000 RTP/SAVP "), "{offer}");
        assert!(
            offer.contains("a=crypto:1 AES_CM_128_HMAC_SHA1_80 inline:"),
            "{offer}"
        );
        let chosen = negotiate(&remote(&offer).unwrap(), &[Codec::Pcmu]).unwrap();
        let theirs = chosen.srtp.clone().expect("SRTP agreed");
        assert_eq!((theirs.tag, &theirs.key), (1, &ours.key));
        assert!(!format!("{chosen:?}").contains("7, 7"));
        // An answer to it gives our key under the offer's tag.
        let answer = answer(&local(), &chosen, 2).to_string();
        assert!(
            answer.contains("RTP/SAVP") && answer.contains("a=crypto:1 "),
            "{answer}"
        );
        // SRTP with another suite only, or no key, is refused; a broken key is no key.
        let other = described(
            "c=IN IP4 1.2.3.4\r\nm=audio 5 RTP/SAVP 0\r\n\
             a=crypto:1 AES_256_CM_HMAC_SHA1_80 inline:AAAA\r\n",
        );
        assert_eq!(
            negotiate(&remote(&other).unwrap(), &[Codec::Pcmu]),
            Err(SdpError::Encrypted)
        );
        let short = described(
            "c=IN IP4 1.2.3.4\r\nm=audio 5 RTP/SAVP 0\r\n\
             a=crypto:1 AES_CM_128_HMAC_SHA1_80 inline:AAAA\r\n",
        );
        assert_eq!(
            negotiate(&remote(&short).unwrap(), &[Codec::Pcmu]),
            Err(SdpError::Encrypted)
        );
        // A lifetime ezk's parser would overflow on is refused before it reads it.
        let huge = described(
            "c=IN IP4 1.2.3.4\r\nm=audio 5 RTP/SAVP 0\r\n\
             a=crypto:1 AES_CM_128_HMAC_SHA1_80 inline:AAAA|2^40\r\n",
        );
        assert!(matches!(remote(&huge), Err(SdpError::Malformed { .. })));
    }

    #[test]
    fn ptime_asks_for_10_ms_opus_and_a_peer_s_ptime_and_maxptime_are_honoured() {
        let ten = LocalAudio {
            frame_ms: 10,
            ..local()
        };
        let text = offer(&ten, 1).to_string();
        assert!(text.contains("a=ptime:10\r\n"), "{text}");
        let pcmu_only = LocalAudio {
            codecs: vec![Codec::Pcmu],
            ..ten.clone()
        };
        let text = offer(&pcmu_only, 1).to_string();
        assert!(text.contains("a=ptime:20\r\n"), "{text}");
        // What we send, by what the peer's Opus offer says.
        let opus = |attributes: &str| {
            described(&format!(
                "c=IN IP4 127.0.0.1\r\nm=audio 5000 RTP/AVP 96 0\r\n\
                 a=rtpmap:96 opus/48000/2\r\n{attributes}"
            ))
        };
        let sent = |attributes: &str, ours: &LocalAudio| take(&opus(attributes), ours).unwrap();
        for (attributes, wanted, expected) in [
            ("", 10, 10),
            ("a=ptime:10\r\n", 10, 10),
            ("a=ptime:20\r\n", 10, 20),
            ("a=ptime:20\r\na=maxptime:120\r\n", 10, 20),
            ("a=maxptime:10\r\n", 20, 10),
            ("a=maxptime:5\r\n", 10, 20),
            ("a=ptime:nonsense\r\n", 10, 10),
            ("a=ptime:10\r\n", 20, 20),
            ("", 20, 20),
        ] {
            let ours = LocalAudio {
                frame_ms: wanted,
                ..local()
            };
            let n = sent(attributes, &ours);
            assert_eq!(n.codec, Codec::Opus);
            assert_eq!(n.frame_ms, expected, "{attributes:?}, we want {wanted}");
        }
        let theirs = remote(&opus("a=ptime:20\r\na=maxptime:40\r\n")).unwrap();
        assert_eq!((theirs.ptime, theirs.maxptime), (Some(20), Some(40)));
        // A session-level ptime counts too.
        let session = described(
            "a=ptime:20\r\nc=IN IP4 127.0.0.1\r\nm=audio 5000 RTP/AVP 96\r\n\
             a=rtpmap:96 opus/48000/2\r\n",
        );
        assert_eq!(take(&session, &ten).unwrap().frame_ms, 20);
        // Other codecs go in 20 ms frames, and our answer asks for what we take.
        let n = take(&opus(""), &pcmu_only).unwrap();
        assert_eq!((n.codec, n.frame_ms), (Codec::Pcmu, 20));
        assert!(answer(&ten, &n, 2).to_string().contains("a=ptime:20\r\n"));
        let n = take(&opus(""), &ten).unwrap();
        assert!(answer(&ten, &n, 2).to_string().contains("a=ptime:10\r\n"));
    }

    #[test]
    fn a_softphone_offer_negotiates_its_first_codec_and_events() {
        let theirs = remote(BARESIP_OFFER).unwrap();
        assert_eq!(theirs.addr, "127.0.0.1:10000".parse().unwrap());
        let n = negotiate(&theirs, &[Codec::Pcmu, Codec::Opus]).unwrap();
        assert_eq!((n.codec, n.payload_type), (Codec::Opus, 96));
        assert_eq!(n.payloads.codec(96), Some(Codec::Opus));
        assert_eq!(
            n.events, None,
            "events at 8 kHz do not go with Opus's clock"
        );
        let n = negotiate(&theirs, &[Codec::Pcmu]).unwrap();
        assert_eq!(
            (n.codec, n.payload_type, n.events),
            (Codec::Pcmu, 0, Some(101))
        );
        let answer = answer(&local(), &n, 1);
        let text = answer.to_string();
        assert!(text.contains("m=audio 4000 RTP/AVP 0 101\r\n"), "{text}");
        let back = read(&answer).unwrap();
        assert_eq!(back.formats[0].encoding, "PCMU");
    }

    #[test]
    fn our_offer_reads_back_as_struct_and_as_text() {
        let offer = offer(&local(), 1);
        for theirs in [read(&offer).unwrap(), remote(&offer.to_string()).unwrap()] {
            assert_eq!(theirs.addr, local().addr);
            let n = negotiate(&theirs, &[Codec::Opus]).unwrap();
            assert_eq!(
                (n.codec, n.payload_type, n.events),
                (Codec::Opus, 111, Some(102))
            );
        }
        let text = offer.to_string();
        for line in [
            "o=lipcall 7 1 IN IP4 127.0.0.1\r\n",
            "c=IN IP4 127.0.0.1\r\n",
            "a=rtpmap:111 opus/48000/2\r\n",
            "a=fmtp:111 useinbandfec=1\r\n",
            "a=rtpmap:101 telephone-event/8000\r\n",
            "a=ptime:20\r\n",
            "a=sendrecv\r\n",
        ] {
            assert!(text.contains(line), "{line:?} in {text}");
        }
    }

    #[test]
    fn rtcp_goes_to_the_port_above_or_where_a_rtcp_says_or_on_the_rtp_port_with_mux() {
        // baresip's default: neither attribute, RTCP on the RTP port + 1.
        let n = take(BARESIP_OFFER, &local()).unwrap();
        assert_eq!(
            (n.rtcp, n.rtcp_mux),
            ("127.0.0.1:10001".parse().unwrap(), false)
        );
        let ours_back = answer(&local(), &n, 1).to_string();
        assert!(ours_back.contains("a=rtcp:4001\r\n"), "{ours_back}");
        assert!(!ours_back.contains("rtcp-mux"), "{ours_back}");
        // Our offer names our RTCP socket and offers mux; an answer taking mux says it back.
        let mut ours = local();
        ours.rtcp = Some("192.0.2.7:5001".parse().unwrap());
        let offer = offer(&ours, 1);
        let text = offer.to_string();
        assert!(
            text.contains("a=rtcp:5001 IN IP4 192.0.2.7\r\na=rtcp-mux\r\n"),
            "{text}"
        );
        let theirs = read(&offer).unwrap();
        assert_eq!(theirs.rtcp, "192.0.2.7:5001".parse().unwrap());
        let muxed = negotiate(&theirs, &[Codec::Pcmu]).unwrap();
        assert_eq!((muxed.rtcp, muxed.rtcp_mux), (theirs.addr, true));
        assert!(
            answer(&local(), &muxed, 1)
                .to_string()
                .contains("a=rtcp-mux\r\n")
        );
        // A port alone keeps the media's address; a bad one, or an odd address, is refused.
        let with = |attr: &str| format!("{}{attr}\r\n", BARESIP_OFFER);
        let n = take(&with("a=rtcp:7000"), &local()).unwrap();
        assert_eq!(n.rtcp, "127.0.0.1:7000".parse().unwrap());
        for bad in ["a=rtcp:0", "a=rtcp:x", "a=rtcp:7000 IN IP4 nowhere"] {
            assert!(
                matches!(take(&with(bad), &local()), Err(SdpError::Malformed { .. })),
                "{bad}"
            );
        }
        assert!(matches!(
            take(&with("a=rtcp:7000 IN IP4 224.0.0.1"), &local()),
            Err(SdpError::OddAddress(_))
        ));
    }

    #[test]
    fn hostile_descriptions_are_errors() {
        assert_eq!(remote(&described("")), Err(SdpError::NoAudio));
        assert!(matches!(remote("garbage"), Err(SdpError::Malformed { .. })));
        assert!(matches!(
            remote("v=0\r\nc=IN IP4 1.2.3.4\r\nm=audio 5 RTP/AVP 0\r\n"),
            Err(SdpError::Malformed { .. })
        ));
        assert_eq!(
            remote(&described("c=IN IP4 1.2.3.4\r\nm=audio 0 RTP/AVP 0\r\n")),
            Err(SdpError::Refused)
        );
        assert_eq!(
            remote(&described("m=audio 5 RTP/AVP 0\r\n")),
            Err(SdpError::NoAddress)
        );
        assert!(
            remote(&described(
                "c=IN IP4 host.example\r\nm=audio 5 RTP/AVP 0\r\n"
            ))
            .is_err()
        );
        assert!(remote(&described("c=IN IP4 1.2.3.4\r\nm=audio 5 RTP/AVP 200\r\n")).is_err());
        assert!(remote(&described("c=IN IP4 1.2.3.4\r\nm=audio 5 TCP/MSRP *\r\n")).is_err());
        let no_key = remote(&described("c=IN IP4 1.2.3.4\r\nm=audio 5 RTP/SAVP 0\r\n")).unwrap();
        assert_eq!(negotiate(&no_key, &[Codec::Pcmu]), Err(SdpError::Encrypted));
        let g729 = remote(&described("c=IN IP4 1.2.3.4\r\nm=audio 5 RTP/AVP 18\r\n")).unwrap();
        assert!(matches!(
            negotiate(&g729, &[Codec::Pcmu]),
            Err(SdpError::NoCommonCodec(_))
        ));
        assert!(matches!(
            remote(&"a=x\r\n".repeat(MAX_SDP_BYTES)),
            Err(SdpError::TooLong(_))
        ));
        // The error quotes the line cut at a character, not a byte (a panic before).
        let wide = described(&format!(
            "c=IN IP4 1.2.3.4\r\nm=audio 5 RTP/AVP x{}\r\n",
            "é".repeat(99)
        ));
        let _ = remote(&wide);
        assert!(matches!(
            remote(&described(&format!("a=rtcp:x{}\r\n", "é".repeat(99)))),
            Err(SdpError::Malformed { .. })
        ));
    }

    #[test]
    fn odd_media_addresses_are_refused_by_name() {
        let with = |c: &str| described(&format!("c={c}\r\nm=audio 5000 RTP/AVP 0\r\n"));
        assert!(take(&with("IN IP4 127.0.0.1"), &local()).is_ok());
        for (c, named) in [
            ("IN IP4 0.0.0.0", "0.0.0.0:5000"),
            ("IN IP4 255.255.255.255", "255.255.255.255:5000"),
            ("IN IP4 224.0.0.1/127", "224.0.0.1:5000"),
            ("IN IP6 ::1", "[::1]:5000"),
        ] {
            let e = take(&with(c), &local()).unwrap_err();
            assert!(matches!(e, SdpError::OddAddress(_)), "{c}: {e:?}");
            assert!(e.to_string().contains(named), "{e}");
        }
        // Within a call, 0.0.0.0 is an old-style hold: taken, and answered recvonly.
        let held = take_in_call(&parse(&with("IN IP4 0.0.0.0")).unwrap(), &local()).unwrap();
        assert_eq!(held.direction, Direction::SendOnly);
        assert!(
            answer(&local(), &held, 2)
                .to_string()
                .contains("a=recvonly")
        );
        let multicast = parse(&with("IN IP4 224.0.0.1")).unwrap();
        assert!(take_in_call(&multicast, &local()).is_err());
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        #[test]
        fn any_text_parses_or_is_an_error(text in "(([vocmtas]=[ -~]{0,40})?\r\n){0,12}") {
            if let Ok(theirs) = remote(&text) {
                let _ = negotiate(&theirs, &Codec::ALL);
            }
            if let Ok(theirs) = remote(&described(&text)) {
                let _ = negotiate(&theirs, &Codec::ALL);
            }
        }

        #[test]
        fn mutated_offers_never_panic(cut in 0usize..400, byte in any::<u8>(), at in 0usize..400) {
            let mut bytes = BARESIP_OFFER.as_bytes().to_vec();
            bytes.truncate(cut.max(1));
            if at < bytes.len() {
                bytes[at] = byte;
            }
            let text = String::from_utf8_lossy(&bytes);
            if let Ok(chosen) = remote(&text).and_then(|r| negotiate(&r, &Codec::ALL)) {
                // Whatever was agreed, our answer says it back, as struct and as text.
                let answer = answer(&local(), &chosen, 2);
                for back in [read(&answer).unwrap(), remote(&answer.to_string()).unwrap()] {
                    let again = negotiate(&back, &Codec::ALL).unwrap();
                    prop_assert_eq!(
                        (again.codec, again.payload_type, again.events),
                        (chosen.codec, chosen.payload_type, chosen.events)
                    );
                }
            }
        }
    }
}
