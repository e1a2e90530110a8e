//! Whole Ogg Speex streams: encoding PCM the way speexenc does and decoding the way speexdec does
//! (same granule bookkeeping, same samples trimmed at start and end), with per-frame features.

use super::codec::{CodecError, Decoder, Encoder, EncoderConfig, FrameOutcome, MAX_PACKET_BYTES};
use super::features::FeatureExtractor;
use super::ogg_file::{self, OggSpeexError, SpeexFile, SpeexHeader};
use crate::vocab::FRAME_SIZE;
use crate::vocab::FrameFeatures;

#[derive(Debug, thiserror::Error)]
pub enum StreamError {
    #[error(transparent)]
    Ogg(#[from] OggSpeexError),
    #[error(transparent)]
    Codec(#[from] CodecError),
    #[error("the stream holds no audio frame")]
    NoAudio,
}

/// Encodes 8 kHz mono PCM into an Ogg Speex file that speexdec plays.
pub fn encode(pcm: &[i16], config: EncoderConfig) -> Result<Vec<u8>, StreamError> {
    let mut encoder = Encoder::new(config)?;
    let lookahead = encoder.lookahead();
    let total = pcm.len();
    // Like speexenc: keep encoding (zero-padded) until the look-ahead has flushed the last sample.
    let frame_count = (total + lookahead).div_ceil(FRAME_SIZE).max(1);
    let mut packets = Vec::new();
    let mut granules = Vec::new();
    let mut buffer = [0u8; MAX_PACKET_BYTES];
    let granule_after =
        |frames: usize| ((frames * FRAME_SIZE).saturating_sub(lookahead)).min(total);
    for id in 0..frame_count {
        let mut frame = [0i16; FRAME_SIZE];
        let start = id * FRAME_SIZE;
        if start < total {
            let end = (start + FRAME_SIZE).min(total);
            frame[..end - start].copy_from_slice(&pcm[start..end]);
        }
        if let Some(n) = encoder.encode_frame(&frame, &mut buffer) {
            packets.push(buffer[..n].to_vec());
            granules.push(granule_after(id + 1) as u64);
        }
    }
    if let Some(n) = encoder.finish(&mut buffer) {
        packets.push(buffer[..n].to_vec());
        let frames = frame_count.next_multiple_of(config.frames_per_packet);
        granules.push(granule_after(frames) as u64);
    }
    let header = SpeexHeader::narrowband(config.vbr, config.frames_per_packet);
    let serial = stream_serial(pcm);
    Ok(ogg_file::write(
        &header,
        &[format!(
            "ENCODER=lipcall quality {}{}",
            config.quality,
            if config.vbr { " vbr" } else { "" }
        )],
        &packets,
        |i| granules[i],
        serial,
    )?)
}

/// A serial number that differs between streams but is reproducible for the same input.
fn stream_serial(pcm: &[i16]) -> u32 {
    pcm.iter().fold(0x811c_9dc5u32, |h, &s| {
        (h ^ u32::from(s as u16)).wrapping_mul(0x0100_0193)
    })
}

/// A decoded stream: the PCM speexdec would write and one feature row per 20 ms of it.
#[derive(Debug, Clone)]
pub struct Decoded {
    pub header: SpeexHeader,
    pub pcm: Vec<i16>,
    pub features: Vec<FrameFeatures>,
    /// Packets the decoder rejected as corrupt (speexdec skips the rest of such a packet too).
    pub corrupt_packets: usize,
}

/// Decodes an Ogg Speex file as speexdec 1.2.1 does, including the samples it trims.
pub fn decode(bytes: &[u8], enhancer: bool) -> Result<Decoded, StreamError> {
    let file = ogg_file::read(bytes)?;
    decode_file(&file, enhancer)
}

pub fn decode_file(file: &SpeexFile, enhancer: bool) -> Result<Decoded, StreamError> {
    let mut decoder = Decoder::new(enhancer)?;
    let mut extractor = FeatureExtractor::new();
    let lookahead = decoder.lookahead() as i64;
    let frames_per_packet = file.header.frames_per_packet;
    let frame = FRAME_SIZE as i64;
    let mut corrupt_packets = 0;
    // speexdec's comment packet page has granule 0.
    let mut last_granule: i64 = 0;
    let mut out = [0i16; FRAME_SIZE];
    for page in &file.pages {
        let packets_on_page = page.packets.len() as i64;
        let page_granule = page.granule.map_or(-1, |g| i64::try_from(g).unwrap_or(-1));
        let mut skip = if page_granule > 0 {
            packets_on_page * frame * frames_per_packet as i64 - (page_granule - last_granule)
        } else {
            0
        };
        if page.end_of_stream {
            skip = -skip;
        }
        last_granule = page_granule;
        for (index, packet) in page.packets.iter().enumerate() {
            let packet_no = index as i64 + 1;
            decoder.load(packet)?;
            let walked = extractor.start_packet(packet).is_ok();
            let mut damaged = !walked;
            for j in 0..frames_per_packet as i64 {
                match decoder.decode_next(&mut out) {
                    Ok(FrameOutcome::Decoded) => {}
                    Ok(FrameOutcome::EndOfPacket) => break,
                    Err(CodecError::Corrupted | CodecError::Overflow) => {
                        damaged = true;
                        break;
                    }
                    Err(e) => return Err(e.into()),
                }
                let mut offset = 0i64;
                let mut length = frame;
                if packet_no == 1 && j == 0 && skip > 0 {
                    length -= skip + lookahead;
                    offset = skip + lookahead;
                }
                if packet_no == packets_on_page && skip < 0 {
                    let packet_length = frames_per_packet as i64 * frame + skip + lookahead;
                    length = (packet_length - j * frame).clamp(0, frame);
                }
                let start = offset.clamp(0, frame) as usize;
                let end = (offset + length.max(0)).clamp(0, frame) as usize;
                extractor.push_frame(&out, start..end.max(start));
            }
            corrupt_packets += usize::from(damaged);
        }
        if page.end_of_stream {
            break;
        }
    }
    let (pcm, features) = extractor.finish();
    Ok(Decoded {
        header: file.header.clone(),
        pcm,
        features,
        corrupt_packets,
    })
}

/// What a receiver would see of `pcm`: encoded at `config`, decoded with the enhancer on, and
/// trimmed as speexdec trims, so feature row `n` lines up with input samples `160n..160n+160`.
pub fn round_trip(pcm: &[i16], config: EncoderConfig) -> Result<Decoded, StreamError> {
    decode(&encode(pcm, config)?, true)
}
