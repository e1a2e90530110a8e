//! Ogg Opus (.opus) files as RFC 7845 defines them and opusenc/opusdec write and read them: an
//! identification header (OpusHead) alone on the first page, a comment header (OpusTags), then
//! audio packets whose pages carry granule positions at 48 kHz, counting the pre-skip.

use std::io::Cursor;

use ogg::reading::{OggReadError, PacketReader};

pub use crate::codec::ogg::Page;
use crate::codec::ogg::{self as ogg_shared, ReadFault};

const HEAD_MAGIC: &[u8; 8] = b"OpusHead";
const TAGS_MAGIC: &[u8; 8] = b"OpusTags";
/// OpusHead with channel mapping family 0 (no mapping table).
const HEAD_SIZE: usize = 19;
/// More comments than this is no real file; the rest are ignored.
const MAX_COMMENTS: usize = 1024;

#[derive(Debug, thiserror::Error)]
pub enum OggOpusError {
    #[error("the file is empty")]
    Empty,
    #[error("not an Ogg file (no Ogg page at the start)")]
    NotOgg,
    #[error("the Ogg data is damaged or truncated: {0}")]
    Damaged(String),
    #[error("this Ogg file holds {0}, not Opus")]
    OtherCodec(&'static str),
    #[error("the OpusHead header is invalid: {0}")]
    BadHeader(&'static str),
    #[error("the OpusTags header is invalid: {0}")]
    BadTags(&'static str),
    #[error("Ogg Opus version {0} is not supported (only 0.x files are)")]
    Version(u8),
    #[error("the file ends before its last page: truncated")]
    Truncated,
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

/// The identification header (RFC 7845 5.1).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OpusHead {
    pub version: u8,
    pub channels: u8,
    /// Samples at 48 kHz to drop at the start of the decoded stream.
    pub pre_skip: u16,
    /// The rate of the encoder's input, for information only (0: unknown).
    pub input_rate: u32,
    /// Gain to apply on decoding, in 1/256 dB.
    pub output_gain: i16,
    pub mapping_family: u8,
    /// Opus streams in each packet (1 with family 0).
    pub streams: u8,
    /// Of those, the coupled (stereo) ones.
    pub coupled: u8,
    /// Decoded channel of each output channel (implied with family 0).
    pub mapping: Vec<u8>,
}

impl OpusHead {
    /// The header of a mono stream with mapping family 0, as lipcall writes it.
    pub fn mono(pre_skip: u16, input_rate: u32) -> Self {
        Self {
            version: 1,
            channels: 1,
            pre_skip,
            input_rate,
            output_gain: 0,
            mapping_family: 0,
            streams: 1,
            coupled: 0,
            mapping: vec![0],
        }
    }

    pub fn to_packet(&self) -> Vec<u8> {
        let mut p = Vec::with_capacity(HEAD_SIZE + 2 + self.mapping.len());
        p.extend_from_slice(HEAD_MAGIC);
        p.push(self.version);
        p.push(self.channels);
        p.extend_from_slice(&self.pre_skip.to_le_bytes());
        p.extend_from_slice(&self.input_rate.to_le_bytes());
        p.extend_from_slice(&self.output_gain.to_le_bytes());
        p.push(self.mapping_family);
        if self.mapping_family != 0 {
            p.push(self.streams);
            p.push(self.coupled);
            p.extend_from_slice(&self.mapping);
        }
        p
    }

    /// Parses and checks an OpusHead packet. Longer packets are accepted (RFC 7845 5.1: later
    /// minor versions may append fields).
    pub fn from_packet(p: &[u8]) -> Result<Self, OggOpusError> {
        if !p.starts_with(HEAD_MAGIC) {
            return Err(OggOpusError::BadHeader("no OpusHead magic"));
        }
        if p.len() < HEAD_SIZE {
            return Err(OggOpusError::BadHeader("shorter than 19 bytes"));
        }
        let version = p[8];
        // The high nibble is the major version: a change there is incompatible.
        if version & 0xf0 != 0 {
            return Err(OggOpusError::Version(version));
        }
        let channels = p[9];
        if channels == 0 {
            return Err(OggOpusError::BadHeader("channel count 0"));
        }
        let pre_skip = u16::from_le_bytes([p[10], p[11]]);
        let input_rate = u32::from_le_bytes([p[12], p[13], p[14], p[15]]);
        let output_gain = i16::from_le_bytes([p[16], p[17]]);
        let mapping_family = p[18];
        let (streams, coupled, mapping) = if mapping_family == 0 {
            if channels > 2 {
                return Err(OggOpusError::BadHeader(
                    "mapping family 0 allows only 1 or 2 channels",
                ));
            }
            (1, channels - 1, (0..channels).collect())
        } else {
            if mapping_family == 1 && channels > 8 {
                return Err(OggOpusError::BadHeader(
                    "mapping family 1 allows at most 8 channels",
                ));
            }
            let table = p
                .get(HEAD_SIZE + 2..HEAD_SIZE + 2 + usize::from(channels))
                .ok_or(OggOpusError::BadHeader(
                    "the channel mapping table is cut short",
                ))?;
            let (streams, coupled) = (p[HEAD_SIZE], p[HEAD_SIZE + 1]);
            if streams == 0 {
                return Err(OggOpusError::BadHeader("stream count 0"));
            }
            if coupled > streams {
                return Err(OggOpusError::BadHeader("more coupled streams than streams"));
            }
            let decoded = u16::from(streams) + u16::from(coupled);
            if decoded > 255 {
                return Err(OggOpusError::BadHeader("more than 255 decoded channels"));
            }
            if table.iter().any(|&c| c != 255 && u16::from(c) >= decoded) {
                return Err(OggOpusError::BadHeader(
                    "the channel mapping names a channel no stream decodes",
                ));
            }
            (streams, coupled, table.to_vec())
        };
        Ok(Self {
            version,
            channels,
            pre_skip,
            input_rate,
            output_gain,
            mapping_family,
            streams,
            coupled,
            mapping,
        })
    }
}

/// A whole Ogg Opus stream as read from a file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OpusFile {
    pub head: OpusHead,
    pub vendor: String,
    pub comments: Vec<String>,
    /// Audio pages in order; the two header packets are not included.
    pub pages: Vec<Page>,
}

impl OpusFile {
    pub fn audio_packet_count(&self) -> usize {
        self.pages.iter().map(|p| p.packets.len()).sum()
    }
}

/// Whether a beginning-of-stream page at the start of `bytes` opens an Opus stream (every
/// stream of an Ogg file begins before any data page, RFC 3533 4).
pub fn holds_opus(bytes: &[u8]) -> bool {
    let mut at = 0usize;
    while let Some(header) = bytes.get(at..at + 27) {
        let is_bos = header[5] & 0x02 != 0;
        if &header[..4] != b"OggS" || !is_bos {
            return false;
        }
        let segments = usize::from(header[26]);
        let Some(lacing) = bytes.get(at + 27..at + 27 + segments) else {
            return false;
        };
        let body = at + 27 + segments;
        if bytes.get(body..).is_some_and(|b| b.starts_with(HEAD_MAGIC)) {
            return true;
        }
        at = body + lacing.iter().map(|&l| usize::from(l)).sum::<usize>();
    }
    false
}

fn classify_foreign(first: &[u8]) -> OggOpusError {
    OggOpusError::OtherCodec(ogg_shared::stream_codec(first))
}

fn map_ogg_error(e: OggReadError) -> OggOpusError {
    match ReadFault::from(e) {
        ReadFault::NotOgg => OggOpusError::NotOgg,
        ReadFault::Truncated => OggOpusError::Truncated,
        ReadFault::Damaged(why) => OggOpusError::Damaged(why),
    }
}

fn read_u32(p: &[u8], at: usize) -> Option<usize> {
    let b = p.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
}

/// A length-prefixed string at `*at`, moving `*at` past it.
fn read_field<'a>(p: &'a [u8], at: &mut usize) -> Option<&'a [u8]> {
    let len = read_u32(p, *at)?;
    let text = p.get(*at + 4..)?.get(..len)?;
    *at += 4 + len;
    Some(text)
}

/// Parses OpusTags (RFC 7845 5.2): the vendor string and `KEY=value` comments. Every length
/// is checked against the packet, so no claim can make it read or allocate past it.
fn parse_tags(p: &[u8]) -> Result<(String, Vec<String>), OggOpusError> {
    if !p.starts_with(TAGS_MAGIC) {
        return Err(OggOpusError::BadTags("no OpusTags magic"));
    }
    let mut at = TAGS_MAGIC.len();
    let vendor = read_field(p, &mut at).ok_or(OggOpusError::BadTags(
        "the vendor string runs past the packet",
    ))?;
    let vendor = String::from_utf8_lossy(vendor).into_owned();
    let count = read_u32(p, at).ok_or(OggOpusError::BadTags("no comment count"))?;
    at += 4;
    // Each comment takes at least its 4-byte length.
    if count > (p.len() - at) / 4 {
        return Err(OggOpusError::BadTags(
            "more comments claimed than the packet holds",
        ));
    }
    let mut comments = Vec::with_capacity(count.min(MAX_COMMENTS));
    for _ in 0..count {
        let c = read_field(p, &mut at)
            .ok_or(OggOpusError::BadTags("a comment runs past the packet"))?;
        if comments.len() < MAX_COMMENTS {
            comments.push(String::from_utf8_lossy(c).into_owned());
        }
    }
    Ok((vendor, comments))
}

fn tags_packet(vendor: &str, comments: &[String]) -> Vec<u8> {
    ogg_shared::comment_packet(TAGS_MAGIC, vendor, comments)
}

/// Reads the first Ogg Opus stream of a file (the first link of a chain). Other logical
/// streams are ignored.
pub fn read(bytes: &[u8]) -> Result<OpusFile, OggOpusError> {
    let mut links = read_chain(bytes)?;
    Ok(links.swap_remove(0))
}

/// One link of a chain as it is read.
#[derive(Default)]
struct LinkReader {
    serial: Option<u32>,
    head: Option<OpusHead>,
    tags: Option<(String, Vec<String>)>,
    pages: Vec<Page>,
    ended: bool,
}

impl LinkReader {
    fn starting(serial: u32) -> Self {
        Self {
            serial: Some(serial),
            ..Self::default()
        }
    }

    fn take(&mut self, packet: ogg::Packet) -> Result<(), OggOpusError> {
        self.ended = packet.last_in_stream();
        if self.head.is_none() {
            if !(packet.first_in_page() && packet.last_in_page()) {
                return Err(OggOpusError::BadHeader(
                    "it shares its page with other data",
                ));
            }
            self.head = Some(OpusHead::from_packet(&packet.data)?);
        } else if self.tags.is_none() {
            self.tags = Some(parse_tags(&packet.data)?);
        } else {
            ogg_shared::push_audio_packet(&mut self.pages, packet);
        }
        Ok(())
    }

    fn finish(self) -> Result<OpusFile, OggOpusError> {
        let head = self.head.ok_or(OggOpusError::Truncated)?;
        let Some((vendor, comments)) = self.tags else {
            return Err(if self.ended {
                OggOpusError::BadTags("the stream ends before its OpusTags packet")
            } else {
                OggOpusError::Truncated
            });
        };
        if !self.ended {
            return Err(OggOpusError::Truncated);
        }
        Ok(OpusFile {
            head,
            vendor,
            comments,
            pages: self.pages,
        })
    }
}

/// Reads every link of a chained Ogg Opus file (RFC 7845 3: streams one after another, as
/// concatenated files are, each with its own headers), in order; at least one. Other logical
/// streams grouped with a link are ignored.
pub fn read_chain(bytes: &[u8]) -> Result<Vec<OpusFile>, OggOpusError> {
    if bytes.is_empty() {
        return Err(OggOpusError::Empty);
    }
    if !bytes.starts_with(b"OggS") {
        return Err(OggOpusError::NotOgg);
    }
    let mut reader = PacketReader::new(Cursor::new(bytes));
    let mut links = Vec::new();
    let mut link = LinkReader::default();
    let mut foreign = None;
    while let Some(packet) = reader.read_packet().map_err(map_ogg_error)? {
        if packet.first_in_stream() {
            if packet.data.starts_with(HEAD_MAGIC) {
                if link.serial.is_none() {
                    link = LinkReader::starting(packet.stream_serial());
                } else if link.ended {
                    let done =
                        std::mem::replace(&mut link, LinkReader::starting(packet.stream_serial()));
                    links.push(done.finish()?);
                }
            } else if foreign.is_none() && link.serial.is_none() {
                foreign = Some(classify_foreign(&packet.data));
            }
        }
        if link.ended || link.serial != Some(packet.stream_serial()) {
            continue;
        }
        link.take(packet)?;
    }
    if link.serial.is_none() {
        return Err(foreign.unwrap_or(OggOpusError::OtherCodec("no Opus stream")));
    }
    links.push(link.finish()?);
    Ok(links)
}

/// Builds an Ogg Opus file from audio packets. `granule_of(i)` is the granule position after
/// packet `i` (48 kHz, counting the pre-skip); only the last may stop short of the decoded
/// length (end trimming, RFC 7845 4.4). Pages hold one second of 20 ms packets.
pub fn write(
    head: &OpusHead,
    vendor: &str,
    comments: &[String],
    packets: &[Vec<u8>],
    granule_of: impl Fn(usize) -> u64,
    serial: u32,
) -> Result<Vec<u8>, OggOpusError> {
    Ok(ogg_shared::write_stream(
        head.to_packet(),
        tags_packet(vendor, comments),
        packets,
        granule_of,
        serial,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_file(packets: usize) -> Vec<u8> {
        let head = OpusHead::mono(312, 8000);
        let packets: Vec<Vec<u8>> = (0..packets).map(|i| vec![0x08, i as u8, 7]).collect();
        write(
            &head,
            "test vendor",
            &["ENCODER=test".into()],
            &packets,
            |i| (i as u64 + 1) * 960,
            7,
        )
        .unwrap()
    }

    #[test]
    fn header_round_trips_and_has_the_rfc_layout() {
        let h = OpusHead::mono(312, 8000);
        let p = h.to_packet();
        assert_eq!(p.len(), 19);
        assert_eq!(&p[8..12], &[1, 1, 0x38, 0x01]);
        assert_eq!(OpusHead::from_packet(&p).unwrap(), h);
        let family1 = OpusHead {
            channels: 2,
            mapping_family: 1,
            streams: 1,
            coupled: 1,
            mapping: vec![0, 1],
            ..h
        };
        let p = family1.to_packet();
        assert_eq!(p.len(), 23);
        assert_eq!(OpusHead::from_packet(&p).unwrap(), family1);
    }

    #[test]
    fn malformed_headers_are_refused_by_name() {
        let good = OpusHead::mono(312, 8000).to_packet();
        let with = |at: usize, v: u8| {
            let mut p = good.clone();
            p[at] = v;
            OpusHead::from_packet(&p).unwrap_err().to_string()
        };
        assert!(with(0, b'X').contains("magic"));
        assert!(with(8, 0x10).contains("version 16"));
        assert!(with(9, 0).contains("channel count 0"));
        assert!(with(9, 3).contains("1 or 2 channels"));
        // Family 1 without its mapping table.
        assert!(with(18, 1).contains("cut short"));
        assert!(
            OpusHead::from_packet(&good[..18])
                .unwrap_err()
                .to_string()
                .contains("19")
        );
        // Minor versions with extra bytes are fine.
        let mut longer = good.clone();
        longer[8] = 15;
        longer.extend_from_slice(&[1, 2, 3]);
        assert_eq!(OpusHead::from_packet(&longer).unwrap().version, 15);
        let mut bad_map = OpusHead {
            channels: 2,
            mapping_family: 1,
            streams: 1,
            coupled: 0,
            mapping: vec![0, 1],
            ..OpusHead::mono(0, 0)
        }
        .to_packet();
        assert!(
            OpusHead::from_packet(&bad_map)
                .unwrap_err()
                .to_string()
                .contains("no stream decodes")
        );
        bad_map[20] = 2;
        assert!(
            OpusHead::from_packet(&bad_map)
                .unwrap_err()
                .to_string()
                .contains("more coupled")
        );
    }

    #[test]
    fn tags_claims_are_checked_against_the_packet() {
        let p = tags_packet("v", &["A=1".into(), "B=2".into()]);
        assert_eq!(
            parse_tags(&p).unwrap(),
            ("v".to_string(), vec!["A=1".to_string(), "B=2".to_string()])
        );
        let mut huge_vendor = p.clone();
        huge_vendor[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(parse_tags(&huge_vendor).is_err());
        let mut huge_count = p.clone();
        huge_count[13..17].copy_from_slice(&0x4000_0000u32.to_le_bytes());
        assert!(parse_tags(&huge_count).is_err());
        assert!(parse_tags(&p[..p.len() - 1]).is_err());
        assert!(parse_tags(b"OpusHead").is_err());
    }

    #[test]
    fn file_round_trips_pages_and_granules() {
        let bytes = sample_file(120);
        assert!(holds_opus(&bytes));
        let f = read(&bytes).unwrap();
        assert_eq!(f.head, OpusHead::mono(312, 8000));
        assert_eq!(f.vendor, "test vendor");
        assert_eq!(f.comments, vec!["ENCODER=test".to_string()]);
        assert_eq!(f.audio_packet_count(), 120);
        assert_eq!(f.pages.len(), 3);
        assert_eq!(f.pages[0].granule, Some(50 * 960));
        assert!(f.pages[2].end_of_stream);
        assert_eq!(f.pages[1].packets[0], vec![0x08, 50, 7]);
    }

    #[test]
    fn truncation_and_garbage_are_errors() {
        let bytes = sample_file(60);
        assert!(matches!(
            read(&bytes[..bytes.len() - 7]),
            Err(OggOpusError::Truncated)
        ));
        assert!(matches!(read(b""), Err(OggOpusError::Empty)));
        assert!(matches!(read(b"RIFF....WAVE"), Err(OggOpusError::NotOgg)));
        assert!(!holds_opus(b"RIFF....WAVE"));
        assert!(!holds_opus(&bytes[..30]));
        // Every prefix is an error or a file, never a panic.
        for cut in 0..bytes.len() {
            let _ = read(&bytes[..cut]);
            let _ = holds_opus(&bytes[..cut]);
        }
    }
}
