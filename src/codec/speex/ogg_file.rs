//! Ogg Speex (.spx) files as speexenc writes and speexdec reads them: an 80-byte header packet,
//! a Vorbis-style comment packet, then audio packets with granule positions in samples.

use std::io::Cursor;

use ogg::reading::{OggReadError, PacketReader};

pub use crate::codec::ogg::Page;
use crate::codec::ogg::{self as ogg_shared, ReadFault};
use crate::vocab::{FRAME_SIZE, SAMPLE_RATE};

const MAGIC: &[u8; 8] = b"Speex   ";
const HEADER_SIZE: usize = 80;
/// The narrowband mode's bitstream version in libspeex 1.2.
const NB_BITSTREAM_VERSION: i32 = 4;
/// More frames than this in one packet is no real file, only a way to make the decoder spin.
pub const MAX_FRAMES_PER_PACKET: usize = 64;

#[derive(Debug, thiserror::Error)]
pub enum OggSpeexError {
    #[error("the file is empty")]
    Empty,
    #[error("not an Ogg file (no Ogg page at the start)")]
    NotOgg,
    #[error("the Ogg data is damaged or truncated: {0}")]
    Damaged(String),
    #[error("this Ogg file holds {0}, not Speex")]
    OtherCodec(&'static str),
    #[error("the Speex header is invalid: {0}")]
    BadHeader(&'static str),
    #[error("{0} Speex is not supported: lipcall decodes narrowband (8 kHz) only")]
    NotNarrowband(&'static str),
    #[error("the file ends before its last page: truncated")]
    Truncated,
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

/// The fields of the Speex header packet that matter to a narrowband decoder.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SpeexHeader {
    pub version: String,
    pub rate: u32,
    pub channels: u32,
    pub bitrate: i32,
    pub vbr: bool,
    pub frames_per_packet: usize,
    pub extra_headers: usize,
}

impl SpeexHeader {
    pub fn narrowband(vbr: bool, frames_per_packet: usize) -> Self {
        Self {
            version: "1.2.1".into(),
            rate: SAMPLE_RATE,
            channels: 1,
            bitrate: -1,
            vbr,
            frames_per_packet,
            extra_headers: 0,
        }
    }

    pub fn to_packet(&self) -> Vec<u8> {
        let mut p = Vec::with_capacity(HEADER_SIZE);
        p.extend_from_slice(MAGIC);
        let mut version = [0u8; 20];
        let v = self.version.as_bytes();
        let n = v.len().min(19);
        version[..n].copy_from_slice(&v[..n]);
        p.extend_from_slice(&version);
        let fields: [i32; 13] = [
            1,
            HEADER_SIZE as i32,
            self.rate as i32,
            0,
            NB_BITSTREAM_VERSION,
            self.channels as i32,
            self.bitrate,
            FRAME_SIZE as i32,
            i32::from(self.vbr),
            self.frames_per_packet as i32,
            self.extra_headers as i32,
            0,
            0,
        ];
        for f in fields {
            p.extend_from_slice(&f.to_le_bytes());
        }
        p
    }

    pub fn from_packet(p: &[u8]) -> Result<Self, OggSpeexError> {
        if p.len() < HEADER_SIZE || &p[..8] != MAGIC {
            return Err(OggSpeexError::BadHeader("too short or wrong magic"));
        }
        let field = |i: usize| {
            let at = 28 + 4 * i;
            i32::from_le_bytes([p[at], p[at + 1], p[at + 2], p[at + 3]])
        };
        let version_end = p[8..28].iter().position(|&b| b == 0).unwrap_or(20);
        let version = String::from_utf8_lossy(&p[8..8 + version_end]).into_owned();
        if field(0) > 1 {
            return Err(OggSpeexError::BadHeader("unknown Speex bitstream version"));
        }
        match field(3) {
            0 => {}
            1 => return Err(OggSpeexError::NotNarrowband("wideband")),
            2 => return Err(OggSpeexError::NotNarrowband("ultra-wideband")),
            _ => return Err(OggSpeexError::BadHeader("unknown mode")),
        }
        if field(4) != NB_BITSTREAM_VERSION {
            return Err(OggSpeexError::BadHeader(
                "encoded with an incompatible Speex version",
            ));
        }
        let rate = u32::try_from(field(2))
            .ok()
            .filter(|r| (1000..=192_000).contains(r))
            .ok_or(OggSpeexError::BadHeader("sample rate out of range"))?;
        let frames_per_packet = match usize::try_from(field(9)) {
            Ok(0) => 1,
            Ok(n) if n <= MAX_FRAMES_PER_PACKET => n,
            _ => return Err(OggSpeexError::BadHeader("frames per packet out of range")),
        };
        let extra_headers = usize::try_from(field(10))
            .ok()
            .filter(|&n| n <= 16)
            .ok_or(OggSpeexError::BadHeader("extra header count out of range"))?;
        Ok(Self {
            version,
            rate,
            channels: u32::try_from(field(5)).unwrap_or(1).max(1),
            bitrate: field(6),
            vbr: field(8) != 0,
            frames_per_packet,
            extra_headers,
        })
    }
}

/// A whole Ogg Speex stream as read from a file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SpeexFile {
    pub header: SpeexHeader,
    pub vendor: String,
    pub comments: Vec<String>,
    /// Audio pages in order; header, comment and extra-header packets are not included.
    pub pages: Vec<Page>,
}

impl SpeexFile {
    pub fn audio_packet_count(&self) -> usize {
        self.pages.iter().map(|p| p.packets.len()).sum()
    }
}

fn classify_foreign(first: &[u8]) -> OggSpeexError {
    OggSpeexError::OtherCodec(ogg_shared::stream_codec(first))
}

fn map_ogg_error(e: OggReadError) -> OggSpeexError {
    match ReadFault::from(e) {
        ReadFault::NotOgg => OggSpeexError::NotOgg,
        ReadFault::Truncated => OggSpeexError::Truncated,
        ReadFault::Damaged(why) => OggSpeexError::Damaged(why),
    }
}

/// Parses comment packet text: vendor string and `KEY=value` entries.
fn parse_comments(p: &[u8]) -> (String, Vec<String>) {
    let read_u32 = |at: usize| -> Option<usize> {
        let b = p.get(at..at + 4)?;
        Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
    };
    let text = |at: usize, len: usize| -> Option<String> {
        let end = at.checked_add(len)?;
        Some(String::from_utf8_lossy(p.get(at..end)?).into_owned())
    };
    let Some(vendor_len) = read_u32(0) else {
        return (String::new(), Vec::new());
    };
    let vendor = text(4, vendor_len).unwrap_or_default();
    let mut comments = Vec::new();
    let mut at = 4 + vendor_len;
    if let Some(count) = read_u32(at) {
        at += 4;
        for _ in 0..count.min(1024) {
            let Some(len) = read_u32(at) else { break };
            let Some(c) = text(at + 4, len) else { break };
            comments.push(c);
            at += 4 + len;
        }
    }
    (vendor, comments)
}

/// Reads an Ogg Speex stream. Other logical streams in the file are ignored.
pub fn read(bytes: &[u8]) -> Result<SpeexFile, OggSpeexError> {
    if bytes.is_empty() {
        return Err(OggSpeexError::Empty);
    }
    if bytes.len() < 4 || &bytes[..4] != b"OggS" {
        return Err(OggSpeexError::NotOgg);
    }
    let mut reader = PacketReader::new(Cursor::new(bytes));
    let mut serial = None;
    let mut foreign = None;
    let mut header = None;
    let mut vendor = String::new();
    let mut comments = Vec::new();
    let mut headers_seen = 0usize;
    let mut pages: Vec<Page> = Vec::new();
    let mut ended = false;
    while let Some(packet) = reader.read_packet().map_err(map_ogg_error)? {
        if serial.is_none() && packet.first_in_stream() {
            if packet.data.starts_with(MAGIC) {
                serial = Some(packet.stream_serial());
            } else if foreign.is_none() {
                foreign = Some(classify_foreign(&packet.data));
            }
        }
        if ended || serial != Some(packet.stream_serial()) {
            continue;
        }
        if headers_seen < 2 && packet.last_in_stream() {
            ended = true;
        }
        match headers_seen {
            0 => header = Some(SpeexHeader::from_packet(&packet.data)?),
            1 => (vendor, comments) = parse_comments(&packet.data),
            n if n <= 1 + header.as_ref().map_or(0, |h| h.extra_headers) => {}
            _ => {
                ended = packet.last_in_stream();
                ogg_shared::push_audio_packet(&mut pages, packet);
            }
        }
        headers_seen += 1;
    }
    let Some(header) = header else {
        return Err(foreign.unwrap_or(OggSpeexError::OtherCodec("no Speex stream")));
    };
    if !ended {
        return Err(OggSpeexError::Truncated);
    }
    Ok(SpeexFile {
        header,
        vendor,
        comments,
        pages,
    })
}

/// Builds an Ogg Speex file from audio packets. `granule_of(i)` is the granule position after
/// packet `i`; pages of about one second, as speexenc's libogg pages roughly are.
pub fn write(
    header: &SpeexHeader,
    comments: &[String],
    packets: &[Vec<u8>],
    granule_of: impl Fn(usize) -> u64,
    serial: u32,
) -> Result<Vec<u8>, OggSpeexError> {
    let vendor = format!("lipcall {}", env!("CARGO_PKG_VERSION"));
    Ok(ogg_shared::write_stream(
        header.to_packet(),
        ogg_shared::comment_packet(b"", &vendor, comments),
        packets,
        granule_of,
        serial,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trips() {
        let h = SpeexHeader::narrowband(true, 3);
        let p = h.to_packet();
        assert_eq!(p.len(), 80);
        assert_eq!(SpeexHeader::from_packet(&p).unwrap(), h);
    }

    #[test]
    fn wideband_headers_are_refused_by_name() {
        let mut p = SpeexHeader::narrowband(false, 1).to_packet();
        p[40] = 1;
        assert!(matches!(
            SpeexHeader::from_packet(&p),
            Err(OggSpeexError::NotNarrowband("wideband"))
        ));
    }

    #[test]
    fn file_round_trips_pages_and_granules() {
        let h = SpeexHeader::narrowband(false, 1);
        let packets: Vec<Vec<u8>> = (0..120u8).map(|i| vec![i; 20]).collect();
        let bytes = write(
            &h,
            &["ENCODER=test".into()],
            &packets,
            |i| (i as u64 + 1) * 160 - 40,
            7,
        )
        .unwrap();
        let f = read(&bytes).unwrap();
        assert_eq!(f.header, h);
        assert_eq!(f.comments, vec!["ENCODER=test".to_string()]);
        assert_eq!(f.audio_packet_count(), 120);
        assert_eq!(f.pages.len(), 3);
        assert_eq!(f.pages[0].granule, Some(50 * 160 - 40));
        assert!(f.pages[2].end_of_stream);
        assert_eq!(f.pages[1].packets[0], vec![50u8; 20]);
    }

    #[test]
    fn truncation_and_garbage_are_errors() {
        let h = SpeexHeader::narrowband(false, 1);
        let packets: Vec<Vec<u8>> = (0..60u8).map(|i| vec![i; 20]).collect();
        let bytes = write(&h, &[], &packets, |i| i as u64 * 160, 1).unwrap();
        assert!(matches!(
            read(&bytes[..bytes.len() - 7]),
            Err(OggSpeexError::Truncated)
        ));
        assert!(matches!(read(b""), Err(OggSpeexError::Empty)));
        assert!(matches!(read(b"RIFF....WAVE"), Err(OggSpeexError::NotOgg)));
    }
}
