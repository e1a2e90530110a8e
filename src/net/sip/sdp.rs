//! SDP offer and answer for one audio stream (RFC 3264, RFC 4566): what lipcall offers (Opus,
//! PCMU, PCMA and RFC 4733 telephone-event), reading a peer's description (its media address,
//! formats and direction), and choosing the codec both sides speak. RTCP goes where RFC 3550
//! puts it, the RTP port + 1, unless `a=rtcp` (RFC 3605) names another port, or both sides say
//! `a=rtcp-mux` (RFC 5761: on the RTP port); we offer both, and take mux where it is offered.
//!
//! The SIP stack (ezk) parses SDP into its own types; this module reads the description it
//! prints back, so that every value a hostile peer controls passes one strict, bounded reader
//! with its own errors.

use std::net::{IpAddr, SocketAddr};

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

    fn inline(&self) -> String {
        use base64::Engine;
        base64::engine::general_purpose::STANDARD.encode(self.0)
    }

    /// `inline:KEY[|LIFETIME][|MKI:LEN]` (RFC 4568 9.1) of our suite; `None` for any other.
    fn parse(params: &str) -> Option<Self> {
        use base64::Engine;
        let inline = params
            .split_ascii_whitespace()
            .next()?
            .strip_prefix("inline:")?;
        let key = inline.split('|').next()?;
        let bytes = base64::engine::general_purpose::STANDARD.decode(key).ok()?;
        Some(Self(bytes.try_into().ok()?))
    }
}

/// The peer's SDES crypto attribute we took.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Sdes {
    pub tag: u32,
    pub key: SdesKey,
}

fn parse_crypto(value: &str) -> Option<Sdes> {
    let mut parts = value.splitn(3, ' ');
    let tag = parts.next()?.parse().ok()?;
    if parts.next()? != SRTP_SUITE {
        return None;
    }
    Some(Sdes {
        tag,
        key: SdesKey::parse(parts.next()?)?,
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
    fn attribute(self) -> &'static str {
        match self {
            Direction::SendRecv => "sendrecv",
            Direction::SendOnly => "sendonly",
            Direction::RecvOnly => "recvonly",
            Direction::Inactive => "inactive",
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
    let mut line = line.to_owned();
    line.truncate(80);
    SdpError::Malformed { line, why }
}

fn parse_address(line: &str, value: &str) -> Result<Option<IpAddr>, SdpError> {
    let mut parts = value.split_ascii_whitespace();
    let (Some("IN"), Some(family), Some(addr)) = (parts.next(), parts.next(), parts.next()) else {
        return Err(malformed(line, "expected IN IP4|IP6 ADDRESS"));
    };
    // A multicast address may carry /ttl; a host name is not something we can send to.
    let addr = addr.split('/').next().unwrap_or(addr);
    let ip: IpAddr = addr
        .parse()
        .map_err(|_| malformed(line, "the address is not an IP address"))?;
    match (family, ip) {
        ("IP4", IpAddr::V4(_)) | ("IP6", IpAddr::V6(_)) => Ok(Some(ip)),
        _ => Err(malformed(line, "the address does not match its family")),
    }
}

/// `a=rtcp:PORT [IN IP4|IP6 ADDRESS]` (RFC 3605).
fn parse_rtcp(line: &str, value: &str) -> Result<(u16, Option<IpAddr>), SdpError> {
    let (port, address) = match value.split_once(' ') {
        Some((port, address)) => (port, Some(address)),
        None => (value, None),
    };
    let port = port
        .trim()
        .parse()
        .ok()
        .filter(|&p: &u16| p > 0)
        .ok_or_else(|| malformed(line, "bad RTCP port"))?;
    let ip = match address {
        Some(address) => parse_address(line, address.trim())?,
        None => None,
    };
    Ok((port, ip))
}

fn parse_rtpmap(line: &str, value: &str) -> Result<(u8, String, u32), SdpError> {
    let (pt, rest) = value
        .split_once(' ')
        .ok_or_else(|| malformed(line, "expected PT ENCODING/CLOCK"))?;
    let pt: u8 = pt
        .trim()
        .parse()
        .ok()
        .filter(|&pt| pt < 128)
        .ok_or_else(|| malformed(line, "bad payload type"))?;
    let mut fields = rest.trim().split('/');
    let encoding = fields.next().unwrap_or_default().to_ascii_uppercase();
    let clock: u32 = fields
        .next()
        .and_then(|c| c.parse().ok())
        .filter(|&c| c > 0)
        .ok_or_else(|| malformed(line, "bad clock rate"))?;
    if encoding.is_empty() || encoding.len() > 32 {
        return Err(malformed(line, "bad encoding name"));
    }
    Ok((pt, encoding, clock))
}

/// The first audio stream as read so far: its port, formats, own address and direction.
struct AudioLine {
    port: u16,
    formats: Vec<Format>,
    addr: Option<IpAddr>,
    direction: Option<Direction>,
    secure: bool,
    crypto: Option<Sdes>,
    rtcp: Option<(u16, Option<IpAddr>)>,
    rtcp_mux: bool,
}

/// Reads the first audio stream of a description.
pub fn parse(text: &str) -> Result<RemoteAudio, SdpError> {
    if text.len() > MAX_SDP_BYTES {
        return Err(SdpError::TooLong(text.len()));
    }
    let mut session_addr = None;
    let mut session_direction = Direction::SendRecv;
    let mut audio: Option<AudioLine> = None;
    let mut in_audio = false;
    let mut past_audio = false;
    for line in text.split(['\r', '\n']).filter(|l| !l.is_empty()) {
        let Some((kind, value)) = line.split_once('=') else {
            return Err(malformed(line, "expected TYPE=VALUE"));
        };
        match kind {
            "m" => {
                let seen = audio.is_some();
                in_audio = false;
                if seen {
                    past_audio = true;
                    continue;
                }
                let mut parts = value.split_ascii_whitespace();
                let (Some(media), Some(port), Some(proto)) =
                    (parts.next(), parts.next(), parts.next())
                else {
                    return Err(malformed(line, "expected MEDIA PORT PROTO FORMATS"));
                };
                if media != "audio" {
                    continue;
                }
                let port: u16 = port
                    .split('/')
                    .next()
                    .and_then(|p| p.parse().ok())
                    .ok_or_else(|| malformed(line, "bad port"))?;
                let secure = match proto {
                    "RTP/AVP" | "RTP/AVPF" => false,
                    "RTP/SAVP" | "RTP/SAVPF" => true,
                    _ => return Err(malformed(line, "not RTP/AVP audio")),
                };
                let mut formats = Vec::new();
                for pt in parts.take(MAX_FORMATS) {
                    let pt: u8 = pt
                        .parse()
                        .ok()
                        .filter(|&pt| pt < 128)
                        .ok_or_else(|| malformed(line, "bad payload type"))?;
                    let (encoding, clock_rate) = static_format(pt).unwrap_or(("", 0));
                    formats.push(Format {
                        payload_type: pt,
                        encoding: encoding.to_owned(),
                        clock_rate,
                    });
                }
                audio = Some(AudioLine {
                    port,
                    formats,
                    addr: None,
                    direction: None,
                    secure,
                    crypto: None,
                    rtcp: None,
                    rtcp_mux: false,
                });
                in_audio = true;
            }
            "c" => {
                let addr = parse_address(line, value)?;
                match (&mut audio, in_audio) {
                    (Some(a), true) => a.addr = addr,
                    (None, _) if !past_audio => session_addr = addr,
                    _ => {}
                }
            }
            "a" => {
                let (name, attr_value) = value.split_once(':').unwrap_or((value, ""));
                let direction = match name {
                    "sendrecv" => Some(Direction::SendRecv),
                    "sendonly" => Some(Direction::SendOnly),
                    "recvonly" => Some(Direction::RecvOnly),
                    "inactive" => Some(Direction::Inactive),
                    _ => None,
                };
                match (&mut audio, in_audio) {
                    (Some(a), true) => {
                        if let Some(d) = direction {
                            a.direction = Some(d);
                        } else if name == "crypto" {
                            if a.crypto.is_none() {
                                a.crypto = parse_crypto(attr_value);
                            }
                        } else if name == "rtcp" {
                            a.rtcp = Some(parse_rtcp(line, attr_value)?);
                        } else if name == "rtcp-mux" {
                            a.rtcp_mux = true;
                        } else if name == "rtpmap" {
                            let (pt, encoding, clock) = parse_rtpmap(line, attr_value)?;
                            if let Some(f) = a.formats.iter_mut().find(|f| f.payload_type == pt) {
                                f.encoding = encoding;
                                f.clock_rate = clock;
                            }
                        }
                    }
                    (None, _) => {
                        if let Some(d) = direction {
                            session_direction = d;
                        }
                    }
                    _ => {}
                }
            }
            _ if kind.len() == 1 => {}
            _ => return Err(malformed(line, "expected a one-letter type")),
        }
    }
    let AudioLine {
        port,
        formats,
        addr: media_addr,
        direction,
        secure,
        crypto,
        rtcp,
        rtcp_mux,
    } = audio.ok_or(SdpError::NoAudio)?;
    if port == 0 {
        return Err(SdpError::Refused);
    }
    let ip = media_addr.or(session_addr).ok_or(SdpError::NoAddress)?;
    let rtcp = match rtcp {
        Some((rtcp_port, rtcp_ip)) => SocketAddr::new(rtcp_ip.unwrap_or(ip), rtcp_port),
        // RTP ports are even: an odd last one has no port above it, and only mux can help.
        None => SocketAddr::new(ip, port.checked_add(1).unwrap_or(port)),
    };
    Ok(RemoteAudio {
        addr: SocketAddr::new(ip, port),
        rtcp,
        rtcp_mux,
        formats,
        direction: direction.unwrap_or(session_direction),
        secure,
        crypto,
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
    })
}

/// The peer's description (an offer or an answer) read, its media address checked against our
/// socket's family (`local.addr`) and the codec chosen among `local.codecs`.
pub fn take(text: &str, local: &LocalAudio) -> Result<Negotiated, SdpError> {
    let remote = parse(text)?;
    media_target(remote.addr, local.addr)?;
    media_target(remote.rtcp, local.addr)?;
    negotiate(&remote, &local.codecs)
}

/// As [`take`], for an offer within a call, where `c=0.0.0.0` is RFC 2543's hold, which RFC
/// 3264 (8.4) still asks us to take: the peer receives nothing, and our media keeps the
/// address it had (`remote` stays unspecified; [`super::media`] sends nothing there).
pub fn take_in_call(text: &str, local: &LocalAudio) -> Result<Negotiated, SdpError> {
    let remote = parse(text)?;
    let held = remote.addr.ip().is_unspecified() && remote.addr.is_ipv4() == local.addr.is_ipv4();
    if !held {
        media_target(remote.addr, local.addr)?;
        media_target(remote.rtcp, local.addr)?;
    }
    let mut negotiated = negotiate(&remote, &local.codecs)?;
    if held {
        negotiated.direction = negotiated.direction.deaf();
    }
    Ok(negotiated)
}

fn header(local: &LocalAudio, version: u64) -> String {
    let family = if local.addr.is_ipv4() { "IP4" } else { "IP6" };
    let ip = local.addr.ip();
    format!(
        "v=0\r\no=lipcall {} {version} IN {family} {ip}\r\ns=lipcall\r\nc=IN {family} {ip}\r\nt=0 0\r\n",
        local.session_id
    )
}

fn rtpmap(codec: Codec, pt: u8) -> String {
    match codec {
        Codec::Opus => format!("a=rtpmap:{pt} opus/48000/2\r\na=fmtp:{pt} useinbandfec=1\r\n"),
        other => format!(
            "a=rtpmap:{pt} {}/{}\r\n",
            other.encoding_name(),
            other.clock_rate()
        ),
    }
}

/// Where our RTCP socket is, as `a=rtcp` says it (the address only where it is not the RTP's).
fn rtcp_attribute(local: &LocalAudio) -> String {
    match local.rtcp {
        Some(rtcp) if rtcp.ip() == local.addr.ip() => format!("a=rtcp:{}\r\n", rtcp.port()),
        Some(rtcp) => {
            let family = if rtcp.is_ipv4() { "IP4" } else { "IP6" };
            format!("a=rtcp:{} IN {family} {}\r\n", rtcp.port(), rtcp.ip())
        }
        None => String::new(),
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
pub fn offer(local: &LocalAudio, version: u64) -> String {
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
    let list: Vec<String> = types.iter().map(u8::to_string).collect();
    let mut sdp = header(local, version);
    sdp.push_str(&format!(
        "m=audio {} {} {}\r\n",
        local.addr.port(),
        if local.offer_srtp {
            "RTP/SAVP"
        } else {
            "RTP/AVP"
        },
        list.join(" ")
    ));
    if local.offer_srtp {
        sdp.push_str(&format!(
            "a=crypto:1 {SRTP_SUITE} inline:{}\r\n",
            local.key.inline()
        ));
    }
    for &codec in &codecs {
        sdp.push_str(&rtpmap(codec, offered_type(codec)));
    }
    sdp.push_str(&format!(
        "a=rtpmap:{EVENT_PT} telephone-event/8000\r\na=fmtp:{EVENT_PT} 0-16\r\n"
    ));
    if wide {
        sdp.push_str(&format!(
            "a=rtpmap:{EVENT_WIDE_PT} telephone-event/48000\r\na=fmtp:{EVENT_WIDE_PT} 0-16\r\n"
        ));
    }
    sdp.push_str(&rtcp_attribute(local));
    sdp.push_str("a=rtcp-mux\r\na=ptime:20\r\na=sendrecv\r\n");
    sdp
}

/// Our answer to an offer that negotiated as `chosen`: its codec and events on the peer's
/// payload types, the direction mirrored.
pub fn answer(local: &LocalAudio, chosen: &Negotiated, version: u64) -> String {
    let mut types = vec![chosen.payload_type];
    types.extend(chosen.events);
    let list: Vec<String> = types.iter().map(u8::to_string).collect();
    let mut sdp = header(local, version);
    sdp.push_str(&format!(
        "m=audio {} {} {}\r\n",
        local.addr.port(),
        if chosen.srtp.is_some() {
            "RTP/SAVP"
        } else {
            "RTP/AVP"
        },
        list.join(" ")
    ));
    if let Some(theirs) = &chosen.srtp {
        sdp.push_str(&format!(
            "a=crypto:{} {SRTP_SUITE} inline:{}\r\n",
            theirs.tag,
            local.key.inline()
        ));
    }
    sdp.push_str(&rtpmap(chosen.codec, chosen.payload_type));
    if let Some(pt) = chosen.events {
        sdp.push_str(&format!(
            "a=rtpmap:{pt} telephone-event/{}\r\na=fmtp:{pt} 0-16\r\n",
            chosen.codec.clock_rate()
        ));
    }
    if chosen.rtcp_mux {
        sdp.push_str("a=rtcp-mux\r\n");
    } else {
        sdp.push_str(&rtcp_attribute(local));
    }
    sdp.push_str(&format!(
        "a=ptime:20\r\na={}\r\n",
        chosen.direction.reversed().attribute()
    ));
    sdp
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const BARESIP_OFFER: &str = "v=0\r\no=- 123 456 IN IP4 127.0.0.1\r\ns=-\r\nc=IN IP4 127.0.0.1\r\n\
        t=0 0\r\nm=audio 10000 RTP/AVP 96 0 8 101\r\na=rtpmap:96 opus/48000/2\r\n\
        a=fmtp:96 stereo=1\r\na=rtpmap:101 telephone-event/8000\r\na=sendrecv\r\n";

    fn local() -> LocalAudio {
        LocalAudio {
            addr: "127.0.0.1:4000".parse().unwrap(),
            rtcp: Some("127.0.0.1:4001".parse().unwrap()),
            codecs: vec![Codec::Opus, Codec::Pcmu, Codec::Pcma],
            session_id: 7,
            key: SdesKey([7; SDES_KEY_LEN]),
            offer_srtp: false,
        }
    }

    #[test]
    fn sdes_keys_go_both_ways_and_never_print() {
        let mut ours = local();
        ours.offer_srtp = true;
        let offer = offer(&ours, 1);
        assert!(offer.contains("m=audio 4000 RTP/SAVP "), "{offer}");
        assert!(
            offer.contains("a=crypto:1 AES_CM_128_HMAC_SHA1_80 inline:"),
            "{offer}"
        );
        let remote = parse(&offer).unwrap();
        let chosen = negotiate(&remote, &[Codec::Pcmu]).unwrap();
        let theirs = chosen.srtp.clone().expect("SRTP agreed");
        assert_eq!((theirs.tag, &theirs.key), (1, &ours.key));
        assert!(!format!("{chosen:?}").contains("7, 7"));
        // An answer to it gives our key under the offer's tag.
        let answer = answer(&local(), &chosen, 2);
        assert!(
            answer.contains("RTP/SAVP") && answer.contains("a=crypto:1 "),
            "{answer}"
        );
        // SRTP with another suite only, or no key, is refused; a broken key is no key.
        let other = "v=0\r\nc=IN IP4 1.2.3.4\r\nm=audio 5 RTP/SAVP 0\r\n\
                     a=crypto:1 AES_256_CM_HMAC_SHA1_80 inline:AAAA\r\n";
        assert_eq!(
            negotiate(&parse(other).unwrap(), &[Codec::Pcmu]),
            Err(SdpError::Encrypted)
        );
        let short = "v=0\r\nc=IN IP4 1.2.3.4\r\nm=audio 5 RTP/SAVP 0\r\n\
                     a=crypto:1 AES_CM_128_HMAC_SHA1_80 inline:AAAA\r\n";
        assert_eq!(
            negotiate(&parse(short).unwrap(), &[Codec::Pcmu]),
            Err(SdpError::Encrypted)
        );
    }

    #[test]
    fn a_softphone_offer_negotiates_its_first_codec_and_events() {
        let remote = parse(BARESIP_OFFER).unwrap();
        assert_eq!(remote.addr, "127.0.0.1:10000".parse().unwrap());
        let n = negotiate(&remote, &[Codec::Pcmu, Codec::Opus]).unwrap();
        assert_eq!((n.codec, n.payload_type), (Codec::Opus, 96));
        assert_eq!(n.payloads.codec(96), Some(Codec::Opus));
        assert_eq!(
            n.events, None,
            "events at 8 kHz do not go with Opus's clock"
        );
        let n = negotiate(&remote, &[Codec::Pcmu]).unwrap();
        assert_eq!(
            (n.codec, n.payload_type, n.events),
            (Codec::Pcmu, 0, Some(101))
        );
        let answer = answer(&local(), &n, 1);
        assert!(
            answer.contains("m=audio 4000 RTP/AVP 0 101\r\n"),
            "{answer}"
        );
        let back = parse(&answer).unwrap();
        assert_eq!(back.formats[0].encoding, "PCMU");
    }

    #[test]
    fn our_offer_reads_back() {
        let offer = offer(&local(), 1);
        let remote = parse(&offer).unwrap();
        assert_eq!(remote.addr, local().addr);
        let n = negotiate(&remote, &[Codec::Opus]).unwrap();
        assert_eq!(
            (n.codec, n.payload_type, n.events),
            (Codec::Opus, 111, Some(102))
        );
    }

    #[test]
    fn rtcp_goes_to_the_port_above_or_where_a_rtcp_says_or_on_the_rtp_port_with_mux() {
        // baresip's default: neither attribute, RTCP on the RTP port + 1.
        let n = take(BARESIP_OFFER, &local()).unwrap();
        assert_eq!(
            (n.rtcp, n.rtcp_mux),
            ("127.0.0.1:10001".parse().unwrap(), false)
        );
        let ours_back = answer(&local(), &n, 1);
        assert!(ours_back.contains("a=rtcp:4001\r\n"), "{ours_back}");
        assert!(!ours_back.contains("rtcp-mux"), "{ours_back}");
        // Our offer names our RTCP socket and offers mux; an answer taking mux says it back.
        let mut ours = local();
        ours.rtcp = Some("192.0.2.7:5001".parse().unwrap());
        let offer = offer(&ours, 1);
        assert!(
            offer.contains("a=rtcp:5001 IN IP4 192.0.2.7\r\na=rtcp-mux\r\n"),
            "{offer}"
        );
        let remote = parse(&offer).unwrap();
        assert_eq!(remote.rtcp, "192.0.2.7:5001".parse().unwrap());
        let muxed = negotiate(&remote, &[Codec::Pcmu]).unwrap();
        assert_eq!((muxed.rtcp, muxed.rtcp_mux), (remote.addr, true));
        assert!(answer(&local(), &muxed, 1).contains("a=rtcp-mux\r\n"));
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
        assert_eq!(parse("v=0\r\n"), Err(SdpError::NoAudio));
        assert!(matches!(parse("garbage"), Err(SdpError::Malformed { .. })));
        assert_eq!(
            parse("v=0\r\nc=IN IP4 1.2.3.4\r\nm=audio 0 RTP/AVP 0\r\n"),
            Err(SdpError::Refused)
        );
        assert_eq!(
            parse("v=0\r\nm=audio 5 RTP/AVP 0\r\n"),
            Err(SdpError::NoAddress)
        );
        assert!(parse("v=0\r\nc=IN IP4 host.example\r\nm=audio 5 RTP/AVP 0\r\n").is_err());
        assert!(parse("v=0\r\nc=IN IP4 1.2.3.4\r\nm=audio 5 RTP/AVP 300\r\n").is_err());
        let no_key = parse("v=0\r\nc=IN IP4 1.2.3.4\r\nm=audio 5 RTP/SAVP 0\r\n").unwrap();
        assert_eq!(negotiate(&no_key, &[Codec::Pcmu]), Err(SdpError::Encrypted));
        let g729 = parse("v=0\r\nc=IN IP4 1.2.3.4\r\nm=audio 5 RTP/AVP 18\r\n").unwrap();
        assert!(matches!(
            negotiate(&g729, &[Codec::Pcmu]),
            Err(SdpError::NoCommonCodec(_))
        ));
        assert!(matches!(
            parse(&"a=x\r\n".repeat(MAX_SDP_BYTES)),
            Err(SdpError::TooLong(_))
        ));
    }

    #[test]
    fn odd_media_addresses_are_refused_by_name() {
        let described = |c: &str| format!("v=0\r\nc={c}\r\nm=audio 5000 RTP/AVP 0\r\n");
        assert!(take(&described("IN IP4 127.0.0.1"), &local()).is_ok());
        for (c, named) in [
            ("IN IP4 0.0.0.0", "0.0.0.0:5000"),
            ("IN IP4 255.255.255.255", "255.255.255.255:5000"),
            ("IN IP4 224.0.0.1/127", "224.0.0.1:5000"),
            ("IN IP6 ::1", "[::1]:5000"),
        ] {
            let e = take(&described(c), &local()).unwrap_err();
            assert!(matches!(e, SdpError::OddAddress(_)), "{c}: {e:?}");
            assert!(e.to_string().contains(named), "{e}");
        }
        // Within a call, 0.0.0.0 is an old-style hold: taken, and answered recvonly.
        let held = take_in_call(&described("IN IP4 0.0.0.0"), &local()).unwrap();
        assert_eq!(held.direction, Direction::SendOnly);
        assert!(answer(&local(), &held, 2).contains("a=recvonly"));
        assert!(take_in_call(&described("IN IP4 224.0.0.1"), &local()).is_err());
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        #[test]
        fn any_text_parses_or_is_an_error(text in "(([vocmtas]=[ -~]{0,40})?\r\n){0,12}") {
            if let Ok(remote) = parse(&text) {
                let _ = negotiate(&remote, &Codec::ALL);
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
            if let Ok(chosen) = parse(&text).and_then(|r| negotiate(&r, &Codec::ALL)) {
                // Whatever was agreed, our answer says it back.
                let back = parse(&answer(&local(), &chosen, 2)).unwrap();
                let again = negotiate(&back, &Codec::ALL).unwrap();
                prop_assert_eq!(
                    (again.codec, again.payload_type, again.events),
                    (chosen.codec, chosen.payload_type, chosen.events)
                );
            }
        }
    }
}
