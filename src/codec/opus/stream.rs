//! Whole Ogg Opus streams: encoding PCM the way opusenc does (pre-skip from the encoder's
//! look-ahead, the last granule position trimming the padding) and decoding the way opusdec
//! does (pre-skip dropped, end trimmed, output gain applied), at 8 kHz.

use super::codec::{
    CodecError, Decoder, Encoder, EncoderConfig, MAX_PACKET_BYTES, MAX_PACKET_MS, OPUS_CLOCK_RATE,
    packet_samples,
};
use super::ogg_file::{self, OggOpusError, OpusFile, OpusHead};
use crate::vocab::SAMPLE_RATE;

/// No file lipcall has a use for lasts longer; a stream of tiny packets claiming more is
/// refused before its audio fills memory.
pub const MAX_DURATION_S: usize = 4 * 3600;

#[derive(Debug, thiserror::Error)]
pub enum StreamError {
    #[error(transparent)]
    Ogg(#[from] OggOpusError),
    #[error(transparent)]
    Codec(#[from] CodecError),
    #[error(
        "the first audio page's granule position is smaller than its packets' duration \
         (RFC 7845 4.5)"
    )]
    BadGranule,
    #[error("Opus with {0} streams (surround) is not supported: lipcall decodes one stream")]
    MultiStream(u8),
    #[error(
        "channel mapping family {0} (ambisonics or channels of no defined meaning) is not \
         supported: lipcall plays mono or stereo Opus"
    )]
    MappingFamily(u8),
    #[error("the stream lasts longer than {} hours", MAX_DURATION_S / 3600)]
    TooLong,
    #[error("none of its {0} audio packets is valid Opus: there is no audio to decode")]
    AllCorrupt(usize),
}

/// Encodes mono PCM at `config.input_rate` (8 kHz by default) into an Ogg Opus file that
/// opusdec plays: 20 ms packets, the pre-skip the encoder's look-ahead, and a last granule
/// position that makes the decoded length equal the input's.
pub fn encode(pcm: &[i16], config: EncoderConfig) -> Result<Vec<u8>, StreamError> {
    let mut encoder = Encoder::new(config)?;
    let frame = encoder.frame_samples();
    let lookahead = encoder.lookahead()?;
    let per_sample = u64::from(OPUS_CLOCK_RATE / config.input_rate);
    let total = pcm.len();
    // Keep encoding (zero-padded) until the look-ahead has flushed the last sample.
    let frame_count = (total + lookahead).div_ceil(frame).max(1);
    let end_granule = (total + lookahead) as u64 * per_sample;
    let mut packets = Vec::with_capacity(frame_count);
    let mut buffer = [0u8; MAX_PACKET_BYTES];
    let mut input = vec![0i16; frame];
    for id in 0..frame_count {
        let start = (id * frame).min(total);
        let end = (start + frame).min(total);
        input.fill(0);
        input[..end - start].copy_from_slice(&pcm[start..end]);
        let n = encoder.encode_frame(&input, &mut buffer)?;
        packets.push(buffer[..n].to_vec());
    }
    let pre_skip = u16::try_from(lookahead as u64 * per_sample).unwrap_or(u16::MAX);
    let head = OpusHead::mono(pre_skip, config.input_rate);
    let vendor = format!(
        "lipcall {} ({})",
        env!("CARGO_PKG_VERSION"),
        opus::version()
    );
    let comments = [format!(
        "ENCODER=lipcall {} kb/s{}{}{}",
        f64::from(config.bitrate) / 1000.0,
        if config.vbr { " vbr" } else { " cbr" },
        if config.fec { " fec" } else { "" },
        if config.dtx { " dtx" } else { "" }
    )];
    // Pages before the last carry the exact count; only the last one trims (RFC 7845 4.4).
    let granule_of = |i: usize| ((i as u64 + 1) * frame as u64 * per_sample).min(end_granule);
    Ok(ogg_file::write(
        &head,
        &vendor,
        &comments,
        &packets,
        granule_of,
        stream_serial(pcm),
    )?)
}

/// A serial number that differs between streams but is reproducible for the same input.
fn stream_serial(pcm: &[i16]) -> u32 {
    pcm.iter().fold(0x811c_9dc5u32, |h, &s| {
        (h ^ u32::from(s as u16)).wrapping_mul(0x0100_0193)
    })
}

/// One audio packet of a decoded stream, in stream order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DecodedPacket {
    pub data: Vec<u8>,
    /// Samples it decoded to (for a corrupt packet: the samples concealed for it).
    pub samples: usize,
    /// Where its first sample lands in `Decoded::pcm`: negative while inside the pre-skip.
    pub pcm_offset: i64,
    /// libopus refused it; concealment stands in for it.
    pub corrupt: bool,
}

/// A decoded stream: the PCM opusdec would write (mono) and the packets it came from.
#[derive(Debug, Clone)]
pub struct Decoded {
    pub head: OpusHead,
    pub vendor: String,
    pub comments: Vec<String>,
    /// The rate of `pcm` and of the packets' sample counts: 8 kHz unless asked otherwise.
    pub rate: u32,
    /// Mono, pre-skip dropped and the end trimmed.
    pub pcm: Vec<i16>,
    pub packets: Vec<DecodedPacket>,
    /// Packets libopus rejected as corrupt (each concealed for its duration).
    pub corrupt_packets: usize,
    /// Pages whose granule position disagrees with the audio before them (a page that is not
    /// the last must count its packets exactly; the last may only trim): the file was cut or
    /// written wrong. Its packets are played as they are.
    pub bad_granules: usize,
}

/// Decodes an Ogg Opus file to 8 kHz mono as opusdec does, including the samples it trims.
pub fn decode(bytes: &[u8]) -> Result<Decoded, StreamError> {
    decode_at(bytes, SAMPLE_RATE)
}

/// Decodes an Ogg Opus file at another Opus rate (48 kHz: what opusdec decodes at before it
/// resamples).
/// A chained file (links one after another, as concatenated files are) decodes link by
/// link, each with its own decoder, pre-skip and end trimming, into one signal.
pub fn decode_at(bytes: &[u8], rate: u32) -> Result<Decoded, StreamError> {
    let mut links = ogg_file::read_chain(bytes)?.into_iter();
    let first = links
        .next()
        .ok_or(StreamError::Ogg(OggOpusError::Truncated))?;
    let mut whole = decode_file(first, rate)?;
    let max_samples = MAX_DURATION_S * rate as usize;
    for link in links {
        let next = decode_file(link, rate)?;
        if whole.pcm.len() + next.pcm.len() > max_samples {
            return Err(StreamError::TooLong);
        }
        let offset = whole.pcm.len() as i64;
        whole.pcm.extend_from_slice(&next.pcm);
        whole.packets.extend(next.packets.into_iter().map(|mut p| {
            p.pcm_offset += offset;
            p
        }));
        whole.corrupt_packets += next.corrupt_packets;
        whole.bad_granules += next.bad_granules;
    }
    Ok(whole)
}

pub fn decode_file(file: OpusFile, rate: u32) -> Result<Decoded, StreamError> {
    let head = file.head;
    if head.streams != 1 {
        return Err(StreamError::MultiStream(head.streams));
    }
    if head.mapping_family > 1 {
        return Err(StreamError::MappingFamily(head.mapping_family));
    }
    let mut decoder = Decoder::with_rate(rate)?;
    decoder.set_gain(head.output_gain)?;
    // Granule units (48 kHz) per output sample, and a conversion rounding to the nearest.
    let per_sample = u64::from(OPUS_CLOCK_RATE / rate);
    let to_rate = |granule: u64| granule.saturating_add(per_sample / 2) / per_sample;
    let max_samples = MAX_DURATION_S * rate as usize;
    let mut full = Vec::new();
    let mut packets = Vec::with_capacity(file.pages.iter().map(|p| p.packets.len()).sum());
    let mut corrupt_packets = 0;
    let mut out = vec![0i16; rate as usize * MAX_PACKET_MS / 1000];
    // Where the stream's first sample sits on the granule clock (RFC 7845 4.5), and where it
    // ends, from the first and the last page.
    let mut start_granule = None;
    let mut end_granule = None;
    let mut bad_granules = 0;
    let mut last_duration = decoder.frame_samples();
    for page in file.pages {
        for data in page.packets {
            let offset = full.len();
            let (samples, corrupt) = match decoder.decode(&data, &mut out) {
                // An empty packet is a lost one (RFC 6716 3.1): concealed, and counted so that
                // a file of nothing else is no audio at all.
                Ok(n) => (n, data.is_empty()),
                Err(CodecError::Corrupted | CodecError::OutputTooSmall { .. }) => {
                    let n = packet_samples(&data, rate).unwrap_or(last_duration);
                    decoder.conceal(&mut out[..n])?;
                    (n, true)
                }
                Err(e) => return Err(e.into()),
            };
            if offset + samples > max_samples {
                return Err(StreamError::TooLong);
            }
            full.extend_from_slice(&out[..samples]);
            last_duration = samples.max(decoder.frame_samples() / 8);
            corrupt_packets += usize::from(corrupt);
            packets.push(DecodedPacket {
                data,
                samples,
                pcm_offset: offset as i64,
                corrupt,
            });
        }
        let Some(granule) = page.granule else {
            continue;
        };
        let page_end = full.len() as u64 * per_sample;
        match start_granule {
            None => {
                start_granule = Some(match granule.checked_sub(page_end) {
                    Some(start) => start,
                    // A first page may end short of its packets only by end trimming.
                    None if page.end_of_stream => 0,
                    None => return Err(StreamError::BadGranule),
                });
            }
            Some(start) => {
                let counted = start.saturating_add(page_end);
                let agrees = if page.end_of_stream {
                    granule <= counted
                } else {
                    granule == counted
                };
                bad_granules += usize::from(!agrees);
            }
        }
        if page.end_of_stream {
            end_granule = Some(granule);
        }
    }
    if corrupt_packets > 0 && corrupt_packets == packets.len() {
        return Err(StreamError::AllCorrupt(corrupt_packets));
    }
    let pre_skip = to_rate(u64::from(head.pre_skip)) as usize;
    let end = match (start_granule, end_granule) {
        (Some(start), Some(end)) => to_rate(end.saturating_sub(start)).min(full.len() as u64),
        _ => full.len() as u64,
    } as usize;
    let pcm = full
        .get(pre_skip..end)
        .map(<[i16]>::to_vec)
        .unwrap_or_default();
    for p in &mut packets {
        p.pcm_offset -= pre_skip as i64;
    }
    Ok(Decoded {
        head,
        vendor: file.vendor,
        comments: file.comments,
        rate,
        pcm,
        packets,
        corrupt_packets,
        bad_granules,
    })
}

/// What a receiver would hear of 8 kHz `pcm` sent at `config`, trimmed as opusdec trims.
pub fn round_trip(pcm: &[i16], config: EncoderConfig) -> Result<Decoded, StreamError> {
    decode(&encode(pcm, config)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vocab::FRAME_SIZE;

    fn speechy(n: usize) -> Vec<i16> {
        (0..n)
            .map(|i| {
                let t = i as f32 / 8000.0;
                // A 140 Hz buzz whose loudness comes and goes like syllables.
                let env = 0.5 + 0.5 * (2.0 * std::f32::consts::PI * 3.0 * t).sin();
                let mut s = 0.0;
                for h in 1..20 {
                    let f = 140.0 * h as f32;
                    s += (2.0 * std::f32::consts::PI * f * t).sin()
                        / (1.0 + ((f - 600.0) / 400.0).powi(2));
                }
                (6000.0 * env * s) as i16
            })
            .collect()
    }

    #[test]
    fn undefined_channel_mappings_and_files_of_empty_packets_are_refused() {
        let head = OpusHead {
            channels: 255,
            mapping_family: 255,
            streams: 1,
            coupled: 0,
            mapping: std::iter::once(0)
                .chain(std::iter::repeat_n(255, 254))
                .collect(),
            ..OpusHead::mono(312, 48_000)
        };
        let packets = vec![vec![0x08, 0xff, 0xfe]; 10];
        let bytes =
            ogg_file::write(&head, "t", &[], &packets, |i| (i as u64 + 1) * 960, 1).unwrap();
        assert!(matches!(
            decode(&bytes),
            Err(StreamError::MappingFamily(255))
        ));
        let empty = vec![Vec::new(); 5000];
        let head = OpusHead::mono(312, 48_000);
        let bytes = ogg_file::write(&head, "t", &[], &empty, |i| (i as u64 + 1) * 960, 2).unwrap();
        assert!(matches!(decode(&bytes), Err(StreamError::AllCorrupt(5000))));
    }

    #[test]
    fn a_chained_file_decodes_every_link_in_order() {
        let one = encode(&speechy(16_000), EncoderConfig::default()).unwrap();
        let quiet: Vec<i16> = speechy(12_000).iter().map(|&x| x / 4).collect();
        let two = encode(&quiet, EncoderConfig::default()).unwrap();
        let chained = [one.clone(), two.clone()].concat();
        assert_eq!(ogg_file::read_chain(&chained).unwrap().len(), 2);
        let (a, b, whole) = (
            decode(&one).unwrap(),
            decode(&two).unwrap(),
            decode(&chained).unwrap(),
        );
        assert_eq!(whole.pcm.len(), a.pcm.len() + b.pcm.len());
        assert_eq!(whole.pcm, [a.pcm.clone(), b.pcm].concat());
        assert_eq!(whole.packets.len(), a.packets.len() + b.packets.len());
        let second = &whole.packets[a.packets.len()];
        assert_eq!(
            second.pcm_offset,
            a.pcm.len() as i64 + b.packets[0].pcm_offset
        );
        // A second link cut short is as a single one cut short.
        let cut = [one, two[..two.len() - 40].to_vec()].concat();
        assert!(matches!(
            decode(&cut),
            Err(StreamError::Ogg(OggOpusError::Truncated))
        ));
    }

    #[test]
    fn decoded_length_equals_the_input_length() {
        for n in [0, 1, 159, 160, 161, 4321, 8000] {
            let pcm = speechy(n);
            let decoded = round_trip(&pcm, EncoderConfig::default()).unwrap();
            assert_eq!(decoded.pcm.len(), n, "input of {n} samples");
            assert_eq!(decoded.head.pre_skip, 312);
            assert_eq!(decoded.head.input_rate, 8000);
            assert_eq!(decoded.corrupt_packets, 0);
        }
    }

    #[test]
    fn packets_tile_the_output_from_minus_the_pre_skip() {
        let pcm = speechy(8000);
        let d = round_trip(&pcm, EncoderConfig::default()).unwrap();
        // (8000 + 52) / 160 rounded up.
        assert_eq!(d.packets.len(), 51);
        assert_eq!(d.packets[0].pcm_offset, -52);
        for w in d.packets.windows(2) {
            assert_eq!(w[0].samples, FRAME_SIZE);
            assert_eq!(w[1].pcm_offset, w[0].pcm_offset + FRAME_SIZE as i64);
        }
    }

    #[test]
    fn decoded_audio_lines_up_with_the_input() {
        let pcm = speechy(16_000);
        let d = round_trip(&pcm, EncoderConfig::default()).unwrap();
        let corr = |lag: i64| -> f64 {
            (800..15_000i64)
                .map(|i| f64::from(pcm[i as usize]) * f64::from(d.pcm[(i + lag) as usize]))
                .sum()
        };
        let best = (-8..=8)
            .max_by(|&a, &b| corr(a).total_cmp(&corr(b)))
            .unwrap();
        assert_eq!(best, 0, "decoded audio is {best} samples late");
    }

    #[test]
    fn a_48k_encode_decodes_to_8k_with_the_same_duration() {
        let pcm48: Vec<i16> = speechy(8000)
            .iter()
            .flat_map(|&s| std::iter::repeat_n(s, 6))
            .collect();
        let config = EncoderConfig {
            input_rate: 48_000,
            bitrate: 24_000,
            ..Default::default()
        };
        let d = decode(&encode(&pcm48, config).unwrap()).unwrap();
        assert_eq!(d.head.pre_skip, 312);
        assert_eq!(d.pcm.len(), 8000);
    }

    #[test]
    fn corrupt_packets_are_concealed_and_counted() {
        let pcm = speechy(8000);
        let mut file = ogg_file::read(&encode(&pcm, EncoderConfig::default()).unwrap()).unwrap();
        // Code 3 with zero frames: libopus refuses it.
        file.pages[0].packets[10] = vec![0x03, 0x00];
        let d = decode_file(file, SAMPLE_RATE).unwrap();
        assert_eq!(d.corrupt_packets, 1);
        assert!(d.packets[10].corrupt);
        assert_eq!(d.pcm.len(), 8000);
    }

    #[test]
    fn a_stream_cut_from_a_longer_one_keeps_its_length() {
        // RFC 7845 4.5: the first page's granule may run ahead of its packets.
        let pcm = speechy(8000);
        let bytes = encode(&pcm, EncoderConfig::default()).unwrap();
        let mut file = ogg_file::read(&bytes).unwrap();
        for page in &mut file.pages {
            page.granule = page.granule.map(|g| g + 48_000 * 3600);
        }
        assert_eq!(decode_file(file, SAMPLE_RATE).unwrap().pcm.len(), 8000);
    }

    #[test]
    fn the_output_gain_is_applied() {
        let pcm = speechy(8000);
        let bytes = encode(&pcm, EncoderConfig::default()).unwrap();
        let plain = decode(&bytes).unwrap();
        let mut file = ogg_file::read(&bytes).unwrap();
        file.head.output_gain = -6 * 256;
        let quieter = decode_file(file, SAMPLE_RATE).unwrap();
        let energy = |s: &[i16]| s.iter().map(|&x| f64::from(x).powi(2)).sum::<f64>();
        let ratio_db = 10.0 * (energy(&quieter.pcm) / energy(&plain.pcm)).log10();
        assert!((ratio_db + 6.0).abs() < 0.1, "{ratio_db:.2} dB");
    }

    #[test]
    fn granules_that_disagree_with_the_audio_are_counted() {
        let bytes = encode(&speechy(40_000), EncoderConfig::default()).unwrap();
        let file = ogg_file::read(&bytes).unwrap();
        assert!(file.pages.len() >= 3);
        assert_eq!(
            decode_file(file.clone(), SAMPLE_RATE).unwrap().bad_granules,
            0
        );
        // A middle page a second ahead of its audio, and a last page claiming more than it holds.
        let mut wrong = file.clone();
        wrong.pages[1].granule = wrong.pages[1].granule.map(|g| g + 48_000);
        let last = wrong.pages.len() - 1;
        wrong.pages[last].granule = wrong.pages[last].granule.map(|g| g + 960);
        let d = decode_file(wrong, SAMPLE_RATE).unwrap();
        assert_eq!(d.bad_granules, 2);
        // Played by its packets: nothing of the audio is cut.
        assert!(d.pcm.len() >= 40_000, "{}", d.pcm.len());
    }

    #[test]
    fn multistream_and_bad_granules_are_refused() {
        let pcm = speechy(4000);
        let bytes = encode(&pcm, EncoderConfig::default()).unwrap();
        let mut file = ogg_file::read(&bytes).unwrap();
        file.head.streams = 2;
        assert!(matches!(
            decode_file(file, SAMPLE_RATE),
            Err(StreamError::MultiStream(2))
        ));
        // A first page claiming less than its packets, though not the last page.
        let mut file =
            ogg_file::read(&encode(&speechy(16_000), EncoderConfig::default()).unwrap()).unwrap();
        file.pages[0].granule = Some(960);
        assert!(matches!(
            decode_file(file, SAMPLE_RATE),
            Err(StreamError::BadGranule)
        ));
    }
}
