//! What the Ogg Speex and Ogg Opus containers share: naming another codec's stream, sorting the
//! `ogg` crate's read errors, audio pages as read, the comment packet's layout and the writing of a stream (vendor string, then
//! `KEY=value` entries, each with a 32-bit little-endian length).

use ogg::reading::OggReadError;
use ogg::writing::{PacketWriteEndInfo, PacketWriter};

/// The codec of a logical stream, told by its first packet's magic.
pub fn stream_codec(first_packet: &[u8]) -> &'static str {
    const MAGICS: [(&[u8], &str); 5] = [
        (b"\x01vorbis", "Vorbis"),
        (b"OpusHead", "Opus"),
        (b"Speex   ", "Speex"),
        (b"\x7fFLAC", "FLAC"),
        (b"\x80theora", "Theora"),
    ];
    MAGICS
        .iter()
        .find(|(magic, _)| first_packet.starts_with(magic))
        .map_or("an unknown stream", |&(_, name)| name)
}

/// Why the `ogg` crate could not read on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ReadFault {
    /// No Ogg capture pattern: not an Ogg file.
    NotOgg,
    /// The file ends inside a page.
    Truncated,
    Damaged(String),
}

impl From<OggReadError> for ReadFault {
    fn from(e: OggReadError) -> Self {
        match e {
            OggReadError::NoCapturePatternFound => ReadFault::NotOgg,
            OggReadError::ReadError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
                ReadFault::Truncated
            }
            other => ReadFault::Damaged(other.to_string()),
        }
    }
}

/// One Ogg page of a logical stream, with the audio packets that end on it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Page {
    /// The page's granule position, in the codec's unit (Speex: samples; Opus: 48 kHz samples
    /// counting the pre-skip), at the end of its last packet; `None` where it is -1 (no packet
    /// ends here).
    pub granule: Option<u64>,
    pub end_of_stream: bool,
    pub packets: Vec<Vec<u8>>,
}

/// Adds an audio packet to `pages`, opening a new page where the packet starts one.
pub fn push_audio_packet(pages: &mut Vec<Page>, packet: ogg::Packet) {
    if packet.first_in_page() || pages.is_empty() {
        pages.push(Page {
            granule: (packet.absgp_page() != u64::MAX).then_some(packet.absgp_page()),
            end_of_stream: false,
            packets: Vec::new(),
        });
    }
    if let Some(page) = pages.last_mut() {
        page.end_of_stream |= packet.last_in_stream();
        page.packets.push(packet.data);
    }
}

/// Audio packets per page when writing: one second of 20 ms packets (speexenc's libogg pages
/// and opusenc's default page delay come to about that).
const PACKETS_PER_PAGE: usize = 50;

/// A logical stream as Speex and Opus files lay it out: the identification header alone on the
/// first page, the comment packet on the second, then the audio packets, `granule_of(i)` being
/// the granule position after packet `i`.
pub fn write_stream(
    header: Vec<u8>,
    comments: Vec<u8>,
    packets: &[Vec<u8>],
    granule_of: impl Fn(usize) -> u64,
    serial: u32,
) -> std::io::Result<Vec<u8>> {
    let mut writer = PacketWriter::new(Vec::new());
    writer.write_packet(header, serial, PacketWriteEndInfo::EndPage, 0)?;
    let end = if packets.is_empty() {
        PacketWriteEndInfo::EndStream
    } else {
        PacketWriteEndInfo::EndPage
    };
    writer.write_packet(comments, serial, end, 0)?;
    for (i, p) in packets.iter().enumerate() {
        let info = if i + 1 == packets.len() {
            PacketWriteEndInfo::EndStream
        } else if (i + 1) % PACKETS_PER_PAGE == 0 {
            PacketWriteEndInfo::EndPage
        } else {
            PacketWriteEndInfo::NormalPacket
        };
        writer.write_packet(p.clone(), serial, info, granule_of(i))?;
    }
    Ok(writer.into_inner())
}

/// A comment packet: `magic` (empty for Speex, `OpusTags` for Opus), the vendor string and the
/// comments.
pub fn comment_packet(magic: &[u8], vendor: &str, comments: &[String]) -> Vec<u8> {
    let field = |p: &mut Vec<u8>, text: &str| {
        p.extend_from_slice(&(text.len() as u32).to_le_bytes());
        p.extend_from_slice(text.as_bytes());
    };
    let mut p = magic.to_vec();
    field(&mut p, vendor);
    p.extend_from_slice(&(comments.len() as u32).to_le_bytes());
    for c in comments {
        field(&mut p, c);
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_are_told_by_their_magic() {
        assert_eq!(stream_codec(b"OpusHead\x01"), "Opus");
        assert_eq!(stream_codec(b"Speex   1.2"), "Speex");
        assert_eq!(stream_codec(b"\x01vorbis"), "Vorbis");
        assert_eq!(stream_codec(b"Opus"), "an unknown stream");
        assert_eq!(stream_codec(b""), "an unknown stream");
    }

    #[test]
    fn comment_packets_lay_out_lengths_before_text() {
        let p = comment_packet(b"M", "v", &["A=1".into(), "BB=2".into()]);
        let mut expected = b"M".to_vec();
        expected.extend_from_slice(&[1, 0, 0, 0, b'v', 2, 0, 0, 0]);
        expected.extend_from_slice(&[3, 0, 0, 0, b'A', b'=', b'1']);
        expected.extend_from_slice(&[4, 0, 0, 0, b'B', b'B', b'=', b'2']);
        assert_eq!(p, expected);
        assert_eq!(comment_packet(b"", "", &[]), vec![0; 8]);
    }
}
