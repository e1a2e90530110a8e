//! The Opus packet: the TOC byte (RFC 6716 3.1) and the frame packing codes 0-3 (3.2),
//! with every requirement of 3.4 checked.

/// Largest Opus frame in bytes ([R2]).
pub const MAX_FRAME_BYTES: usize = 1275;
/// Most frames one packet may hold (120 ms of 2.5 ms frames).
pub const MAX_FRAMES: usize = 48;
/// Longest packet, in 48 kHz samples ([R5]: 120 ms).
const MAX_PACKET_SAMPLES_48K: u32 = 5760;

/// Which layers code a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Mode {
    /// SILK only (linear prediction, NB/MB/WB).
    Silk,
    /// SILK up to 8 kHz plus CELT above (SWB/FB).
    Hybrid,
    /// CELT only (MDCT): no linear prediction, so no NLSFs.
    Celt,
}

/// The audio bandwidth the TOC byte announces.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Bandwidth {
    /// 4 kHz (8 kHz sampling).
    Narrow,
    /// 6 kHz (12 kHz sampling).
    Medium,
    /// 8 kHz (16 kHz sampling).
    Wide,
    /// 12 kHz (24 kHz sampling).
    SuperWide,
    /// 20 kHz (48 kHz sampling).
    Full,
}

/// The table-of-contents byte that starts every packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Toc {
    /// Configuration number 0..=31 (RFC 6716 Table 2).
    pub config: u8,
    pub stereo: bool,
    /// Frame packing code 0..=3.
    pub code: u8,
}

impl Toc {
    pub fn from_byte(byte: u8) -> Self {
        Self {
            config: byte >> 3,
            stereo: byte & 0x04 != 0,
            code: byte & 0x03,
        }
    }

    pub fn mode(&self) -> Mode {
        match self.config {
            0..=11 => Mode::Silk,
            12..=15 => Mode::Hybrid,
            _ => Mode::Celt,
        }
    }

    pub fn bandwidth(&self) -> Bandwidth {
        match self.config {
            0..=3 => Bandwidth::Narrow,
            4..=7 => Bandwidth::Medium,
            8..=11 => Bandwidth::Wide,
            12..=13 => Bandwidth::SuperWide,
            14..=15 => Bandwidth::Full,
            16..=19 => Bandwidth::Narrow,
            20..=23 => Bandwidth::Wide,
            24..=27 => Bandwidth::SuperWide,
            _ => Bandwidth::Full,
        }
    }

    /// Duration of each frame in 48 kHz samples (120 = 2.5 ms ... 2880 = 60 ms).
    pub fn frame_samples_48k(&self) -> u32 {
        let size_index = u32::from(self.config & 0x03);
        match self.mode() {
            // 10, 20, 40, 60 ms
            Mode::Silk => [480, 960, 1920, 2880][size_index as usize],
            // 10, 20 ms
            Mode::Hybrid => 480 << (size_index & 1),
            // 2.5, 5, 10, 20 ms
            Mode::Celt => 120 << size_index,
        }
    }

    /// Duration of each frame in milliseconds, rounded down (2.5 ms gives 2).
    pub fn frame_ms(&self) -> u32 {
        self.frame_samples_48k() / 48
    }
}

/// Why a packet breaks RFC 6716 3.4 (the requirement's tag in brackets).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PacketError {
    #[error("empty packet [R1]")]
    Empty,
    #[error("frame of {bytes} bytes, more than {MAX_FRAME_BYTES} [R2]")]
    FrameTooLong { bytes: usize },
    #[error("code 1 packet with an odd payload of {bytes} bytes [R3]")]
    OddCbrPayload { bytes: usize },
    #[error("frame length field runs past the end of the packet [R4/R7]")]
    TruncatedLength,
    #[error("frame {frame} of {bytes} bytes runs past the end of the packet [R4/R7]")]
    FrameOverrun { frame: usize, bytes: usize },
    #[error("code 3 packet without a frame count byte [R5]")]
    MissingFrameCount,
    #[error("code 3 packet with {count} frames of {frame_ms} ms: not 1..=120 ms [R5]")]
    BadFrameCount { count: usize, frame_ms: u32 },
    #[error("padding runs past the end of the packet [R6/R7]")]
    PaddingOverrun,
    #[error("code 3 CBR payload of {bytes} bytes does not split into {count} frames [R6]")]
    UnevenCbrPayload { bytes: usize, count: usize },
}

/// A packet split into its frames, borrowing the packet's bytes.
#[derive(Debug, Clone)]
pub struct Packet<'a> {
    pub toc: Toc,
    data: &'a [u8],
    count: usize,
    /// Where the first frame starts; the others follow it back to back.
    start: usize,
    /// Frame sizes, each at most `MAX_FRAME_BYTES` (small, as the packet is copied per call).
    sizes: [u16; MAX_FRAMES],
    /// Padding bytes of a code 3 packet (not part of any frame).
    pub padding: usize,
}

impl<'a> Packet<'a> {
    /// Splits a packet (not self-delimited) into frames.
    pub fn parse(data: &'a [u8]) -> Result<Self, PacketError> {
        let (&toc_byte, mut rest) = data.split_first().ok_or(PacketError::Empty)?;
        let toc = Toc::from_byte(toc_byte);
        let mut packet = Self {
            toc,
            data,
            count: 0,
            start: 0,
            sizes: [0; MAX_FRAMES],
            padding: 0,
        };
        let sizes = &mut packet.sizes;
        let count;
        match toc.code {
            0 => {
                count = 1;
                sizes[0] = frame_size(rest.len())?;
            }
            1 => {
                if rest.len() % 2 != 0 {
                    return Err(PacketError::OddCbrPayload { bytes: rest.len() });
                }
                count = 2;
                sizes[0] = frame_size(rest.len() / 2)?;
                sizes[1] = sizes[0];
            }
            2 => {
                count = 2;
                let (first, used) = read_length(rest)?;
                rest = &rest[used..];
                if first > rest.len() {
                    return Err(PacketError::FrameOverrun {
                        frame: 0,
                        bytes: first,
                    });
                }
                sizes[0] = frame_size(first)?;
                sizes[1] = frame_size(rest.len() - first)?;
            }
            _ => {
                let (&frame_count, after) =
                    rest.split_first().ok_or(PacketError::MissingFrameCount)?;
                rest = after;
                count = usize::from(frame_count & 0x3F);
                let vbr = frame_count & 0x80 != 0;
                let padded = frame_count & 0x40 != 0;
                if count == 0 || count as u32 * toc.frame_samples_48k() > MAX_PACKET_SAMPLES_48K {
                    return Err(PacketError::BadFrameCount {
                        count,
                        frame_ms: toc.frame_ms(),
                    });
                }
                if padded {
                    let mut padding = 0usize;
                    loop {
                        let (&byte, after) =
                            rest.split_first().ok_or(PacketError::PaddingOverrun)?;
                        rest = after;
                        padding += if byte == 255 { 254 } else { usize::from(byte) };
                        if byte != 255 {
                            break;
                        }
                    }
                    if padding > rest.len() {
                        return Err(PacketError::PaddingOverrun);
                    }
                    rest = &rest[..rest.len() - padding];
                    packet.padding = padding;
                }
                if vbr {
                    let mut total = 0usize;
                    for (frame, size) in sizes.iter_mut().enumerate().take(count - 1) {
                        let (length, used) = read_length(rest)?;
                        rest = &rest[used..];
                        total += length;
                        if total > rest.len() {
                            return Err(PacketError::FrameOverrun {
                                frame,
                                bytes: length,
                            });
                        }
                        *size = frame_size(length)?;
                    }
                    sizes[count - 1] = frame_size(rest.len() - total)?;
                } else {
                    if rest.len() % count != 0 {
                        return Err(PacketError::UnevenCbrPayload {
                            bytes: rest.len(),
                            count,
                        });
                    }
                    let size = frame_size(rest.len() / count)?;
                    sizes[..count].fill(size);
                }
            }
        }
        packet.start = data.len() - packet.padding - rest.len();
        packet.count = count;
        Ok(packet)
    }

    pub fn frame_count(&self) -> usize {
        self.count
    }

    /// The bytes of frame `index`, if there is one.
    pub fn frame(&self, index: usize) -> Option<&'a [u8]> {
        if index >= self.count {
            return None;
        }
        let before: usize = self.sizes[..index].iter().map(|&s| usize::from(s)).sum();
        let start = self.start + before;
        self.data.get(start..start + usize::from(self.sizes[index]))
    }

    pub fn frames(&self) -> impl ExactSizeIterator<Item = &'a [u8]> + '_ {
        (0..self.count).map(|i| self.frame(i).unwrap_or_default())
    }

    /// Total duration in 48 kHz samples.
    pub fn samples_48k(&self) -> u32 {
        self.count as u32 * self.toc.frame_samples_48k()
    }
}

/// A frame's size, refused past the largest a frame may be (3.4, R2).
fn frame_size(bytes: usize) -> Result<u16, PacketError> {
    match u16::try_from(bytes) {
        Ok(size) if bytes <= MAX_FRAME_BYTES => Ok(size),
        _ => Err(PacketError::FrameTooLong { bytes }),
    }
}

/// A frame length of one or two bytes (3.2.1); returns the length and the bytes it used.
fn read_length(data: &[u8]) -> Result<(usize, usize), PacketError> {
    match *data {
        [] => Err(PacketError::TruncatedLength),
        [first, ..] if first < 252 => Ok((usize::from(first), 1)),
        [_] => Err(PacketError::TruncatedLength),
        [first, second, ..] => Ok((usize::from(second) * 4 + usize::from(first), 2)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sizes(packet: &Packet<'_>) -> Vec<usize> {
        packet.frames().map(<[u8]>::len).collect()
    }

    #[test]
    fn toc_byte_fields() {
        // config 9 (SILK WB 20 ms), mono, code 0
        let toc = Toc::from_byte(9 << 3);
        assert_eq!(toc.mode(), Mode::Silk);
        assert_eq!(toc.bandwidth(), Bandwidth::Wide);
        assert_eq!(toc.frame_ms(), 20);
        let toc = Toc::from_byte((1 << 3) | 0x04 | 1);
        assert_eq!(
            (toc.bandwidth(), toc.frame_ms(), toc.stereo, toc.code),
            (Bandwidth::Narrow, 20, true, 1)
        );
        assert_eq!(Toc::from_byte(15 << 3).mode(), Mode::Hybrid);
        assert_eq!(Toc::from_byte(15 << 3).bandwidth(), Bandwidth::Full);
        assert_eq!(Toc::from_byte(13 << 3).frame_ms(), 20);
        assert_eq!(Toc::from_byte(16 << 3).frame_samples_48k(), 120);
        assert_eq!(Toc::from_byte(31 << 3).frame_ms(), 20);
        assert_eq!(Toc::from_byte(11 << 3).frame_ms(), 60);
    }

    #[test]
    fn codes_0_to_2() {
        let p = [9 << 3, 1, 2, 3];
        assert_eq!(sizes(&Packet::parse(&p).unwrap()), [3]);
        assert_eq!(
            sizes(&Packet::parse(&[9 << 3]).unwrap()),
            [0],
            "a zero-byte frame is legal (DTX/loss)"
        );
        let p = [(9 << 3) | 1, 1, 2, 3, 4];
        let packet = Packet::parse(&p).unwrap();
        assert_eq!(packet.frame(1), Some(&[3u8, 4][..]));
        assert_eq!(
            Packet::parse(&[(9 << 3) | 1, 1, 2, 3]).unwrap_err(),
            PacketError::OddCbrPayload { bytes: 3 }
        );
        let p = [(9 << 3) | 2, 1, 7, 8, 9];
        let packet = Packet::parse(&p).unwrap();
        assert_eq!(packet.frame(0), Some(&[7u8][..]));
        assert_eq!(packet.frame(1), Some(&[8u8, 9][..]));
        assert!(matches!(
            Packet::parse(&[(9 << 3) | 2, 5, 7]),
            Err(PacketError::FrameOverrun { .. })
        ));
        assert_eq!(
            Packet::parse(&[(9 << 3) | 2, 252]).unwrap_err(),
            PacketError::TruncatedLength
        );
        // Two-byte length: 252 + 4 * 1 = 256
        let mut p = vec![(9 << 3) | 2, 252, 1];
        p.extend(std::iter::repeat_n(0, 300));
        assert_eq!(sizes(&Packet::parse(&p).unwrap()), [256, 44]);
    }

    #[test]
    fn code_3_cbr_vbr_and_padding() {
        // 3 CBR frames of SILK NB 20 ms with 2 + 254 bytes of padding... keep it small:
        // padding bytes 255 (254) then 1: 255 bytes of padding.
        let mut p = vec![(1 << 3) | 3, 0x40 | 3, 255, 1];
        p.extend([1, 1, 2, 2, 3, 3]);
        p.extend(std::iter::repeat_n(0, 255));
        let packet = Packet::parse(&p).unwrap();
        assert_eq!(sizes(&packet), [2, 2, 2]);
        assert_eq!(packet.padding, 255);
        assert_eq!(packet.samples_48k(), 3 * 960);
        // VBR: sizes 1 and 3, the last takes the rest.
        let p = [(1 << 3) | 3, 0x80 | 3, 1, 3, 9, 8, 8, 8, 7, 7];
        let packet = Packet::parse(&p).unwrap();
        assert_eq!(sizes(&packet), [1, 3, 2]);
        assert_eq!(packet.frame(2), Some(&[7u8, 7][..]));
        // 7 frames of 20 ms are 140 ms > 120 ms.
        assert!(matches!(
            Packet::parse(&[(1 << 3) | 3, 7]),
            Err(PacketError::BadFrameCount { count: 7, .. })
        ));
        assert!(matches!(
            Packet::parse(&[(1 << 3) | 3, 0]),
            Err(PacketError::BadFrameCount { count: 0, .. })
        ));
        assert_eq!(
            Packet::parse(&[(1 << 3) | 3]).unwrap_err(),
            PacketError::MissingFrameCount
        );
        assert_eq!(
            Packet::parse(&[(1 << 3) | 3, 2, 1, 2, 3]).unwrap_err(),
            PacketError::UnevenCbrPayload { bytes: 3, count: 2 }
        );
        assert_eq!(
            Packet::parse(&[(1 << 3) | 3, 0x40 | 1, 5, 0]).unwrap_err(),
            PacketError::PaddingOverrun
        );
        assert_eq!(
            Packet::parse(&[(1 << 3) | 3, 0x40 | 1, 255]).unwrap_err(),
            PacketError::PaddingOverrun
        );
        // VBR lengths that overrun.
        assert!(matches!(
            Packet::parse(&[(1 << 3) | 3, 0x80 | 3, 2, 2, 1, 1]),
            Err(PacketError::FrameOverrun { .. })
        ));
    }

    #[test]
    fn frames_longer_than_1275_bytes_are_rejected() {
        let mut p = vec![9 << 3];
        p.extend(std::iter::repeat_n(0, 1276));
        assert_eq!(
            Packet::parse(&p).unwrap_err(),
            PacketError::FrameTooLong { bytes: 1276 }
        );
        p.truncate(1276);
        assert!(Packet::parse(&p).is_ok());
    }
}
