//! Mumble's control messages: the protobuf messages of Mumble.proto (BSD licence, see NOTICE)
//! that a voice client needs, written by hand as prost structs with the .proto's field numbers
//! (no protoc at build time), and the TLS stream's framing: a big-endian u16 type and u32
//! length before each message.

use super::MumbleError;

/// The largest control message we accept (murmur's own limit is 8 MiB; a voice client never
/// needs more than its channel and user lists).
pub const MAX_MESSAGE: usize = 8 * 1024 * 1024;
/// Bytes of a frame's header: type (u16) and length (u32).
pub const HEADER: usize = 6;

/// The message types of the TCP framing, in Mumble.proto's order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u16)]
pub enum MessageType {
    Version = 0,
    UdpTunnel = 1,
    Authenticate = 2,
    Ping = 3,
    Reject = 4,
    ServerSync = 5,
    ChannelRemove = 6,
    ChannelState = 7,
    UserRemove = 8,
    UserState = 9,
    TextMessage = 11,
    PermissionDenied = 12,
    CryptSetup = 15,
    CodecVersion = 21,
    ServerConfig = 24,
}

impl MessageType {
    pub fn from_u16(value: u16) -> Option<Self> {
        use MessageType::*;
        Some(match value {
            0 => Version,
            1 => UdpTunnel,
            2 => Authenticate,
            3 => Ping,
            4 => Reject,
            5 => ServerSync,
            6 => ChannelRemove,
            7 => ChannelState,
            8 => UserRemove,
            9 => UserState,
            11 => TextMessage,
            12 => PermissionDenied,
            15 => CryptSetup,
            21 => CodecVersion,
            24 => ServerConfig,
            _ => return None,
        })
    }
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct Version {
    #[prost(uint32, optional, tag = "1")]
    pub version: Option<u32>,
    #[prost(string, optional, tag = "2")]
    pub release: Option<String>,
    #[prost(string, optional, tag = "3")]
    pub os: Option<String>,
    #[prost(string, optional, tag = "4")]
    pub os_version: Option<String>,
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct Authenticate {
    #[prost(string, optional, tag = "1")]
    pub username: Option<String>,
    #[prost(string, optional, tag = "2")]
    pub password: Option<String>,
    #[prost(string, repeated, tag = "3")]
    pub tokens: Vec<String>,
    #[prost(int32, repeated, packed = "false", tag = "4")]
    pub celt_versions: Vec<i32>,
    #[prost(bool, optional, tag = "5")]
    pub opus: Option<bool>,
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct Ping {
    #[prost(uint64, optional, tag = "1")]
    pub timestamp: Option<u64>,
    #[prost(uint32, optional, tag = "2")]
    pub good: Option<u32>,
    #[prost(uint32, optional, tag = "3")]
    pub late: Option<u32>,
    #[prost(uint32, optional, tag = "4")]
    pub lost: Option<u32>,
    #[prost(uint32, optional, tag = "5")]
    pub resync: Option<u32>,
    #[prost(uint32, optional, tag = "6")]
    pub udp_packets: Option<u32>,
    #[prost(uint32, optional, tag = "7")]
    pub tcp_packets: Option<u32>,
}

/// Why the server turned the authentication down (`Reject.type`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, prost::Enumeration)]
#[repr(i32)]
pub enum RejectType {
    None = 0,
    WrongVersion = 1,
    InvalidUsername = 2,
    WrongUserPw = 3,
    WrongServerPw = 4,
    UsernameInUse = 5,
    ServerFull = 6,
    NoCertificate = 7,
    AuthenticatorFail = 8,
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct Reject {
    #[prost(enumeration = "RejectType", optional, tag = "1")]
    pub r#type: Option<i32>,
    #[prost(string, optional, tag = "2")]
    pub reason: Option<String>,
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct ServerSync {
    #[prost(uint32, optional, tag = "1")]
    pub session: Option<u32>,
    #[prost(uint32, optional, tag = "2")]
    pub max_bandwidth: Option<u32>,
    #[prost(string, optional, tag = "3")]
    pub welcome_text: Option<String>,
    #[prost(uint64, optional, tag = "4")]
    pub permissions: Option<u64>,
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct ChannelRemove {
    #[prost(uint32, optional, tag = "1")]
    pub channel_id: Option<u32>,
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct ChannelState {
    #[prost(uint32, optional, tag = "1")]
    pub channel_id: Option<u32>,
    #[prost(uint32, optional, tag = "2")]
    pub parent: Option<u32>,
    #[prost(string, optional, tag = "3")]
    pub name: Option<String>,
    #[prost(uint32, optional, tag = "11")]
    pub max_users: Option<u32>,
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct UserRemove {
    #[prost(uint32, optional, tag = "1")]
    pub session: Option<u32>,
    #[prost(uint32, optional, tag = "2")]
    pub actor: Option<u32>,
    #[prost(string, optional, tag = "3")]
    pub reason: Option<String>,
    #[prost(bool, optional, tag = "4")]
    pub ban: Option<bool>,
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct UserState {
    #[prost(uint32, optional, tag = "1")]
    pub session: Option<u32>,
    #[prost(uint32, optional, tag = "2")]
    pub actor: Option<u32>,
    #[prost(string, optional, tag = "3")]
    pub name: Option<String>,
    #[prost(uint32, optional, tag = "4")]
    pub user_id: Option<u32>,
    #[prost(uint32, optional, tag = "5")]
    pub channel_id: Option<u32>,
    #[prost(bool, optional, tag = "6")]
    pub mute: Option<bool>,
    #[prost(bool, optional, tag = "7")]
    pub deaf: Option<bool>,
    #[prost(bool, optional, tag = "8")]
    pub suppress: Option<bool>,
    #[prost(bool, optional, tag = "9")]
    pub self_mute: Option<bool>,
    #[prost(bool, optional, tag = "10")]
    pub self_deaf: Option<bool>,
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct TextMessage {
    #[prost(uint32, optional, tag = "1")]
    pub actor: Option<u32>,
    #[prost(uint32, repeated, packed = "false", tag = "2")]
    pub session: Vec<u32>,
    #[prost(uint32, repeated, packed = "false", tag = "3")]
    pub channel_id: Vec<u32>,
    #[prost(uint32, repeated, packed = "false", tag = "4")]
    pub tree_id: Vec<u32>,
    #[prost(string, optional, tag = "5")]
    pub message: Option<String>,
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct PermissionDenied {
    #[prost(uint32, optional, tag = "1")]
    pub permission: Option<u32>,
    #[prost(uint32, optional, tag = "2")]
    pub channel_id: Option<u32>,
    #[prost(uint32, optional, tag = "3")]
    pub session: Option<u32>,
    #[prost(string, optional, tag = "4")]
    pub reason: Option<String>,
    #[prost(int32, optional, tag = "5")]
    pub r#type: Option<i32>,
    #[prost(string, optional, tag = "6")]
    pub name: Option<String>,
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct CryptSetup {
    #[prost(bytes = "vec", optional, tag = "1")]
    pub key: Option<Vec<u8>>,
    #[prost(bytes = "vec", optional, tag = "2")]
    pub client_nonce: Option<Vec<u8>>,
    #[prost(bytes = "vec", optional, tag = "3")]
    pub server_nonce: Option<Vec<u8>>,
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct CodecVersion {
    #[prost(int32, optional, tag = "1")]
    pub alpha: Option<i32>,
    #[prost(int32, optional, tag = "2")]
    pub beta: Option<i32>,
    #[prost(bool, optional, tag = "3")]
    pub prefer_alpha: Option<bool>,
    #[prost(bool, optional, tag = "4")]
    pub opus: Option<bool>,
}

#[derive(Clone, PartialEq, prost::Message)]
pub struct ServerConfig {
    #[prost(uint32, optional, tag = "1")]
    pub max_bandwidth: Option<u32>,
    #[prost(string, optional, tag = "2")]
    pub welcome_text: Option<String>,
    #[prost(bool, optional, tag = "3")]
    pub allow_html: Option<bool>,
    #[prost(uint32, optional, tag = "4")]
    pub message_length: Option<u32>,
    #[prost(uint32, optional, tag = "5")]
    pub image_message_length: Option<u32>,
    #[prost(uint32, optional, tag = "6")]
    pub max_users: Option<u32>,
}

/// A control message from the server, decoded.
#[derive(Debug, Clone, PartialEq)]
pub enum Incoming {
    Version(Version),
    UdpTunnel(Vec<u8>),
    Ping(Ping),
    Reject(Reject),
    ServerSync(ServerSync),
    ChannelRemove(ChannelRemove),
    ChannelState(ChannelState),
    UserRemove(UserRemove),
    UserState(UserState),
    TextMessage(TextMessage),
    PermissionDenied(PermissionDenied),
    CryptSetup(CryptSetup),
    CodecVersion(CodecVersion),
    ServerConfig(ServerConfig),
    /// A type a voice client has no use for (ACLs, ban lists, user lists, ...): skipped.
    Other(u16),
}

fn decode<M: prost::Message + Default>(kind: &'static str, body: &[u8]) -> Result<M, MumbleError> {
    M::decode(body).map_err(|e| MumbleError::Malformed(format!("{kind}: {e}")))
}

impl Incoming {
    /// Decodes the body of a frame of type `kind`.
    pub fn decode(kind: u16, body: &[u8]) -> Result<Self, MumbleError> {
        use MessageType as T;
        let Some(known) = MessageType::from_u16(kind) else {
            return Ok(Self::Other(kind));
        };
        Ok(match known {
            T::Version => Self::Version(decode("Version", body)?),
            // Not protobuf: the voice packet itself, as it would travel by UDP.
            T::UdpTunnel => Self::UdpTunnel(body.to_vec()),
            T::Ping => Self::Ping(decode("Ping", body)?),
            T::Reject => Self::Reject(decode("Reject", body)?),
            T::ServerSync => Self::ServerSync(decode("ServerSync", body)?),
            T::ChannelRemove => Self::ChannelRemove(decode("ChannelRemove", body)?),
            T::ChannelState => Self::ChannelState(decode("ChannelState", body)?),
            T::UserRemove => Self::UserRemove(decode("UserRemove", body)?),
            T::UserState => Self::UserState(decode("UserState", body)?),
            T::TextMessage => Self::TextMessage(decode("TextMessage", body)?),
            T::PermissionDenied => Self::PermissionDenied(decode("PermissionDenied", body)?),
            T::CryptSetup => Self::CryptSetup(decode("CryptSetup", body)?),
            T::CodecVersion => Self::CodecVersion(decode("CodecVersion", body)?),
            T::ServerConfig => Self::ServerConfig(decode("ServerConfig", body)?),
            T::Authenticate => Self::Other(kind),
        })
    }
}

/// One message framed for the TLS stream.
pub fn frame(kind: MessageType, message: &impl prost::Message) -> Vec<u8> {
    frame_bytes(kind, &message.encode_to_vec())
}

/// A voice packet framed as a UDPTunnel message (whose body is the packet itself, not
/// protobuf).
pub fn tunnel(packet: &[u8]) -> Vec<u8> {
    frame_bytes(MessageType::UdpTunnel, packet)
}

fn frame_bytes(kind: MessageType, body: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER + body.len());
    out.extend_from_slice(&(kind as u16).to_be_bytes());
    // Our own messages are small (a voice packet, a name): far below u32::MAX.
    out.extend_from_slice(&u32::try_from(body.len()).unwrap_or(u32::MAX).to_be_bytes());
    out.extend_from_slice(body);
    out
}

/// Cuts the TLS byte stream into frames as its bytes arrive.
#[derive(Debug, Default)]
pub struct Deframer {
    buffer: Vec<u8>,
}

impl Deframer {
    pub fn push(&mut self, bytes: &[u8]) {
        self.buffer.extend_from_slice(bytes);
    }

    /// The next whole frame (type, body); `Err` on a length beyond [`MAX_MESSAGE`] (the stream
    /// cannot be trusted after it).
    pub fn next_frame(&mut self) -> Result<Option<(u16, Vec<u8>)>, MumbleError> {
        if self.buffer.len() < HEADER {
            return Ok(None);
        }
        let kind = u16::from_be_bytes([self.buffer[0], self.buffer[1]]);
        let length = u32::from_be_bytes([
            self.buffer[2],
            self.buffer[3],
            self.buffer[4],
            self.buffer[5],
        ]) as usize;
        if length > MAX_MESSAGE {
            return Err(MumbleError::Malformed(format!(
                "a control message of {length} bytes (type {kind}): more than {MAX_MESSAGE}"
            )));
        }
        if self.buffer.len() < HEADER + length {
            return Ok(None);
        }
        let body = self.buffer[HEADER..HEADER + length].to_vec();
        self.buffer.drain(..HEADER + length);
        Ok(Some((kind, body)))
    }
}

/// Mumble's version number for `major.minor.patch` (the 1.2-1.4 encoding; 1.5 servers answer
/// a client announcing it with the legacy UDP voice format).
pub const fn version(major: u32, minor: u32, patch: u32) -> u32 {
    (major << 16) | (minor << 8) | patch
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn frames_round_trip_through_the_deframer_in_pieces() {
        let auth = Authenticate {
            username: Some("ann".into()),
            password: Some("pw".into()),
            opus: Some(true),
            ..Default::default()
        };
        let mut stream = frame(MessageType::Authenticate, &auth);
        stream.extend(frame(
            MessageType::Ping,
            &Ping {
                timestamp: Some(7),
                ..Default::default()
            },
        ));
        let mut d = Deframer::default();
        let mut got = Vec::new();
        for b in &stream {
            d.push(std::slice::from_ref(b));
            while let Some(f) = d.next_frame().unwrap() {
                got.push(f);
            }
        }
        assert_eq!(got.len(), 2);
        assert_eq!(got[0].0, 2);
        assert_eq!(
            <Authenticate as prost::Message>::decode(got[0].1.as_slice()).unwrap(),
            auth
        );
        match Incoming::decode(got[1].0, &got[1].1).unwrap() {
            Incoming::Ping(p) => assert_eq!(p.timestamp, Some(7)),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn field_numbers_match_mumble_proto() {
        // UserState{session=5 (field 1), name="x" (field 3), channel_id=2 (field 5)}
        let bytes = [0x08, 5, 0x1a, 1, b'x', 0x28, 2];
        match Incoming::decode(9, &bytes).unwrap() {
            Incoming::UserState(u) => {
                assert_eq!(u.session, Some(5));
                assert_eq!(u.name.as_deref(), Some("x"));
                assert_eq!(u.channel_id, Some(2));
            }
            other => panic!("{other:?}"),
        }
        // Reject{type=WrongServerPW (4)}
        match Incoming::decode(4, &[0x08, 4]).unwrap() {
            Incoming::Reject(r) => assert_eq!(r.r#type, Some(RejectType::WrongServerPw as i32)),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn an_oversized_length_is_an_error() {
        let mut d = Deframer::default();
        d.push(&[0, 3, 0xff, 0xff, 0xff, 0xff]);
        assert!(d.next_frame().is_err());
    }

    proptest! {
        #[test]
        fn any_body_decodes_or_errs(kind in 0u16..30, body in proptest::collection::vec(any::<u8>(), 0..200)) {
            let _ = Incoming::decode(kind, &body);
        }

        #[test]
        fn any_stream_deframes_without_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            let mut d = Deframer::default();
            d.push(&bytes);
            while let Ok(Some(_)) = d.next_frame() {}
        }
    }
}
