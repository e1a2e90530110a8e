//! The relay's control datagrams. A room is named on the wire only by a hash, so the relay
//! never sees the name.
//!
//! Joining proves the joiner's address: a `Join` is answered with a `Challenge` carrying a
//! cookie (a keyed hash of the source address and room, which the relay keeps no state for);
//! only a `Confirm` echoing it from that address makes a member. The cookie is then the
//! member's token: the keepalive (`Confirm` again, every few seconds) and `Leave` carry it, so
//! nobody who cannot receive at a member's address can join it to a room, hold its place or
//! remove it. The relay's answers (`Joined`, `Refused`) echo the cookie they answer.
//!
//! Layout (39 bytes, every kind): `"LPCR"`, version 2, kind, detail (the refusal's reason, else
//! 0), 16-byte room id, 16-byte cookie (zero in a `Join`). The first byte `L` has RTP version
//! bits 01, so a control datagram is never mistaken for RTP or RTCP. Requests and answers are
//! the same size, so the relay never answers with more bytes than it was sent.
//!
//! Version 1 (22 bytes, no cookie) is refused: its joins are answered with its own `Refused`.

use sha2::{Digest, Sha256};

pub const MAGIC: [u8; 4] = *b"LPCR";
pub const VERSION: u8 = 2;
pub const LEN: usize = 39;
/// The first protocol, without cookies: `"LPCR"`, 1, kind, room id.
const LEGACY_VERSION: u8 = 1;
const LEGACY_LEN: usize = 22;
const LEGACY_JOIN: u8 = 1;
const LEGACY_REFUSED: u8 = 4;

/// A room as the relay knows it: a hash of its name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RoomId(pub [u8; 16]);

impl RoomId {
    pub fn from_name(name: &str) -> Self {
        let digest = Sha256::new()
            .chain_update(b"lipcall-room-v1:")
            .chain_update(name.as_bytes())
            .finalize();
        let mut id = [0u8; 16];
        id.copy_from_slice(&digest[..16]);
        Self(id)
    }
}

/// What the relay hands a joiner's address, and what proves the member later.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Cookie(pub [u8; 16]);

impl Cookie {
    pub const NONE: Cookie = Cookie([0; 16]);

    /// Equality in constant time (a token is a secret an attacker could otherwise probe).
    pub fn matches(&self, other: &Cookie) -> bool {
        self.0
            .iter()
            .zip(&other.0)
            .fold(0u8, |acc, (a, b)| acc | (a ^ b))
            == 0
    }
}

/// Why the relay turned a join down.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Refusal {
    #[error("the room is full")]
    RoomFull,
    #[error("the relay has no room for another room")]
    RelayFull,
    #[error("too many members from this address already")]
    SourceQuota,
    #[error("too many joins from this address; try again in a few seconds")]
    RateLimited,
}

impl Refusal {
    fn code(self) -> u8 {
        match self {
            Refusal::RoomFull => 1,
            Refusal::RelayFull => 2,
            Refusal::SourceQuota => 3,
            Refusal::RateLimited => 4,
        }
    }

    fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            1 => Refusal::RoomFull,
            2 => Refusal::RelayFull,
            3 => Refusal::SourceQuota,
            4 => Refusal::RateLimited,
            _ => return None,
        })
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ControlKind {
    /// Asks to join the room: answered with a `Challenge`, nothing else.
    Join,
    /// Echoes the challenge's cookie: joins, or keeps the place (sent again as a keepalive).
    Confirm,
    /// Leaves the room (with the member's cookie).
    Leave,
    /// The relay's answer to a `Join`: the cookie to echo.
    Challenge,
    /// The relay's answer to a `Confirm`: the sender is a member.
    Joined,
    /// The relay's answer to a `Confirm` it cannot admit.
    Refused(Refusal),
}

impl ControlKind {
    fn code(self) -> (u8, u8) {
        match self {
            ControlKind::Join => (1, 0),
            ControlKind::Leave => (2, 0),
            ControlKind::Joined => (3, 0),
            ControlKind::Refused(why) => (4, why.code()),
            ControlKind::Challenge => (5, 0),
            ControlKind::Confirm => (6, 0),
        }
    }

    fn from_code(code: u8, detail: u8) -> Option<Self> {
        let kind = match code {
            1 => ControlKind::Join,
            2 => ControlKind::Leave,
            3 => ControlKind::Joined,
            4 => return Refusal::from_code(detail).map(ControlKind::Refused),
            5 => ControlKind::Challenge,
            6 => ControlKind::Confirm,
            _ => return None,
        };
        (detail == 0).then_some(kind)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Control {
    pub kind: ControlKind,
    pub room: RoomId,
    pub cookie: Cookie,
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ControlError {
    #[error("malformed relay control datagram")]
    Malformed,
    #[error(
        "relay control datagram of protocol version {0}; this lipcall speaks version {VERSION}: update it"
    )]
    Version(u8),
}

impl Control {
    pub fn new(kind: ControlKind, room: RoomId, cookie: Cookie) -> Self {
        Self { kind, room, cookie }
    }

    pub fn encode(&self) -> [u8; LEN] {
        let mut out = [0u8; LEN];
        let (kind, detail) = self.kind.code();
        out[..4].copy_from_slice(&MAGIC);
        out[4] = VERSION;
        out[5] = kind;
        out[6] = detail;
        out[7..23].copy_from_slice(&self.room.0);
        out[23..].copy_from_slice(&self.cookie.0);
        out
    }

    pub fn decode(data: &[u8]) -> Result<Self, ControlError> {
        if data.len() < 5 || data[..4] != MAGIC {
            return Err(ControlError::Malformed);
        }
        if data[4] != VERSION {
            return Err(ControlError::Version(data[4]));
        }
        if data.len() != LEN {
            return Err(ControlError::Malformed);
        }
        let kind = ControlKind::from_code(data[5], data[6]).ok_or(ControlError::Malformed)?;
        let mut room = [0u8; 16];
        room.copy_from_slice(&data[7..23]);
        let mut cookie = [0u8; 16];
        cookie.copy_from_slice(&data[23..]);
        Ok(Self {
            kind,
            room: RoomId(room),
            cookie: Cookie(cookie),
        })
    }
}

/// For a well-formed version 1 join: that protocol's `Refused` for its room, which an outdated
/// client reports as a refusal instead of waiting in silence. The same size as the join.
pub fn legacy_refusal(data: &[u8]) -> Option<[u8; LEGACY_LEN]> {
    if data.len() != LEGACY_LEN
        || data[..4] != MAGIC
        || data[4] != LEGACY_VERSION
        || data[5] != LEGACY_JOIN
    {
        return None;
    }
    let mut out = [0u8; LEGACY_LEN];
    out.copy_from_slice(data);
    out[5] = LEGACY_REFUSED;
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_rejects() {
        let room = RoomId::from_name("kitchen");
        let cookie = Cookie([7; 16]);
        for kind in [
            ControlKind::Join,
            ControlKind::Confirm,
            ControlKind::Leave,
            ControlKind::Challenge,
            ControlKind::Joined,
            ControlKind::Refused(Refusal::RoomFull),
            ControlKind::Refused(Refusal::RelayFull),
            ControlKind::Refused(Refusal::SourceQuota),
            ControlKind::Refused(Refusal::RateLimited),
        ] {
            let c = Control::new(kind, room, cookie);
            let bytes = c.encode();
            assert_eq!(
                crate::net::classify(&bytes),
                crate::net::DatagramKind::Control
            );
            assert_eq!(Control::decode(&bytes), Ok(c));
        }
        assert_ne!(RoomId::from_name("kitchen"), RoomId::from_name("garden"));
        let bytes = Control::new(ControlKind::Join, room, Cookie::NONE).encode();
        for (at, value) in [(5, 9), (6, 1), (5, 0)] {
            let mut bad = bytes;
            bad[at] = value;
            assert_eq!(Control::decode(&bad), Err(ControlError::Malformed));
        }
        let mut refused =
            Control::new(ControlKind::Refused(Refusal::RoomFull), room, cookie).encode();
        refused[6] = 0;
        assert_eq!(Control::decode(&refused), Err(ControlError::Malformed));
        assert_eq!(
            Control::decode(&bytes[..LEN - 1]),
            Err(ControlError::Malformed)
        );
        assert_eq!(Control::decode(b"LPC"), Err(ControlError::Malformed));
    }

    #[test]
    fn version_1_is_told_apart_and_its_join_refused_in_its_own_format() {
        let mut v1_join = [0u8; LEGACY_LEN];
        v1_join[..4].copy_from_slice(&MAGIC);
        v1_join[4] = 1;
        v1_join[5] = 1;
        v1_join[6..].copy_from_slice(&RoomId::from_name("kitchen").0);
        assert_eq!(Control::decode(&v1_join), Err(ControlError::Version(1)));
        let refusal = legacy_refusal(&v1_join).unwrap();
        assert_eq!(refusal[5], 4);
        assert_eq!(refusal[6..], v1_join[6..]);
        let mut v1_leave = v1_join;
        v1_leave[5] = 2;
        assert_eq!(legacy_refusal(&v1_leave), None);
        assert_eq!(legacy_refusal(&v1_join[..21]), None);
    }

    #[test]
    fn cookies_match_only_themselves() {
        let a = Cookie([1; 16]);
        let mut b = a;
        assert!(a.matches(&b));
        b.0[15] ^= 0x80;
        assert!(!a.matches(&b));
    }
}
