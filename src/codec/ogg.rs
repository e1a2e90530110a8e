//! What the Ogg Speex and Ogg Opus containers share: naming another codec's stream, sorting the
//! `ogg` crate's read errors, and the comment packet's layout (vendor string, then
//! `KEY=value` entries, each with a 32-bit little-endian length).

use ogg::reading::OggReadError;

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
