//! A small safe wrapper over the reference libspeex 1.2.1 encoder and decoder, narrowband
//! (8 kHz) and wideband (16 kHz: a narrowband layer for 0-4 kHz, then a layer for 4-8 kHz that
//! a narrowband decoder steps over).
//!
//! libspeex is built statically by `speex-sys` from its bundled C source (float build). Every
//! unsafe call lives in this file; each state is owned by exactly one Rust value and freed on drop.

#![allow(unsafe_code)]

use std::ffi::{c_int, c_void};
use std::ptr::NonNull;

use speex_sys as sys;

use crate::vocab::FRAME_SIZE;

/// Largest packet we ever produce: 8 frames of the biggest mode (492 bits) plus a terminator.
pub const MAX_PACKET_BYTES: usize = 8 * 62 + 1;

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum CodecError {
    #[error("libspeex could not allocate a codec state")]
    Init,
    #[error("quality {0} is outside 0..=10")]
    Quality(u8),
    #[error("complexity {0} is outside 1..=10")]
    Complexity(u8),
    #[error("frames per packet must be 1..=8, not {0}")]
    FramesPerPacket(usize),
    #[error("corrupted Speex packet")]
    Corrupted,
    #[error("Speex packet is shorter than its frames claim")]
    Overflow,
    #[error("a packet of {0} bytes is larger than any Speex packet can be")]
    PacketTooLarge(usize),
    #[error("a frame of {got} samples where this mode's 20 ms is {expected}")]
    FrameLength { got: usize, expected: usize },
}

/// Speex's bands: its narrowband mode, or the wideband mode over it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Band {
    #[default]
    Narrow,
    Wide,
}

impl Band {
    /// The audio rate.
    pub const fn rate(self) -> u32 {
        match self {
            Band::Narrow => 8000,
            Band::Wide => 16_000,
        }
    }

    /// Samples in one 20 ms frame.
    pub const fn frame_size(self) -> usize {
        self.rate() as usize / 50
    }

    fn mode(self) -> *const sys::SpeexMode {
        match self {
            Band::Narrow => &raw const sys::speex_nb_mode,
            Band::Wide => &raw const sys::speex_wb_mode,
        }
    }
}

/// How the encoder is set up. The defaults are speexenc's: quality 8, CBR, complexity 3.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EncoderConfig {
    pub quality: u8,
    pub vbr: bool,
    pub complexity: u8,
    pub frames_per_packet: usize,
}

impl Default for EncoderConfig {
    fn default() -> Self {
        Self {
            quality: 8,
            vbr: false,
            complexity: 3,
            frames_per_packet: 1,
        }
    }
}

impl EncoderConfig {
    fn validate(&self) -> Result<(), CodecError> {
        if self.quality > 10 {
            return Err(CodecError::Quality(self.quality));
        }
        if !(1..=10).contains(&self.complexity) {
            return Err(CodecError::Complexity(self.complexity));
        }
        if !(1..=8).contains(&self.frames_per_packet) {
            return Err(CodecError::FramesPerPacket(self.frames_per_packet));
        }
        Ok(())
    }
}

/// The bit-packer libspeex reads from and writes to.
struct Bits(Box<sys::SpeexBits>);

impl Bits {
    fn new() -> Self {
        // SAFETY: SpeexBits is plain data; speex_bits_init fills every field and allocates its
        // buffer, which speex_bits_destroy frees in Drop.
        let mut bits: Box<sys::SpeexBits> = Box::new(unsafe { std::mem::zeroed() });
        unsafe { sys::speex_bits_init(bits.as_mut()) };
        Self(bits)
    }

    fn ptr(&mut self) -> *mut sys::SpeexBits {
        self.0.as_mut()
    }
}

impl Drop for Bits {
    fn drop(&mut self) {
        // SAFETY: initialised in `new`, destroyed once.
        unsafe { sys::speex_bits_destroy(self.ptr()) };
    }
}

// SAFETY: the bit buffer is owned by this value alone and never shared between threads.
unsafe impl Send for Bits {}

/// A narrowband Speex encoder producing packets of `frames_per_packet` frames.
pub struct Encoder {
    state: NonNull<c_void>,
    bits: Bits,
    config: EncoderConfig,
    band: Band,
    frames_pending: usize,
}

// SAFETY: the encoder state is owned exclusively by this value; libspeex keeps no global state.
unsafe impl Send for Encoder {}

impl Encoder {
    pub fn new(config: EncoderConfig) -> Result<Self, CodecError> {
        Self::with_band(config, Band::Narrow)
    }

    pub fn with_band(config: EncoderConfig, band: Band) -> Result<Self, CodecError> {
        config.validate()?;
        // SAFETY: the modes are statics of the library; init returns null only on OOM.
        let raw = unsafe { sys::speex_encoder_init(band.mode()) };
        let state = NonNull::new(raw).ok_or(CodecError::Init)?;
        let mut encoder = Self {
            state,
            bits: Bits::new(),
            config,
            band,
            frames_pending: 0,
        };
        encoder.ctl(sys::SPEEX_SET_COMPLEXITY, i32::from(config.complexity));
        if config.vbr {
            encoder.ctl(sys::SPEEX_SET_VBR, 1);
            // VBR takes a float quality; speexenc passes the integer quality as a float.
            let mut q = f32::from(config.quality);
            // SAFETY: SPEEX_SET_VBR_QUALITY reads one float.
            unsafe {
                sys::speex_encoder_ctl(
                    state.as_ptr(),
                    sys::SPEEX_SET_VBR_QUALITY,
                    (&mut q as *mut f32).cast(),
                )
            };
        } else {
            encoder.ctl(sys::SPEEX_SET_QUALITY, i32::from(config.quality));
        }
        Ok(encoder)
    }

    fn ctl(&mut self, request: i32, value: i32) {
        let mut v: c_int = value;
        // SAFETY: every request passed here reads one int.
        unsafe {
            sys::speex_encoder_ctl(self.state.as_ptr(), request, (&mut v as *mut c_int).cast())
        };
    }

    pub fn config(&self) -> EncoderConfig {
        self.config
    }

    pub fn band(&self) -> Band {
        self.band
    }

    /// Samples the encoder delays its input by (its analysis look-ahead).
    pub fn lookahead(&self) -> usize {
        let mut v: c_int = 0;
        // SAFETY: SPEEX_GET_LOOKAHEAD writes one int.
        unsafe {
            sys::speex_encoder_ctl(
                self.state.as_ptr(),
                sys::SPEEX_GET_LOOKAHEAD,
                (&mut v as *mut c_int).cast(),
            )
        };
        usize::try_from(v).unwrap_or(0)
    }

    /// Encodes one 20 ms frame. When the packet is complete (after `frames_per_packet` frames)
    /// it is written to `packet` and its length returned.
    pub fn encode_frame(
        &mut self,
        frame: &[i16; FRAME_SIZE],
        packet: &mut [u8; MAX_PACKET_BYTES],
    ) -> Option<usize> {
        self.encode_samples(frame, packet).ok().flatten()
    }

    /// [`Encoder::encode_frame`] for either band: `frame` must hold 20 ms at its rate.
    pub fn encode_samples(
        &mut self,
        frame: &[i16],
        packet: &mut [u8; MAX_PACKET_BYTES],
    ) -> Result<Option<usize>, CodecError> {
        let expected = self.band.frame_size();
        if frame.len() != expected {
            return Err(CodecError::FrameLength {
                got: frame.len(),
                expected,
            });
        }
        // libspeex takes a mutable pointer but only reads the input of speex_encode_int.
        let mut input = [0i16; 2 * FRAME_SIZE];
        input[..expected].copy_from_slice(frame);
        // SAFETY: input holds at least one frame of the mode; state and bits are valid.
        unsafe { sys::speex_encode_int(self.state.as_ptr(), input.as_mut_ptr(), self.bits.ptr()) };
        self.frames_pending += 1;
        if self.frames_pending < self.config.frames_per_packet {
            return Ok(None);
        }
        Ok(Some(self.flush(packet)))
    }

    /// Ends the packet being built, padding it with terminators up to `frames_per_packet`
    /// frames as speexenc does at the end of a stream. Returns `None` if no frame is pending.
    pub fn finish(&mut self, packet: &mut [u8; MAX_PACKET_BYTES]) -> Option<usize> {
        if self.frames_pending == 0 {
            return None;
        }
        while self.frames_pending < self.config.frames_per_packet {
            // SAFETY: packs 5 bits into the valid bit buffer.
            unsafe { sys::speex_bits_pack(self.bits.ptr(), 15, 5) };
            self.frames_pending += 1;
        }
        Some(self.flush(packet))
    }

    fn flush(&mut self, packet: &mut [u8; MAX_PACKET_BYTES]) -> usize {
        // SAFETY: bits is valid; write copies at most MAX_PACKET_BYTES into `packet`.
        let written = unsafe {
            sys::speex_bits_insert_terminator(self.bits.ptr());
            let n = sys::speex_bits_write(
                self.bits.ptr(),
                packet.as_mut_ptr().cast(),
                MAX_PACKET_BYTES as c_int,
            );
            sys::speex_bits_reset(self.bits.ptr());
            n
        };
        self.frames_pending = 0;
        usize::try_from(written).unwrap_or(0)
    }
}

impl Drop for Encoder {
    fn drop(&mut self) {
        // SAFETY: created by speex_encoder_init, destroyed once.
        unsafe { sys::speex_encoder_destroy(self.state.as_ptr()) };
    }
}

/// A narrowband Speex decoder with loss concealment.
pub struct Decoder {
    state: NonNull<c_void>,
    bits: Bits,
    band: Band,
    /// Frames of the loaded packet decoded so far.
    frame: usize,
    /// The frame at which libspeex would report the packet corrupt, found by the walker
    /// beforehand: the decoder is not asked for it, because libspeex prints a notification
    /// on stderr for each (hundreds of thousands of lines for a damaged file) and can be told
    /// not to only at build time.
    corrupt_at: Option<usize>,
}

// SAFETY: as for Encoder.
unsafe impl Send for Decoder {}

/// What decoding one frame slot of a packet gave.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameOutcome {
    /// A frame was decoded into the output.
    Decoded,
    /// The packet ended (terminator or no bits left): nothing was written.
    EndOfPacket,
}

impl Decoder {
    /// `enhancer` is the perceptual enhancer (speexdec's default is on).
    pub fn new(enhancer: bool) -> Result<Self, CodecError> {
        Self::with_band(enhancer, Band::Narrow)
    }

    /// A decoder of `band` (a narrowband one decodes a wideband stream's narrowband layer).
    pub fn with_band(enhancer: bool, band: Band) -> Result<Self, CodecError> {
        // SAFETY: as for the encoder.
        let raw = unsafe { sys::speex_decoder_init(band.mode()) };
        let state = NonNull::new(raw).ok_or(CodecError::Init)?;
        let mut decoder = Self {
            state,
            bits: Bits::new(),
            band,
            frame: 0,
            corrupt_at: None,
        };
        let mut enh: c_int = i32::from(enhancer);
        // SAFETY: SPEEX_SET_ENH reads one int.
        unsafe {
            sys::speex_decoder_ctl(
                decoder.state.as_ptr(),
                sys::SPEEX_SET_ENH,
                (&mut enh as *mut c_int).cast(),
            )
        };
        decoder.load(&[])?;
        Ok(decoder)
    }

    /// Hands a packet to the decoder; follow with `decode_next` for each of its frames.
    pub fn load(&mut self, packet: &[u8]) -> Result<(), CodecError> {
        if packet.len() > MAX_PACKET_BYTES * 4 {
            return Err(CodecError::PacketTooLarge(packet.len()));
        }
        use super::bitstream::{BitstreamError, Walker};
        self.frame = 0;
        self.corrupt_at = match Walker::new().frames(packet).find_map(Result::err) {
            // Truncation is not corrupt to libspeex: it decodes the missing bits as zeros.
            None | Some(BitstreamError::Truncated { .. }) => None,
            // The walker meets a wideband layer at the start of the frame after it; the
            // wideband decoder reads it at the end of the frame it belongs to.
            Some(
                error @ (BitstreamError::InvalidWidebandSubmode { .. }
                | BitstreamError::TooManyWidebandLayers { .. }),
            ) if self.band == Band::Wide => Some(error.frame().saturating_sub(1)),
            Some(error) => Some(error.frame()),
        };
        // SAFETY: libspeex copies `len` bytes from the slice (growing its own buffer if needed).
        unsafe {
            sys::speex_bits_read_from(
                self.bits.ptr(),
                packet.as_ptr().cast::<std::ffi::c_char>().cast_mut(),
                packet.len() as c_int,
            )
        };
        Ok(())
    }

    pub fn band(&self) -> Band {
        self.band
    }

    /// Decodes the next frame of the loaded packet.
    pub fn decode_next(&mut self, out: &mut [i16; FRAME_SIZE]) -> Result<FrameOutcome, CodecError> {
        self.decode_next_into(out)
    }

    /// [`Decoder::decode_next`] for either band: `out` must hold 20 ms at its rate.
    pub fn decode_next_into(&mut self, out: &mut [i16]) -> Result<FrameOutcome, CodecError> {
        self.check_length(out.len())?;
        if self.corrupt_at == Some(self.frame) {
            return Err(CodecError::Corrupted);
        }
        self.frame += 1;
        // SAFETY: out holds one frame, state and bits are valid.
        let ret = unsafe {
            sys::speex_decode_int(self.state.as_ptr(), self.bits.ptr(), out.as_mut_ptr())
        };
        match ret {
            0 => {
                // SAFETY: bits is valid.
                if unsafe { sys::speex_bits_remaining(self.bits.ptr()) } < 0 {
                    Err(CodecError::Overflow)
                } else {
                    Ok(FrameOutcome::Decoded)
                }
            }
            -1 => Ok(FrameOutcome::EndOfPacket),
            _ => Err(CodecError::Corrupted),
        }
    }

    fn check_length(&self, got: usize) -> Result<(), CodecError> {
        let expected = self.band.frame_size();
        if got == expected {
            Ok(())
        } else {
            Err(CodecError::FrameLength { got, expected })
        }
    }

    /// Synthesises a frame for a lost packet from the decoder's state (packet loss concealment).
    pub fn conceal(&mut self, out: &mut [i16; FRAME_SIZE]) {
        let _ = self.conceal_into(out);
    }

    /// [`Decoder::conceal`] for either band: `out` must hold 20 ms at its rate.
    pub fn conceal_into(&mut self, out: &mut [i16]) -> Result<(), CodecError> {
        self.check_length(out.len())?;
        // SAFETY: a null bits pointer asks libspeex for concealment; out holds one frame.
        unsafe {
            sys::speex_decode_int(self.state.as_ptr(), std::ptr::null_mut(), out.as_mut_ptr())
        };
        Ok(())
    }

    /// Samples of delay the decoder adds (speexdec trims them at the start of a stream).
    pub fn lookahead(&self) -> usize {
        let mut v: c_int = 0;
        // SAFETY: SPEEX_GET_LOOKAHEAD writes one int.
        unsafe {
            sys::speex_decoder_ctl(
                self.state.as_ptr(),
                sys::SPEEX_GET_LOOKAHEAD,
                (&mut v as *mut c_int).cast(),
            )
        };
        usize::try_from(v).unwrap_or(0)
    }
}

impl Drop for Decoder {
    fn drop(&mut self) {
        // SAFETY: created by speex_decoder_init, destroyed once.
        unsafe { sys::speex_decoder_destroy(self.state.as_ptr()) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tone(n: usize) -> Vec<i16> {
        (0..n)
            .map(|i| {
                let t = i as f32 / 8000.0;
                (6000.0 * (2.0 * std::f32::consts::PI * 220.0 * t).sin()
                    + 3000.0 * (2.0 * std::f32::consts::PI * 660.0 * t).sin())
                    as i16
            })
            .collect()
    }

    #[test]
    fn packet_sizes_follow_the_mode_table() {
        // Bits per frame for qualities 0..=10 (design brief), padded to whole bytes.
        let bits = [43, 79, 119, 160, 160, 220, 220, 300, 300, 364, 492];
        for (quality, bits) in bits.iter().enumerate() {
            let mut enc = Encoder::new(EncoderConfig {
                quality: quality as u8,
                ..Default::default()
            })
            .unwrap();
            let mut packet = [0u8; MAX_PACKET_BYTES];
            let frame = [100i16; FRAME_SIZE];
            let n = enc.encode_frame(&frame, &mut packet).unwrap();
            assert_eq!(n, usize::div_ceil(*bits, 8), "quality {quality}");
        }
    }

    #[test]
    fn round_trip_keeps_the_tone() {
        let input = tone(8000);
        let mut enc = Encoder::new(EncoderConfig::default()).unwrap();
        let mut dec = Decoder::new(false).unwrap();
        let mut packet = [0u8; MAX_PACKET_BYTES];
        let mut out = Vec::new();
        for frame in input.chunks_exact(FRAME_SIZE) {
            let n = enc
                .encode_frame(frame.try_into().unwrap(), &mut packet)
                .unwrap();
            dec.load(&packet[..n]).unwrap();
            let mut pcm = [0i16; FRAME_SIZE];
            assert_eq!(dec.decode_next(&mut pcm).unwrap(), FrameOutcome::Decoded);
            out.extend_from_slice(&pcm);
        }
        let energy_in: f64 = input.iter().map(|&s| f64::from(s).powi(2)).sum();
        let energy_out: f64 = out.iter().map(|&s| f64::from(s).powi(2)).sum();
        assert!(energy_out > 0.5 * energy_in && energy_out < 1.5 * energy_in);
    }

    #[test]
    fn several_frames_per_packet_decode_then_end() {
        let input = tone(FRAME_SIZE * 3);
        let mut enc = Encoder::new(EncoderConfig {
            frames_per_packet: 3,
            ..Default::default()
        })
        .unwrap();
        let mut packet = [0u8; MAX_PACKET_BYTES];
        let mut len = None;
        for frame in input.chunks_exact(FRAME_SIZE) {
            len = enc.encode_frame(frame.try_into().unwrap(), &mut packet);
        }
        let mut dec = Decoder::new(true).unwrap();
        dec.load(&packet[..len.unwrap()]).unwrap();
        let mut pcm = [0i16; FRAME_SIZE];
        for _ in 0..3 {
            assert_eq!(dec.decode_next(&mut pcm).unwrap(), FrameOutcome::Decoded);
        }
        assert_eq!(
            dec.decode_next(&mut pcm).unwrap(),
            FrameOutcome::EndOfPacket
        );
    }

    #[test]
    fn concealment_fades_instead_of_failing() {
        let mut dec = Decoder::new(true).unwrap();
        let mut pcm = [1i16; FRAME_SIZE];
        dec.conceal(&mut pcm);
        assert!(pcm.iter().all(|&s| s.abs() < 10));
    }

    #[test]
    fn bad_settings_are_refused() {
        let bad = |c: EncoderConfig| Encoder::new(c).err();
        let d = EncoderConfig::default();
        assert_eq!(
            bad(EncoderConfig { quality: 11, ..d }),
            Some(CodecError::Quality(11))
        );
        assert_eq!(
            bad(EncoderConfig { complexity: 0, ..d }),
            Some(CodecError::Complexity(0))
        );
        assert_eq!(
            bad(EncoderConfig {
                frames_per_packet: 9,
                ..d
            }),
            Some(CodecError::FramesPerPacket(9))
        );
    }
}
