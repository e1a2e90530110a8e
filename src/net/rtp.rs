//! RTP packets (RFC 3550) with any payload: parsing through `rtp-types`, and the sender's
//! sequence/timestamp/marker state. What a payload type carries is the codec layer's business
//! ([`crate::codec::any::PayloadMap`]).

use rtp_types::{RtpPacket, RtpPacketBuilder};

use crate::codec::any::Codec;

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum RtpError {
    #[error("malformed RTP packet: {0}")]
    Malformed(String),
    #[error("unexpected RTP payload type {0}")]
    PayloadType(u8),
    #[error("empty RTP payload")]
    Empty,
    #[error("RTP packet does not fit: {0}")]
    Write(String),
}

/// The header fields the receiver uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RtpHeader {
    pub marker: bool,
    pub payload_type: u8,
    pub sequence: u16,
    pub timestamp: u32,
    pub ssrc: u32,
}

/// A parsed RTP packet borrowing its payload (padding and header extension removed).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rtp<'a> {
    pub header: RtpHeader,
    pub payload: &'a [u8],
}

/// Parses any RTP packet; `expect_pt` rejects other payload types.
pub fn parse(data: &[u8], expect_pt: Option<u8>) -> Result<Rtp<'_>, RtpError> {
    let packet = RtpPacket::parse(data).map_err(|e| RtpError::Malformed(e.to_string()))?;
    let header = RtpHeader {
        marker: packet.marker_bit(),
        payload_type: packet.payload_type(),
        sequence: packet.sequence_number(),
        timestamp: packet.timestamp(),
        ssrc: packet.ssrc(),
    };
    if let Some(pt) = expect_pt
        && pt != header.payload_type
    {
        return Err(RtpError::PayloadType(header.payload_type));
    }
    let start = packet.payload_offset();
    let end = start + packet.payload_len();
    let payload = data.get(start..end).ok_or(RtpError::Empty)?;
    if payload.is_empty() {
        return Err(RtpError::Empty);
    }
    Ok(Rtp { header, payload })
}

/// Writes a packet with a plain 12-byte header into `out` (cleared first).
pub fn write(header: &RtpHeader, payload: &[u8], out: &mut Vec<u8>) -> Result<(), RtpError> {
    out.clear();
    RtpPacketBuilder::<&[u8], &[u8]>::new()
        .marker_bit(header.marker)
        .payload_type(header.payload_type)
        .sequence_number(header.sequence)
        .timestamp(header.timestamp)
        .ssrc(header.ssrc)
        .payload(payload)
        .write_into_vec(out)
        .map_err(|e| RtpError::Write(e.to_string()))
}

/// The sender's side of one RTP stream: random SSRC, sequence and timestamp start.
#[derive(Debug, Clone)]
pub struct RtpStream {
    pub ssrc: u32,
    payload_type: u8,
    /// Timestamp ticks per 20 ms frame.
    frame_ticks: u32,
    sequence: u16,
    timestamp: u32,
    first_timestamp: u32,
    talking: bool,
    pub packets_sent: u32,
    pub octets_sent: u32,
}

impl RtpStream {
    /// A stream with random SSRC, first sequence number and first timestamp (RFC 3550 5.1).
    pub fn new_random() -> Result<Self, getrandom::Error> {
        let mut bytes = [0u8; 10];
        getrandom::fill(&mut bytes)?;
        let ssrc = u32::from_be_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
        let sequence = u16::from_be_bytes([bytes[4], bytes[5]]);
        let timestamp = u32::from_be_bytes([bytes[6], bytes[7], bytes[8], bytes[9]]);
        Ok(Self::new(ssrc, sequence, timestamp))
    }

    /// A stream of Speex (payload type 110, 8 kHz clock) until [`RtpStream::set_payload`].
    pub fn new(ssrc: u32, sequence: u16, timestamp: u32) -> Self {
        Self {
            ssrc,
            payload_type: Codec::Speex.default_payload_type(),
            frame_ticks: Codec::Speex.frame_ticks(),
            sequence,
            timestamp,
            first_timestamp: timestamp,
            talking: false,
            packets_sent: 0,
            octets_sent: 0,
        }
    }

    /// Sends `payload_type` from now on, on a clock of `frame_ticks` per 20 ms.
    pub fn set_payload(&mut self, payload_type: u8, frame_ticks: u32) {
        self.payload_type = payload_type;
        self.frame_ticks = frame_ticks;
    }

    pub fn payload_type(&self) -> u8 {
        self.payload_type
    }

    /// The timestamp the next packet will carry.
    pub fn next_timestamp(&self) -> u32 {
        self.timestamp
    }

    pub fn first_timestamp(&self) -> u32 {
        self.first_timestamp
    }

    /// Builds the next packet carrying `frames` 20 ms frames. The first packet of a talk spurt
    /// carries the marker bit.
    pub fn packetize(
        &mut self,
        payload: &[u8],
        frames: u32,
        out: &mut Vec<u8>,
    ) -> Result<RtpHeader, RtpError> {
        let ticks = self.frame_ticks.wrapping_mul(frames.max(1));
        self.packetize_ticks(payload, ticks, out)
    }

    /// Builds the next packet, lasting `ticks` of the RTP clock.
    pub fn packetize_ticks(
        &mut self,
        payload: &[u8],
        ticks: u32,
        out: &mut Vec<u8>,
    ) -> Result<RtpHeader, RtpError> {
        let header = RtpHeader {
            marker: !self.talking,
            payload_type: self.payload_type,
            sequence: self.sequence,
            timestamp: self.timestamp,
            ssrc: self.ssrc,
        };
        write(&header, payload, out)?;
        self.talking = true;
        self.sequence = self.sequence.wrapping_add(1);
        self.timestamp = self.timestamp.wrapping_add(ticks);
        self.packets_sent = self.packets_sent.wrapping_add(1);
        self.octets_sent = self.octets_sent.wrapping_add(payload.len() as u32);
        Ok(header)
    }

    /// Builds a packet of another payload type in this stream (an RFC 4733 event): it takes the
    /// stream's next sequence number (RFC 4733 2.1) and counts for its reports, at a
    /// `timestamp` of its own; the stream's timestamp and talk spurt stay as they are.
    pub fn packetize_other(
        &mut self,
        payload_type: u8,
        marker: bool,
        timestamp: u32,
        payload: &[u8],
        out: &mut Vec<u8>,
    ) -> Result<RtpHeader, RtpError> {
        let header = RtpHeader {
            marker,
            payload_type,
            sequence: self.sequence,
            timestamp,
            ssrc: self.ssrc,
        };
        write(&header, payload, out)?;
        self.sequence = self.sequence.wrapping_add(1);
        self.packets_sent = self.packets_sent.wrapping_add(1);
        self.octets_sent = self.octets_sent.wrapping_add(payload.len() as u32);
        Ok(header)
    }

    /// Skips `frames` frames of silence that are not sent (DTX, mute): the timestamp moves on
    /// and the next packet starts a new talk spurt.
    pub fn skip(&mut self, frames: u32) {
        self.timestamp = self
            .timestamp
            .wrapping_add(self.frame_ticks.wrapping_mul(frames));
        self.talking = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packets_round_trip_and_advance() {
        let mut s = RtpStream::new(0x1234_5678, 65535, u32::MAX - 100);
        let mut out = Vec::new();
        let h1 = s.packetize(&[1, 2, 3], 1, &mut out).unwrap();
        assert!(h1.marker);
        let p = parse(&out, Some(110)).unwrap();
        assert_eq!(p.header, h1);
        assert_eq!(p.payload, &[1, 2, 3]);
        let h2 = s.packetize(&[4], 2, &mut out).unwrap();
        assert!(!h2.marker);
        assert_eq!(h2.sequence, 0);
        assert_eq!(h2.timestamp, (u32::MAX - 100).wrapping_add(160));
        assert_eq!(s.next_timestamp(), h2.timestamp.wrapping_add(320));
        s.skip(3);
        assert!(s.packetize(&[5], 1, &mut out).unwrap().marker);
        // Opus: 960 ticks per frame, any duration.
        s.set_payload(96, 960);
        let before = s.next_timestamp();
        let h = s.packetize(&[6], 2, &mut out).unwrap();
        assert_eq!((h.payload_type, h.timestamp), (96, before));
        s.packetize_ticks(&[7], 480, &mut out).unwrap();
        assert_eq!(s.next_timestamp(), before.wrapping_add(1920 + 480));
    }

    #[test]
    fn bad_packets_are_errors() {
        assert!(parse(&[0x80, 110], None).is_err());
        let mut out = Vec::new();
        write(
            &RtpHeader {
                marker: false,
                payload_type: 0,
                sequence: 1,
                timestamp: 2,
                ssrc: 3,
            },
            &[9],
            &mut out,
        )
        .unwrap();
        assert_eq!(parse(&out, Some(110)), Err(RtpError::PayloadType(0)));
        assert_eq!(parse(&out[..12], None), Err(RtpError::Empty));
    }
}
