//! The relay's control datagrams: a peer joins a room (and keeps its place with the same
//! message every few seconds), leaves it, and the relay answers. A room is named on the wire
//! only by a hash, so the relay never sees the name.
//!
//! Layout (22 bytes): `"LPCR"`, version 1, kind, 16-byte room id. The first byte `L` has
//! RTP version bits 01, so a control datagram is never mistaken for RTP or RTCP.

use sha2::{Digest, Sha256};

pub const MAGIC: [u8; 4] = *b"LPCR";
const VERSION: u8 = 1;
pub const LEN: usize = 22;

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

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ControlKind {
    /// Join the room, or stay in it (sent again as a keepalive).
    Join,
    Leave,
    /// The relay's answer to a join: the sender is a member.
    Joined,
    /// The relay's answer when the room or the relay is full.
    Refused,
}

impl ControlKind {
    fn code(self) -> u8 {
        match self {
            ControlKind::Join => 1,
            ControlKind::Leave => 2,
            ControlKind::Joined => 3,
            ControlKind::Refused => 4,
        }
    }

    fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            1 => ControlKind::Join,
            2 => ControlKind::Leave,
            3 => ControlKind::Joined,
            4 => ControlKind::Refused,
            _ => return None,
        })
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Control {
    pub kind: ControlKind,
    pub room: RoomId,
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("malformed relay control datagram")]
pub struct ControlError;

impl Control {
    pub fn encode(&self) -> [u8; LEN] {
        let mut out = [0u8; LEN];
        out[..4].copy_from_slice(&MAGIC);
        out[4] = VERSION;
        out[5] = self.kind.code();
        out[6..].copy_from_slice(&self.room.0);
        out
    }

    pub fn decode(data: &[u8]) -> Result<Self, ControlError> {
        if data.len() != LEN || data[..4] != MAGIC || data[4] != VERSION {
            return Err(ControlError);
        }
        let kind = ControlKind::from_code(data[5]).ok_or(ControlError)?;
        let mut room = [0u8; 16];
        room.copy_from_slice(&data[6..]);
        Ok(Self {
            kind,
            room: RoomId(room),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_rejects() {
        let c = Control {
            kind: ControlKind::Join,
            room: RoomId::from_name("kitchen"),
        };
        let bytes = c.encode();
        assert_eq!(
            crate::net::classify(&bytes),
            crate::net::DatagramKind::Control
        );
        assert_eq!(Control::decode(&bytes), Ok(c));
        assert_ne!(RoomId::from_name("kitchen"), RoomId::from_name("garden"));
        let mut bad = bytes;
        bad[5] = 9;
        assert_eq!(Control::decode(&bad), Err(ControlError));
        assert_eq!(Control::decode(&bytes[..21]), Err(ControlError));
    }
}
