//! Mumble's legacy voice packets (1.2 to 1.4, and 1.5 servers talking to clients that announce
//! an older version): one header byte (type in the top 3 bits, target in the low 5), Mumble's
//! own variable-length integers, then the audio. The same bytes travel in a UDP datagram
//! (encrypted) or in a UDPTunnel control message (inside TLS).
//!
//! From the server a voice packet carries the speaker's session, then the sequence number
//! (counting 10 ms frames), then one Opus frame whose length varint has bit 13 set on the
//! last packet of a talk spurt; positional audio may follow and is ignored. From a client the
//! session is left out. A ping (type 1) carries one varint timestamp, echoed back.

use super::MumbleError;

/// Packet types of the header's top 3 bits.
pub const TYPE_PING: u8 = 1;
pub const TYPE_OPUS: u8 = 4;
/// Bit 13 of an Opus length: the last packet of a talk spurt.
pub const TERMINATOR: u64 = 0x2000;
/// The largest Opus frame the length field can carry.
pub const MAX_OPUS: usize = 0x1fff;

/// Appends Mumble's varint encoding of `value`.
pub fn write_varint(out: &mut Vec<u8>, value: i64) {
    let mut v = value as u64;
    if value < 0 {
        let inverted = !value as u64;
        if inverted <= 3 {
            out.push(0xfc | inverted as u8);
            return;
        }
        out.push(0xf8);
        v = inverted;
    }
    if v < 0x80 {
        out.push(v as u8);
    } else if v < 0x4000 {
        out.extend_from_slice(&[0x80 | (v >> 8) as u8, v as u8]);
    } else if v < 0x20_0000 {
        out.extend_from_slice(&[0xc0 | (v >> 16) as u8, (v >> 8) as u8, v as u8]);
    } else if v < 0x1000_0000 {
        out.extend_from_slice(&[
            0xe0 | (v >> 24) as u8,
            (v >> 16) as u8,
            (v >> 8) as u8,
            v as u8,
        ]);
    } else if v < 0x1_0000_0000 {
        out.push(0xf0);
        out.extend_from_slice(&(v as u32).to_be_bytes());
    } else {
        out.push(0xf4);
        out.extend_from_slice(&v.to_be_bytes());
    }
}

/// Reads Mumble's varints from a byte slice.
#[derive(Debug)]
pub struct Reader<'a> {
    data: &'a [u8],
}

impl<'a> Reader<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        Self { data }
    }

    fn byte(&mut self) -> Result<u8, MumbleError> {
        let (&b, rest) = self
            .data
            .split_first()
            .ok_or_else(|| MumbleError::Malformed("voice packet cut short".into()))?;
        self.data = rest;
        Ok(b)
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], MumbleError> {
        if self.data.len() < n {
            return Err(MumbleError::Malformed(format!(
                "voice packet cut short: {n} bytes announced, {} left",
                self.data.len()
            )));
        }
        let (head, rest) = self.data.split_at(n);
        self.data = rest;
        Ok(head)
    }

    fn be(&mut self, n: usize) -> Result<u64, MumbleError> {
        Ok(self
            .take(n)?
            .iter()
            .fold(0u64, |acc, &b| (acc << 8) | u64::from(b)))
    }

    pub fn varint(&mut self) -> Result<i64, MumbleError> {
        self.varint_nested(0)
    }

    fn varint_nested(&mut self, depth: u8) -> Result<i64, MumbleError> {
        let b = self.byte()?;
        let v = u64::from(b);
        Ok(match b {
            0x00..=0x7f => v as i64,
            0x80..=0xbf => (((v & 0x3f) << 8) | self.be(1)?) as i64,
            0xc0..=0xdf => (((v & 0x1f) << 16) | self.be(2)?) as i64,
            0xe0..=0xef => (((v & 0x0f) << 24) | self.be(3)?) as i64,
            0xf0..=0xf3 => self.be(4)? as i64,
            0xf4..=0xf7 => self.be(8)? as i64,
            0xf8..=0xfb => {
                // A negated varint; one level only (a chain of them means nothing).
                if depth > 0 {
                    return Err(MumbleError::Malformed("nested negative varint".into()));
                }
                !self.varint_nested(depth + 1)?
            }
            0xfc..=0xff => !((v & 0x03) as i64),
        })
    }

    pub fn rest(&self) -> &'a [u8] {
        self.data
    }
}

/// A voice packet from the server (the Opus ones; other codecs are reported as such).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ServerPacket<'a> {
    Ping {
        timestamp: u64,
    },
    Opus {
        session: u32,
        sequence: u64,
        frame: &'a [u8],
        last: bool,
    },
    /// CELT or Speex: a codec we do not decode.
    OtherCodec {
        kind: u8,
        session: u32,
    },
}

fn non_negative(v: i64, what: &str) -> Result<u64, MumbleError> {
    u64::try_from(v).map_err(|_| MumbleError::Malformed(format!("negative {what} {v}")))
}

/// Parses a voice packet as the server sends it.
pub fn parse_server_packet(data: &[u8]) -> Result<ServerPacket<'_>, MumbleError> {
    let mut r = Reader::new(data);
    let header = r.byte()?;
    let kind = header >> 5;
    match kind {
        TYPE_PING => Ok(ServerPacket::Ping {
            timestamp: r.varint()? as u64,
        }),
        TYPE_OPUS => {
            let session = u32::try_from(non_negative(r.varint()?, "session")?)
                .map_err(|_| MumbleError::Malformed("session beyond 32 bits".into()))?;
            let sequence = non_negative(r.varint()?, "sequence")?;
            let length = non_negative(r.varint()?, "Opus length")?;
            let size = (length & MAX_OPUS as u64) as usize;
            let frame = r.take(size)?;
            Ok(ServerPacket::Opus {
                session,
                sequence,
                frame,
                last: length & TERMINATOR != 0,
            })
        }
        0 | 2 | 3 => Ok(ServerPacket::OtherCodec {
            kind,
            session: u32::try_from(non_negative(r.varint()?, "session")?).unwrap_or(u32::MAX),
        }),
        _ => Err(MumbleError::Malformed(format!(
            "voice packet of unknown type {kind}"
        ))),
    }
}

/// An Opus voice packet from us to the server (normal talking, target 0).
pub fn client_opus(sequence: u64, frame: &[u8], last: bool) -> Result<Vec<u8>, MumbleError> {
    if frame.len() > MAX_OPUS {
        return Err(MumbleError::Malformed(format!(
            "an Opus frame of {} bytes (at most {MAX_OPUS})",
            frame.len()
        )));
    }
    let mut out = Vec::with_capacity(frame.len() + 8);
    out.push(TYPE_OPUS << 5);
    write_varint(&mut out, sequence as i64);
    let mut length = frame.len() as u64;
    if last {
        length |= TERMINATOR;
    }
    write_varint(&mut out, length as i64);
    out.extend_from_slice(frame);
    Ok(out)
}

/// An Opus packet as the server forwards it (for tests and the fuzz seeds).
pub fn server_opus(session: u32, sequence: u64, frame: &[u8], last: bool) -> Vec<u8> {
    let mut out = vec![TYPE_OPUS << 5];
    write_varint(&mut out, i64::from(session));
    write_varint(&mut out, sequence as i64);
    let length = frame.len().min(MAX_OPUS) as u64 | if last { TERMINATOR } else { 0 };
    write_varint(&mut out, length as i64);
    out.extend_from_slice(&frame[..frame.len().min(MAX_OPUS)]);
    out
}

/// A UDP ping carrying `timestamp`.
pub fn ping(timestamp: u64) -> Vec<u8> {
    let mut out = vec![TYPE_PING << 5];
    write_varint(&mut out, timestamp as i64);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn round(v: i64) -> i64 {
        let mut out = Vec::new();
        write_varint(&mut out, v);
        let mut r = Reader::new(&out);
        let back = r.varint().unwrap();
        assert!(r.rest().is_empty());
        back
    }

    #[test]
    fn varints_take_mumbles_sizes() {
        for (v, len) in [
            (0i64, 1usize),
            (0x7f, 1),
            (0x80, 2),
            (0x3fff, 2),
            (0x4000, 3),
            (0x1f_ffff, 3),
            (0x20_0000, 4),
            (0x0fff_ffff, 4),
            (0x1000_0000, 5),
            (0xffff_ffff, 5),
            (0x1_0000_0000, 9),
            (-1, 1),
            (-4, 1),
            (-5, 2),
        ] {
            let mut out = Vec::new();
            write_varint(&mut out, v);
            assert_eq!(out.len(), len, "{v:#x}");
            assert_eq!(round(v), v);
        }
    }

    #[test]
    fn an_opus_packet_round_trips() {
        let p = server_opus(7, 1234, b"opusdata", true);
        assert_eq!(
            parse_server_packet(&p).unwrap(),
            ServerPacket::Opus {
                session: 7,
                sequence: 1234,
                frame: b"opusdata",
                last: true
            }
        );
        // The client's form is the server's without the session.
        let c = client_opus(1234, b"opusdata", false).unwrap();
        assert_eq!(c[0], 0x80);
        assert_eq!(
            parse_server_packet(&ping(99)).unwrap(),
            ServerPacket::Ping { timestamp: 99 }
        );
    }

    #[test]
    fn a_length_beyond_the_packet_is_an_error() {
        let mut p = server_opus(7, 1, b"abc", false);
        p.truncate(p.len() - 1);
        assert!(parse_server_packet(&p).is_err());
        assert!(parse_server_packet(&[]).is_err());
        assert!(parse_server_packet(&[0xe0]).is_err());
    }

    proptest! {
        #[test]
        fn varints_round_trip(v in any::<i64>()) {
            prop_assert_eq!(round(v), v);
        }

        #[test]
        fn any_bytes_parse_or_err(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
            let _ = parse_server_packet(&bytes);
            let mut r = Reader::new(&bytes);
            while r.varint().is_ok() {}
        }

        #[test]
        fn opus_packets_round_trip(session in any::<u32>(), sequence in 0u64..1 << 40,
                                   frame in proptest::collection::vec(any::<u8>(), 0..300), last in any::<bool>()) {
            let p = server_opus(session, sequence, &frame, last);
            prop_assert_eq!(parse_server_packet(&p).unwrap(),
                ServerPacket::Opus { session, sequence, frame: &frame, last });
        }
    }
}
