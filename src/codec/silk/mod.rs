//! The SILK layer of Opus read without decoding: the range decoder and the indices up to the
//! NLSFs.
//!
//! [`SilkWalker`] follows the decoder through each packet (RFC 6716 4.2): the TOC and frame
//! packing, the SILK header (VAD and LBRR flags), the LBRR frames that precede the regular
//! ones, and per regular frame its type, gains, NLSF indices and interpolation weight. The
//! pitch, LTP and excitation indices are read only to reach the next frame (a 40 or 60 ms
//! Opus frame holds two or three); after the last NLSFs of an Opus frame the walker stops
//! unless asked to read to the end. The NLSFs are reconstructed and stabilised with the
//! decoder's fixed-point arithmetic, so they are the vector libopus holds (`prevNLSF_Q15`)
//! after the frame.
//!
//! State that the decoder carries across packets is carried here too: the previous NLSFs
//! (interpolation), the gain index, the first-frame-after-reset rule, the internal rate and
//! the mode (a CELT-only frame resets SILK). For stereo streams the mid channel is reported.
//! Not followed: decoding the LBRR (FEC) copy of a lost packet in its place.
//!
//! Checked against libopus 1.3.1 in `tests/opus_nlsf.rs`: the final range after every
//! SILK-only packet, and the NLSF vectors of its own `silk_NLSF_decode`.

mod channel;
pub mod nlsf;
pub mod packet;
pub mod range;
mod tables;

pub use channel::SignalType;
pub use nlsf::MAX_ORDER;
pub use packet::{Bandwidth, Mode, Packet, PacketError, Toc};

use channel::{Channel, Coding, Indices, MAX_SUBFRAMES};
use range::RangeDecoder;
use tables::{
    LBRR_FLAGS_40MS_ICDF, LBRR_FLAGS_60MS_ICDF, STEREO_MID_ONLY_ICDF, STEREO_WEIGHT_JOINT_ICDF,
    UNIFORM3_ICDF, UNIFORM5_ICDF,
};

/// Normalised line spectral frequencies of one frame, as the decoder holds them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Nlsf {
    order: u8,
    q15: [i16; MAX_ORDER],
}

impl Nlsf {
    fn new(order: usize, q15: [i16; MAX_ORDER]) -> Self {
        Self {
            order: order.min(MAX_ORDER) as u8,
            q15,
        }
    }

    /// 10 for NB and MB, 16 for WB.
    pub fn order(&self) -> usize {
        usize::from(self.order)
    }

    /// The values in Q15: 32768 is the Nyquist frequency of the internal rate.
    pub fn q15(&self) -> &[i16] {
        &self.q15[..self.order()]
    }

    /// The values as angles in radians (0..pi at the internal rate).
    pub fn radians(&self) -> impl ExactSizeIterator<Item = f32> + '_ {
        self.q15()
            .iter()
            .map(|&v| f32::from(v) * (std::f32::consts::PI / 32768.0))
    }
}

/// One SILK frame (10 or 20 ms) of a SILK-only or hybrid Opus frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SilkFrame {
    /// Which Opus frame of the packet it belongs to.
    pub opus_frame: usize,
    /// Its place within that Opus frame (a 40 or 60 ms Opus frame holds 2 or 3).
    pub index: usize,
    pub mode: Mode,
    /// The bandwidth in the TOC byte.
    pub bandwidth: Bandwidth,
    /// The SILK layer's sampling rate: 8000, 12000 or 16000 (hybrid: 16000).
    pub internal_rate_hz: u32,
    pub duration_ms: u32,
    pub stereo: bool,
    pub vad: bool,
    pub signal_type: SignalType,
    pub high_quant_offset: bool,
    /// Per subframe, the decoder's log-gain index (0..64, about 1.37 dB a step); the first
    /// `subframes` entries are used.
    pub gain_indices: [u8; MAX_SUBFRAMES],
    pub subframes: usize,
    /// The stage-1 NLSF codebook index and the stage-2 residual indices (first `order`).
    pub nlsf_stage1: u8,
    pub nlsf_residuals: [i8; MAX_ORDER],
    /// The frame's NLSFs (those of its second half, or of all of it when not interpolated).
    pub nlsf: Nlsf,
    /// Weight 0..=4 (in quarters) of this frame's NLSFs against the previous ones in the
    /// first half; 4 means no interpolation (10 ms frames, or the first after a reset).
    pub interpolation_q2: u8,
    /// The NLSFs the decoder uses for the first half, when they differ from `nlsf`.
    pub first_half: Option<Nlsf>,
    /// Size of the Opus frame in bits.
    pub frame_bits: u32,
    /// Where the range decoder stands after the frame's last symbol; `None` where the walker
    /// stopped after the NLSFs (see [`SilkWalker::read_to_end`]).
    pub end: Option<SilkEnd>,
}

/// The range decoder's state at the end of a SILK frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SilkEnd {
    /// Bits used from the start of the Opus frame (`ec_tell`). It may pass the frame's size
    /// by the zero bytes an encoder stripped off the end of a SILK-only frame.
    pub bits_used: u32,
    /// The range: after the last SILK frame of a SILK-only Opus frame without redundancy,
    /// the value libopus reports as its final range (`OPUS_GET_FINAL_RANGE`).
    pub range: u32,
}

/// What the walker reports for one frame of a packet.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Frame {
    /// A SILK frame of a SILK-only or hybrid Opus frame, with its NLSFs.
    Silk(SilkFrame),
    /// A CELT-only Opus frame: it carries no NLSFs.
    Celt {
        opus_frame: usize,
        duration_48k: u32,
    },
    /// An Opus frame of at most one byte, which the decoder conceals (DTX or loss).
    Concealed {
        opus_frame: usize,
        duration_48k: u32,
    },
}

impl Frame {
    /// The NLSFs of a SILK frame.
    pub fn nlsf(&self) -> Option<&Nlsf> {
        match self {
            Frame::Silk(frame) => Some(&frame.nlsf),
            _ => None,
        }
    }

    /// Which Opus frame of the packet it comes from.
    pub fn opus_frame(&self) -> usize {
        match *self {
            Frame::Silk(SilkFrame { opus_frame, .. })
            | Frame::Celt { opus_frame, .. }
            | Frame::Concealed { opus_frame, .. } => opus_frame,
        }
    }

    pub fn silk(&self) -> Option<&SilkFrame> {
        match self {
            Frame::Silk(frame) => Some(frame),
            _ => None,
        }
    }
}

/// Why a packet could not be walked: only its framing can be invalid. Within a frame every
/// symbol sequence is valid SILK, and reading past the end gives zeros, as in the decoder
/// (the encoder strips trailing zero bytes off SILK-only frames, relying on that).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SilkError {
    #[error("invalid Opus packet: {0}")]
    Packet(#[from] PacketError),
}

/// Walks the packets of one Opus stream, keeping the SILK decoder state they depend on.
///
/// By default it stops each Opus frame at the NLSFs of its last SILK frame: what follows
/// (pitch, excitation, a stereo side channel) is needed by nothing after it, and skipping it
/// makes the walk several times cheaper. [`SilkWalker::read_to_end`] reads it all, to report
/// where the SILK data ends.
#[derive(Debug, Clone)]
pub struct SilkWalker {
    read_to_end: bool,
    channels: [Channel; 2],
    /// Channels of the previous SILK frame (0 before any).
    channels_in_use: usize,
    previous_mode: Option<Mode>,
    previous_mid_only: bool,
}

impl Default for SilkWalker {
    fn default() -> Self {
        Self::new()
    }
}

impl SilkWalker {
    pub const fn new() -> Self {
        Self {
            read_to_end: false,
            channels: [Channel::new(), Channel::new()],
            channels_in_use: 0,
            previous_mode: None,
            previous_mid_only: false,
        }
    }

    /// Whether to read every frame to its end, which fills [`SilkFrame::end`].
    pub const fn read_to_end(mut self, read_to_end: bool) -> Self {
        self.read_to_end = read_to_end;
        self
    }

    /// Forgets the stream, as a freshly created (or reset) decoder would.
    pub fn reset(&mut self) {
        *self = Self::new().read_to_end(self.read_to_end);
    }

    /// Follows the decoder through a lost packet (its concealment): the NLSFs are kept for
    /// the next frame's interpolation, the gain coding restarts.
    pub fn packet_lost(&mut self) {
        if matches!(self.previous_mode, Some(Mode::Silk | Mode::Hybrid)) {
            for channel in self.channels.iter_mut().take(self.channels_in_use) {
                channel.conceal();
            }
        }
    }

    /// All frames of one packet.
    pub fn walk_packet(&mut self, packet: &[u8]) -> Result<Vec<Frame>, SilkError> {
        let mut frames = Vec::with_capacity(3);
        self.walk_packet_into(packet, &mut frames)?;
        Ok(frames)
    }

    /// Appends the frames of one packet to `out`. After an error `out` holds the frames
    /// before it; they have updated the walker, as they would the decoder.
    pub fn walk_packet_into(
        &mut self,
        packet: &[u8],
        out: &mut Vec<Frame>,
    ) -> Result<(), SilkError> {
        let parsed = Packet::parse(packet)?;
        let toc = parsed.toc;
        for (opus_frame, data) in parsed.frames().enumerate() {
            self.walk_opus_frame(toc, opus_frame, data, out)?;
        }
        Ok(())
    }

    fn walk_opus_frame(
        &mut self,
        toc: Toc,
        opus_frame: usize,
        data: &[u8],
        out: &mut Vec<Frame>,
    ) -> Result<(), SilkError> {
        let duration_48k = toc.frame_samples_48k();
        if data.len() <= 1 {
            self.packet_lost();
            out.push(Frame::Concealed {
                opus_frame,
                duration_48k,
            });
            return Ok(());
        }
        let mode = toc.mode();
        let previous_mode = self.previous_mode.replace(mode);
        if mode == Mode::Celt {
            out.push(Frame::Celt {
                opus_frame,
                duration_48k,
            });
            return Ok(());
        }
        if previous_mode == Some(Mode::Celt) {
            self.channels = [Channel::new(), Channel::new()];
            self.previous_mid_only = false;
        }

        let rate_khz = match (mode, toc.bandwidth()) {
            (Mode::Silk, Bandwidth::Narrow) => 8,
            (Mode::Silk, Bandwidth::Medium) => 12,
            _ => 16,
        };
        let channel_count = if toc.stereo { 2 } else { 1 };
        if channel_count > self.channels_in_use {
            self.channels[1] = Channel::new();
        }
        self.channels_in_use = channel_count;
        // 10 ms: one frame of 2 subframes; 20, 40, 60 ms: 1, 2, 3 frames of 4.
        let duration_ms = toc.frame_ms();
        let (frame_count, subframes) = match duration_ms {
            10 => (1, 2),
            40 => (2, 4),
            60 => (3, 4),
            _ => (1, 4),
        };
        for channel in self.channels.iter_mut().take(channel_count) {
            channel.configure(rate_khz, subframes);
        }

        let frame_bits = 8 * data.len() as u32;
        let mut decoder = RangeDecoder::new(data);
        self.read_header(&mut decoder, channel_count, frame_count);
        let lbrr = self.channels[..channel_count]
            .iter()
            .any(|channel| channel.lbrr.contains(&true));
        if lbrr {
            self.skip_lbrr_frames(&mut decoder, channel_count, frame_count);
        }

        for index in 0..frame_count {
            let mid_only = channel_count == 2 && self.read_stereo_prediction(&mut decoder, index);
            // The side channel of a stereo stream is never reported: it is only read past.
            let stop_early = index + 1 == frame_count && !self.read_to_end;
            let mut mid = None;
            for n in 0..channel_count {
                if n == 1 && (mid_only || stop_early) {
                    continue;
                }
                let coding = if index == 0 {
                    Coding::Independent
                } else if n == 1 && self.previous_mid_only {
                    Coding::IndependentNoLtpScaling
                } else {
                    Coding::Conditional
                };
                let channel = &mut self.channels[n];
                let vad = channel.vad[index];
                let indices = channel.read_indices(&mut decoder, vad, coding);
                if stop_early {
                    channel.stop_after_indices(&indices);
                } else {
                    channel.skip_rest(&mut decoder, &indices, coding);
                }
                let parameters = channel.apply(&indices, coding);
                if n == 0 {
                    mid = Some((vad, indices, parameters));
                }
            }
            self.previous_mid_only = mid_only;

            let end = (!stop_early).then(|| SilkEnd {
                bits_used: decoder.tell(),
                range: decoder.range(),
            });
            let Some((vad, indices, parameters)) = mid else {
                continue;
            };
            let order = self.channels[0].codebook().order();
            out.push(Frame::Silk(SilkFrame {
                opus_frame,
                index,
                mode,
                bandwidth: toc.bandwidth(),
                internal_rate_hz: rate_khz * 1000,
                duration_ms: 5 * subframes as u32,
                stereo: channel_count == 2,
                vad,
                signal_type: indices.signal_type,
                high_quant_offset: indices.high_quant_offset,
                gain_indices: parameters.gain_indices,
                subframes,
                nlsf_stage1: indices.nlsf_stage1,
                nlsf_residuals: indices.nlsf_residuals,
                nlsf: Nlsf::new(order, parameters.nlsf_q15),
                interpolation_q2: parameters.interpolation_q2,
                first_half: parameters.first_half_q15.map(|q15| Nlsf::new(order, q15)),
                frame_bits,
                end,
            }));
        }
        Ok(())
    }

    /// VAD flags and LBRR flags of every channel (RFC 6716 4.2.3-4.2.4).
    fn read_header(
        &mut self,
        decoder: &mut RangeDecoder<'_>,
        channel_count: usize,
        frame_count: usize,
    ) {
        let mut lbrr_present = [false; 2];
        for (channel, present) in self
            .channels
            .iter_mut()
            .zip(&mut lbrr_present)
            .take(channel_count)
        {
            for vad in channel.vad.iter_mut().take(frame_count) {
                *vad = decoder.decode_bit_logp(1);
            }
            *present = decoder.decode_bit_logp(1);
        }
        for (channel, present) in self
            .channels
            .iter_mut()
            .zip(lbrr_present)
            .take(channel_count)
        {
            channel.lbrr = [false; 3];
            if !present {
                continue;
            }
            let flags = match frame_count {
                1 => 1,
                2 => decoder.decode_icdf(&LBRR_FLAGS_40MS_ICDF) + 1,
                _ => decoder.decode_icdf(&LBRR_FLAGS_60MS_ICDF) + 1,
            };
            for (i, lbrr) in channel.lbrr.iter_mut().enumerate().take(frame_count) {
                *lbrr = flags >> i & 1 == 1;
            }
        }
    }

    /// A stereo frame's prediction weights (read past) and mid-only flag: whether the side
    /// channel is left out of frame `index`.
    #[cold]
    #[inline(never)]
    fn read_stereo_prediction(&mut self, decoder: &mut RangeDecoder<'_>, index: usize) -> bool {
        skip_stereo_weights(decoder);
        let mid_only =
            !self.channels[1].vad[index] && decoder.decode_icdf(&STEREO_MID_ONLY_ICDF) == 1;
        if !mid_only && self.previous_mid_only {
            self.channels[1].restart();
        }
        mid_only
    }

    /// The LBRR (in-band FEC) frames come before the regular ones; the regular decoder reads
    /// past them. They update only the pitch-coding context, as in the decoder.
    #[cold]
    #[inline(never)]
    fn skip_lbrr_frames(
        &mut self,
        decoder: &mut RangeDecoder<'_>,
        channel_count: usize,
        frame_count: usize,
    ) {
        for index in 0..frame_count {
            for n in 0..channel_count {
                if !self.channels[n].lbrr[index] {
                    continue;
                }
                if channel_count == 2 && n == 0 {
                    skip_stereo_weights(decoder);
                    if !self.channels[1].lbrr[index] {
                        decoder.decode_icdf(&STEREO_MID_ONLY_ICDF);
                    }
                }
                let channel = &mut self.channels[n];
                let coding = if index > 0 && channel.lbrr[index - 1] {
                    Coding::Conditional
                } else {
                    Coding::Independent
                };
                let indices: Indices = channel.read_indices(decoder, true, coding);
                channel.skip_rest(decoder, &indices, coding);
            }
        }
    }
}

/// The mid/side prediction weights (RFC 6716 4.2.7.1): read past.
fn skip_stereo_weights(decoder: &mut RangeDecoder<'_>) {
    decoder.decode_icdf(&STEREO_WEIGHT_JOINT_ICDF);
    for _ in 0..2 {
        decoder.decode_icdf(&UNIFORM3_ICDF);
        decoder.decode_icdf(&UNIFORM5_ICDF);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A TOC byte: configuration, stereo flag, packing code.
    fn toc(config: u8, stereo: bool, code: u8) -> u8 {
        config << 3 | u8::from(stereo) << 2 | code
    }

    fn silk_frames(frames: &[Frame]) -> Vec<SilkFrame> {
        frames.iter().filter_map(|f| f.silk().copied()).collect()
    }

    #[test]
    fn celt_frames_carry_no_nlsfs_and_tiny_frames_are_concealed() {
        let mut walker = SilkWalker::new();
        let mut celt = vec![toc(31, false, 0)];
        celt.extend([0x55; 40]);
        let frames = walker.walk_packet(&celt).unwrap();
        assert_eq!(
            frames,
            [Frame::Celt {
                opus_frame: 0,
                duration_48k: 960
            }]
        );
        assert_eq!(frames[0].nlsf(), None);
        // Code 1: two frames of one byte each, which the decoder conceals.
        let frames = walker.walk_packet(&[toc(9, false, 1), 7, 7]).unwrap();
        assert_eq!(frames.len(), 2);
        assert!(frames.iter().all(|f| matches!(
            f,
            Frame::Concealed {
                duration_48k: 960,
                ..
            }
        )));
        assert_eq!(frames[1].opus_frame(), 1);
    }

    #[test]
    fn silk_frames_per_duration_bandwidth_and_mode() {
        let payload = [0x3Cu8; 30];
        // (config, mode, internal rate, SILK frames, their duration, order)
        let cases = [
            (1, Mode::Silk, 8000, 1, 20, 10),
            (4, Mode::Silk, 12000, 1, 10, 10),
            (9, Mode::Silk, 16000, 1, 20, 16),
            (10, Mode::Silk, 16000, 2, 20, 16),
            (3, Mode::Silk, 8000, 3, 20, 10),
            (12, Mode::Hybrid, 16000, 1, 10, 16),
            (15, Mode::Hybrid, 16000, 1, 20, 16),
        ];
        for (config, mode, rate, count, duration, order) in cases {
            let mut packet = vec![toc(config, false, 0)];
            packet.extend(payload);
            let frames = SilkWalker::new().walk_packet(&packet).unwrap();
            let silk = silk_frames(&frames);
            assert_eq!(silk.len(), count, "config {config}");
            for (i, frame) in silk.iter().enumerate() {
                assert_eq!(frame.index, i);
                assert_eq!(frame.mode, mode);
                assert_eq!(frame.internal_rate_hz, rate);
                assert_eq!(frame.duration_ms, duration);
                assert_eq!(frame.nlsf.order(), order);
                assert_eq!(frame.nlsf.radians().len(), order);
                assert!(frame.nlsf.q15().windows(2).all(|w| w[0] < w[1]));
            }
        }
    }

    #[test]
    fn interpolation_needs_a_previous_frame_of_the_same_decoder() {
        let mut packet = vec![toc(9, false, 0)];
        packet.extend([0u8; 40]);
        let mut walker = SilkWalker::new();
        // Zero bytes decode as the first symbol everywhere: interpolation weight 0.
        let first = silk_frames(&walker.walk_packet(&packet).unwrap())[0];
        assert_eq!((first.interpolation_q2, first.first_half), (4, None));
        let second = silk_frames(&walker.walk_packet(&packet).unwrap())[0];
        assert_eq!(second.interpolation_q2, 0);
        assert_eq!(second.first_half, Some(first.nlsf));
        // A lost packet keeps the NLSFs for interpolation.
        walker.packet_lost();
        let after_loss = silk_frames(&walker.walk_packet(&packet).unwrap())[0];
        assert_eq!(after_loss.interpolation_q2, 0);
        // A CELT frame resets the SILK decoder, and so does a new internal rate.
        let mut celt = vec![toc(31, false, 0)];
        celt.extend([0x55; 40]);
        walker.walk_packet(&celt).unwrap();
        let after_celt = silk_frames(&walker.walk_packet(&packet).unwrap())[0];
        assert_eq!(after_celt.interpolation_q2, 4);
        let mut narrow = packet.clone();
        narrow[0] = toc(1, false, 0);
        let after_switch = silk_frames(&walker.walk_packet(&narrow).unwrap())[0];
        assert_eq!(after_switch.interpolation_q2, 4);
        walker.reset();
        let after_reset = silk_frames(&walker.walk_packet(&packet).unwrap())[0];
        assert_eq!(after_reset, first);
    }

    #[test]
    fn code_3_packets_and_stereo() {
        // Three CBR frames of SILK NB 20 ms, stereo.
        let mut packet = vec![toc(1, true, 3), 3];
        packet.extend([0x81u8; 45]);
        let frames = SilkWalker::new().walk_packet(&packet).unwrap();
        let silk = silk_frames(&frames);
        assert_eq!(silk.len(), 3);
        assert_eq!(
            silk.iter().map(|f| f.opus_frame).collect::<Vec<_>>(),
            [0, 1, 2]
        );
        assert!(silk.iter().all(|f| f.stereo && f.frame_bits == 15 * 8));
    }

    #[test]
    fn stopping_after_the_last_nlsfs_finds_the_same_frames() {
        let mut fast = SilkWalker::new();
        let mut full = SilkWalker::new().read_to_end(true);
        let mut state = 0x2545_F491u32;
        for n in 0..300 {
            let config = [1, 3, 5, 9, 10, 11, 13, 15][n % 8];
            let mut packet = vec![toc(config, n % 3 == 0, 0)];
            for _ in 0..50 {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                packet.push((state >> 24) as u8);
            }
            let quick = silk_frames(&fast.walk_packet(&packet).unwrap());
            let thorough = silk_frames(&full.walk_packet(&packet).unwrap());
            assert_eq!(quick.len(), thorough.len());
            for (q, t) in quick.iter().zip(&thorough) {
                assert_eq!(q.end.is_none(), q.index + 1 == quick.len());
                assert!(t.end.is_some());
                assert_eq!(SilkFrame { end: t.end, ..*q }, *t);
            }
        }
    }

    #[test]
    fn invalid_framing_is_an_error() {
        let mut walker = SilkWalker::new();
        assert_eq!(
            walker.walk_packet(&[]),
            Err(SilkError::Packet(PacketError::Empty))
        );
        assert!(walker.walk_packet(&[toc(9, false, 1), 1, 2, 3]).is_err());
        let mut out = Vec::new();
        assert!(
            walker
                .walk_packet_into(&[toc(9, false, 3), 0], &mut out)
                .is_err()
        );
        assert!(out.is_empty());
    }
}
